"""What a new user meets on a fresh clone (issue 46, case 13): the env profile's reward scale,
the sweep scripts' Python, the Makefile's CPU torch with its fallback, the ignore rules, the
report's `--out` and progress lines, the snapshot that keeps a budget comparison, and bench
scripts whose workers die with them."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from routine_gym.envs import profile_for
from routine_gym.experiments import specs
from routine_gym.plumbing.run import profile_reward_scale

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
sys.path.insert(0, str(REPO / "bench"))
import common  # noqa: E402  (bench/common.py, as the benchmarks import it)


def clean_env(**extra: str) -> dict[str, str]:
    """A user's shell: PATH and HOME only (no venv on PATH unless given)."""
    return {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/tmp"), "LANG": "C.UTF-8",
            **extra}


# -- the reward scale of the env's profile ---------------------------------------------------

@pytest.mark.parametrize(("env_id", "given", "expected"), [
    ("MiniQbert-v0", None, 0.01),  # its 25- and 100-point rewards: the profile's 0.01
    ("MiniQbert-v0", 1.0, 1.0),  # a given flag wins
    ("MiniQbert-v0", 0.5, 0.5),
    ("CartPole-v1", None, 1.0),
    ("MinAtar/Breakout-v1", None, 1.0),
    ("ALE/Qbert-v5", None, 1.0),  # sign-clipped already
])
def test_an_unset_reward_scale_is_the_env_profiles(env_id, given, expected):
    args = SimpleNamespace(env_id=env_id, reward_scale=given)
    profile_reward_scale(args)
    assert args.reward_scale == expected


def test_a_script_without_reward_scale_is_left_alone():
    args = SimpleNamespace(env_id="MiniQbert-v0")  # rapl_sqil, bc, gail have no such flag
    profile_reward_scale(args)
    assert not hasattr(args, "reward_scale")


def test_the_experiments_name_the_profiles_scale_so_committed_keys_stay():
    # The sweeps pass --reward-scale explicitly (it is in every MiniQbert run's key); the value
    # they pass is the profile's default, so a user's bare run trains as the sweep's does.
    assert specs.REWARD_SCALES == {"MiniQbert-v0": profile_for("MiniQbert-v0").reward_scale}
    from routine_gym.experiments import registry

    committed = REPO / "bench" / "results" / "experiments" / "cpu"
    for name in ("rl", "diagnosis"):
        keys = {row["key"] for row in json.loads((committed / f"{name}.json").read_text())["runs"]}
        built = registry.build(name, "cpu")
        assert keys == {entry.run.key for entry in built}, name
        miniqbert = [e.run for e in built if ("env-id", "MiniQbert-v0") in e.run.flags
                     and e.run.script in specs.SCALED_SCRIPTS]
        assert miniqbert and all(("reward-scale", 0.01) in r.flags for r in miniqbert), name


def test_a_miniqbert_run_as_a_user_learns_at_the_profiles_scale(tmp_path):
    # The run's saved settings (its checkpoint's Args) hold the scale it learnt at.
    for flags, expected in (([], 0.01), (["--reward-scale", "1"], 1.0)):
        run_dir = tmp_path / f"runs{len(flags)}"
        proc = subprocess.run(
            [str(BIN / "python"), str(REPO / "algos" / "rapl_a2c.py"), "--env-id",
             "MiniQbert-v0", "--mode", "a2c", "--num-envs", "2", "--total-timesteps", "200",
             "--checkpoint-every", "100", "--eval-episodes", "0", "--run-dir", str(run_dir),
             *flags], cwd=tmp_path, env=clean_env(), capture_output=True, text=True,
            timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        (checkpoint,) = run_dir.glob("*/checkpoint.pt")
        saved = json.loads(torch.load(checkpoint, weights_only=True)["args"])
        assert saved["reward_scale"] == expected


# -- the sweep scripts' Python -----------------------------------------------------------------

def _sweep_copy(tmp_path: Path, name: str) -> Path:
    (tmp_path / "bench").mkdir()
    shutil.copy2(REPO / "bench" / name, tmp_path / "bench" / name)
    return tmp_path / "bench" / name


def _fake(path: Path, word: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"#!/bin/sh\necho {word} \"$@\"\n")
    path.chmod(0o755)


@pytest.mark.parametrize("name", ["sweep_cpu.sh", "sweep_long.sh"])
def test_a_sweep_script_uses_the_clones_venv_else_python3(name, tmp_path):
    script = _sweep_copy(tmp_path, name)
    _fake(tmp_path / "bin" / "python3", "PYTHON3")
    env = clean_env(PATH=f"{tmp_path / 'bin'}:/usr/bin:/bin", BUDGET="smoke")
    proc = subprocess.run([str(script), str(tmp_path / "S")], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "PYTHON3 -m routine_gym.cli experiment run" in proc.stdout
    _fake(tmp_path / ".venv" / "bin" / "python", "VENV")  # after `make run` or `make test`
    proc = subprocess.run([str(script), str(tmp_path / "S")], env=env, capture_output=True,
                          text=True, timeout=60)
    assert "VENV -m routine_gym.cli experiment run" in proc.stdout
    assert "PYTHON3" not in proc.stdout
    proc = subprocess.run([str(script), str(tmp_path / "S")], env={**env, "PYTHON": "echo"},
                          capture_output=True, text=True, timeout=60)
    assert "VENV" not in proc.stdout and "-m routine_gym.cli experiment run" in proc.stdout


# -- the Makefile: torch's CPU build first, the plain install when its index is out of reach ---

def _make_install(tmp_path: Path, index_fails: bool, *flags: str) -> tuple[int, list[str], str]:
    """`make .venv/.installed` with a fake venv whose python logs each pip call (and fails the
    one with an index URL when `index_fails`): no network, nothing installed."""
    venv = tmp_path / "venv"
    log = tmp_path / "pip.log"
    venv_bin = venv / "bin"
    venv_bin.mkdir(parents=True)
    fail = 'case "$*" in *index-url*) exit 1;; esac\n' if index_fails else ""
    (venv_bin / "python").write_text(f"#!/bin/sh\necho \"$*\" >> {log}\n{fail}exit 0\n")
    (venv_bin / "python").chmod(0o755)
    proc = subprocess.run(["make", "-s", "-f", str(REPO / "Makefile"), f"VENV={venv}",
                           f"{venv}/.installed", *flags], cwd=REPO, env=clean_env(),
                          capture_output=True, text=True, timeout=60)
    calls = log.read_text().splitlines() if log.exists() else []
    return proc.returncode, calls, proc.stdout + proc.stderr


def test_make_installs_the_cpu_torch_first(tmp_path):
    rc, calls, _ = _make_install(tmp_path, index_fails=False)
    assert rc == 0 and (tmp_path / "venv" / ".installed").exists()
    torch_call = [c for c in calls if "--extra-index-url" in c]
    assert len(torch_call) == 1
    assert "torch==2.13.0" in torch_call[0]
    assert "https://download.pytorch.org/whl/cpu" in torch_call[0]
    # ... before the project, whose torch==2.13.0 the CPU build (2.13.0+cpu) then satisfies.
    assert calls.index(torch_call[0]) < calls.index("-m pip install --quiet -e .[dev]")


def test_make_goes_on_with_the_plain_install_when_the_cpu_index_is_out_of_reach(tmp_path):
    rc, calls, out = _make_install(tmp_path, index_fails=True)
    assert rc == 0, out
    assert "could not be used; torch comes from the default index" in out
    assert "-m pip install --quiet -e .[dev]" in calls  # then the cores' report
    assert "torch==2.13.0" in calls[calls.index("-m pip install --quiet -e .[dev]") - 1]
    assert (tmp_path / "venv" / ".installed").exists()


def test_make_without_a_torch_index_makes_the_plain_install_only(tmp_path):
    rc, calls, _ = _make_install(tmp_path, True, "TORCH_INDEX=")
    assert rc == 0
    assert not [c for c in calls if "index-url" in c]


def test_the_venv_make_built_holds_the_cpu_torch():
    # The clone's .venv (make test's, CI's): torch's CPU build, no CUDA libraries beside it.
    if Path(sys.prefix).resolve() != (REPO / ".venv").resolve():
        pytest.skip("not the venv `make` builds in this clone")
    assert torch.__version__.endswith("+cpu") and torch.version.cuda is None
    site = Path(torch.__file__).parent.parent
    assert not list(site.glob("nvidia*")), "a CUDA torch's libraries are installed"


def test_the_makefiles_torch_is_the_projects():
    makefile = (REPO / "Makefile").read_text()
    pyproject = (REPO / "pyproject.toml").read_text()
    version = makefile.split("TORCH_VERSION := ", 1)[1].split()[0]
    assert f'"torch=={version}"' in pyproject


# -- the ignore rules ---------------------------------------------------------------------------

@pytest.mark.parametrize("path", ["sweeps/cpu/rl.json", "wandb/run-1/files/config.yaml",
                                  "runs/x/events.out.tfevents.1"])
def test_what_the_readmes_commands_write_is_ignored(path):
    proc = subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=REPO)
    assert proc.returncode == 0, path


def test_a_committed_snapshots_runs_are_not_ignored():
    proc = subprocess.run(["git", "check-ignore", "-q", "--no-index",
                           "bench/results/experiments/cpu/runs/x/result.json"], cwd=REPO)
    assert proc.returncode == 1


# -- the snapshot keeps a budget comparison ---------------------------------------------------

def _snapshot_with(monkeypatch, tmp_path, dest: Path, *flags: str) -> dict:
    """Run bench/snapshot_experiments.py's `snapshot` on a one-manifest sweep with the report
    writer replaced by a recorder (the report itself is tested in test_budget_comparison)."""
    import snapshot_experiments

    sweep = tmp_path / "sweep"
    (sweep / "runs").mkdir(parents=True, exist_ok=True)
    (sweep / "rl.json").write_text(json.dumps({"runs": []}))
    called: dict = {}
    monkeypatch.setattr(snapshot_experiments, "write_report",
                        lambda out, **kw: called.update(out=out, **kw))
    monkeypatch.setattr(sys, "argv", ["snapshot_experiments.py", str(sweep), str(dest), *flags])
    snapshot_experiments.snapshot()
    return called


def test_a_snapshot_keeps_its_budget_comparison(monkeypatch, tmp_path):
    import snapshot_experiments

    dest = tmp_path / "dest"
    other = tmp_path / "other"
    other.mkdir()
    called = _snapshot_with(monkeypatch, tmp_path, dest, "--beside", str(other))
    assert called["beside"] == other
    noted = json.loads((dest / "provenance.json").read_text())["beside"]
    assert Path(noted) == other.resolve()
    # The next snapshot, with no --beside, draws the comparison again.
    (dest / "report").mkdir(exist_ok=True)
    (dest / "report" / "budgets_fig2.csv").write_text("x\n")
    assert _snapshot_with(monkeypatch, tmp_path, dest)["beside"] == other.resolve()
    # A snapshot whose report compares budgets but names no other sweep is refused, untouched.
    (dest / "provenance.json").write_text(json.dumps({"snapshots": []}))
    (dest / "report").mkdir(exist_ok=True)  # the faked writer drew nothing last time
    (dest / "report" / "budgets_fig2.csv").write_text("x\n")
    with pytest.raises(snapshot_experiments.UsageError, match="give --beside"):
        _snapshot_with(monkeypatch, tmp_path, dest)
    assert (dest / "report" / "budgets_fig2.csv").exists()


def test_the_committed_long_snapshot_is_remade_with_its_comparison():
    # Its report has the budgets_* files; the recipe in its script and docs names --beside.
    long = REPO / "bench" / "results" / "experiments" / "long" / "report"
    assert (long / "budgets_fig2.csv").exists()
    import re

    recipe = re.compile(r"snapshot_experiments\.py \S+ bench/results/experiments/long"
                        r"(?:[^\n]*\\\n)*[^\n]*")  # the command with its continued lines
    for where in (REPO / "bench" / "sweep_long.sh", REPO / "docs" / "experiments.md",
                  REPO / "bench" / "snapshot_experiments.py"):
        found = recipe.findall(where.read_text())
        assert found, where
        for command in found:
            assert "--beside bench/results/experiments/cpu" in command, (where, command)


# -- `experiment report --out`, with progress on stderr -------------------------------------

@pytest.mark.slow
def test_experiment_report_out_writes_elsewhere_and_says_what_it_does(tmp_path):
    # The committed long snapshot (rl alone, 45 runs): its folder is left as it is.
    sweep = REPO / "bench" / "results" / "experiments" / "long"
    before = {p.name: p.stat().st_mtime_ns for p in (sweep / "report").iterdir()}
    proc = subprocess.run([str(BIN / "routine-gym"), "experiment", "report", str(sweep),
                           "--out", "elsewhere/report"], cwd=tmp_path, env=clean_env(),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    written = proc.stdout.split()
    assert written[-1] == "elsewhere/report/report.md"
    assert (tmp_path / "elsewhere" / "report" / "fig2_rl.csv").read_text() == (
        sweep / "report" / "fig2_rl.csv").read_text()
    lines = proc.stderr.splitlines()
    assert all(line.startswith("report [") for line in lines), lines
    # The bootstrap of 45 runs takes seconds: its step is announced when it starts.
    assert any("Fig. 2 (rl): 45 finished run(s)" in line for line in lines)
    assert lines[-1].endswith(f"{len(written)} file(s) written in elsewhere/report")
    assert {p.name: p.stat().st_mtime_ns for p in (sweep / "report").iterdir()} == before


# -- bench scripts: their workers die with them -----------------------------------------------

def test_every_bench_script_makes_its_workers_die_with_it():
    scripts = [p for p in (REPO / "bench").glob("*.py")
               if 'if __name__ == "__main__":' in p.read_text()
               and p.name != "authors_code_runner.py"]  # runs under the authors' Python
    assert len(scripts) >= 13
    for path in scripts:
        main_block = path.read_text().split('if __name__ == "__main__":', 1)[1]
        assert "children_die_with_me()" in main_block, path.name


def test_a_sigtermed_bench_script_leaves_no_worker_behind(tmp_path):
    # bench_learning.py runs the training script as subprocesses from a thread pool; two
    # long runs at once, then SIGTERM to the benchmark alone (as `kill PID` sends it).
    bench = subprocess.Popen(
        [str(BIN / "python"), str(REPO / "bench" / "bench_learning.py"), "--modes", "a2c",
         "--seeds", "1", "2", "--jobs", "2", "--steps", "100000000", "--run-dir",
         str(tmp_path / "runs"), "--out", str(tmp_path / "learning.md"), "--script-args",
         "--torch-threads 1"], cwd=tmp_path, env=clean_env(), stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True, start_new_session=True)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(workers) < 2:
            time.sleep(0.2)
            workers = common.descendants(bench.pid)
        assert len(workers) >= 2, "the benchmark started no runs"
        time.sleep(1.0)
        workers = common.descendants(bench.pid)
        bench.send_signal(signal.SIGTERM)
        assert bench.wait(timeout=30) == 128 + signal.SIGTERM
        time.sleep(0.5)
        alive = [pid for pid in workers if common._alive(pid)]
        assert alive == [], alive
    finally:  # a failed check must not leave the runs behind either
        for pid in {bench.pid, *workers, *common.descendants(bench.pid)}:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        bench.wait(timeout=30)


def test_descendants_finds_grandchildren(tmp_path):
    # A shell whose child sleeps: both are found below the test's process.
    proc = subprocess.Popen(["/bin/sh", "-c", "sleep 30 & wait"])
    try:
        deadline = time.monotonic() + 10
        found: list[int] = []
        while time.monotonic() < deadline and not found:
            found = common.descendants(proc.pid)
            time.sleep(0.05)
        assert len(found) == 1  # the sleep, below the shell
        assert proc.pid in common.descendants(os.getpid())
        assert set(found) <= set(common.descendants(os.getpid()))
    finally:
        for pid in [*common.descendants(proc.pid), proc.pid]:
            os.kill(pid, signal.SIGKILL)
        proc.wait()
