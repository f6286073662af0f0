"""`--track`: the scripts also log to Weights & Biases, the same scalars at the same steps as
TensorBoard, and `routine-gym experiment run --track` passes the flags on to every run.

The scripts run as a user runs them (a fresh process, `python algos/X.py --track ...`) with
W&B offline (`WANDB_MODE=offline`, its files in a temporary `WANDB_DIR`, no account, no
network). The offline run is read back from its `.wandb` record log with W&B's own reader,
`wandb leet inspect --json`, and the TensorBoard side with the report's reader
(`training_curves.read_scalars`).
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from one_line import assert_one_line_error

from routine_gym.experiments import backends, sweep
from routine_gym.experiments.training_curves import read_scalars
from routine_gym.plumbing.arguments import given_flags, parse_args
from routine_gym.plumbing.scalars import ScalarWriter
from routine_gym.plumbing.tracking import INSTALL_HINT, STEP_METRIC, WandbScalars

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
DEMO = REPO / "demos" / "MinAtar-Breakout-v1.npz"
#: The two scripts with the smallest budgets that train, checkpoint and evaluate.
SCRIPTS = {
    "rapl_a2c": ["--mode", "rapl", "--num-envs", "2", "--total-timesteps", "400"],
    "rapl_sqil": ["--total-timesteps", "400", "--learning-starts", "100",
                  "--train-frequency", "2", "--buffer-size", "2000", "--eval-max-steps", "200"],
}


def offline(tmp_path: Path) -> dict[str, str]:
    """A user's environment with W&B offline and silent, its files under `tmp_path/wandb`."""
    return {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path), "LANG": "C.UTF-8",
            "WANDB_MODE": "offline", "WANDB_DIR": str(tmp_path), "WANDB_SILENT": "true",
            "WANDB_ERROR_REPORTING": "false"}


def script(name: str, *flags: str, cwd: Path, python: list[str] | None = None
           ) -> subprocess.CompletedProcess:
    words = [*(python or [str(BIN / "python")]), str(REPO / "algos" / f"{name}.py"), *flags]
    return subprocess.run(words, cwd=cwd, env=offline(cwd), capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)


def ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-3000:])
    return proc.stdout


def wandb_records(run_dir: Path, cwd: Path) -> list[dict]:
    """Every record of an offline W&B run's `.wandb` log, as W&B's reader prints them."""
    proc = subprocess.run([str(BIN / "wandb"), "leet", "inspect", "--json", str(run_dir)],
                          env=offline(cwd), capture_output=True, text=True, timeout=60,
                          stdin=subprocess.DEVNULL)
    ok(proc)
    return [json.loads(line) for line in proc.stdout.splitlines() if line.strip()]


def wandb_scalars(records: list[dict]) -> list[tuple[str, int, float]]:
    """The `(tag, step, value)` of every scalar in the history rows, sorted."""
    rows = [r["history"]["item"] for r in records if r["type"] == "history"]
    return sorted((tag, int(row[STEP_METRIC]), value) for row in rows
                  for tag, value in row.items() if not tag.startswith("_") and tag != STEP_METRIC)


def tensorboard_scalars(run: Path) -> list[tuple[str, int, float]]:
    return sorted((tag, int(step), float(value)) for tag, (steps, values) in
                  read_scalars(run).items() for step, value in zip(steps, values, strict=True))


def the_run(records: list[dict]) -> dict:
    (run,) = [r["run"] for r in records if r["type"] == "run"]
    return run


@pytest.mark.parametrize("name", list(SCRIPTS))
def test_a_tracked_run_logs_the_same_scalars_at_the_same_steps_to_wandb_as_to_tensorboard(
        name, tmp_path):
    ok(script(name, "--env-id", "MinAtar/Breakout-v1", "--demo", str(DEMO), *SCRIPTS[name],
              "--eval-episodes", "1", "--run-dir", "runs", "--torch-threads", "1",
              "--track", "--wandb-project-name", "routine-gym-test", cwd=tmp_path))
    (run,) = (tmp_path / "runs").iterdir()
    (offline_run,) = (tmp_path / "wandb").glob("offline-run-*")
    records = wandb_records(offline_run, tmp_path)
    logged = tensorboard_scalars(run)
    tags = {tag for tag, _, _ in logged}
    assert {"charts/episodic_return", "charts/SPS", "losses/td_loss" if name == "rapl_sqil"
            else "losses/value_loss", "eval/mean_return"} <= tags
    assert len(logged) > 20
    assert wandb_scalars(records) == logged  # tags, steps and float32 values, one for one
    info = the_run(records)
    assert info["display_name"] == run.name and info["project"] == "routine-gym-test"
    config = info["config"]["update"]
    assert config["env_id"] == "MinAtar/Breakout-v1" and config["track"] is True
    assert [r["exit"]["exit_code"] for r in records if r["type"] == "exit"] == [0]


def test_resume_continues_the_same_wandb_run_and_both_sinks_still_match(tmp_path):
    flags = ["--env-id", "MinAtar/Breakout-v1", "--mode", "a2c",  # no --demo: a2c reads none
             "--num-envs", "2", "--eval-episodes", "0", "--run-dir", "runs",
             "--torch-threads", "1", "--checkpoint-every", "200"]
    ok(script("rapl_a2c", *flags, "--total-timesteps", "200", "--track", cwd=tmp_path))
    (run,) = (tmp_path / "runs").iterdir()
    first = torch.load(run / "checkpoint.pt", weights_only=True)["wandb_run_id"]
    ok(script("rapl_a2c", "--resume", str(run), "--total-timesteps", "400", cwd=tmp_path))
    offline_runs = sorted((tmp_path / "wandb").glob("offline-run-*"))
    assert len(offline_runs) == 2
    records = [wandb_records(path, tmp_path) for path in offline_runs]
    assert [the_run(r)["run_id"] for r in records] == [first, first]
    assert the_run(records[0])["project"] == "routine-gym"  # the default project
    assert torch.load(run / "checkpoint.pt", weights_only=True)["wandb_run_id"] == first
    assert wandb_scalars(records[0] + records[1]) == tensorboard_scalars(run)


def test_track_without_wandb_is_a_one_line_error_naming_the_extra(tmp_path):
    # `import wandb` fails as it does where wandb is not installed.
    python = [str(BIN / "python"), "-c", "import runpy, sys; sys.modules['wandb'] = None; "
              "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')"]
    proc = script("rapl_a2c", "--env-id", "MinAtar/Breakout-v1", "--demo", str(DEMO),
                  "--run-dir", "runs", "--track", cwd=tmp_path, python=python)
    assert_one_line_error(proc, "--track", INSTALL_HINT, prefix="rapl_a2c.py: error:")
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").iterdir())


def test_the_writer_mirrors_each_event_and_a_repeated_tag_starts_a_new_row(tmp_path):
    class Run:  # the part of a W&B run WandbScalars uses
        id = "abc"

        def __init__(self):
            self.rows, self.metrics = [], []

        def define_metric(self, name, step_metric=None):
            self.metrics.append((name, step_metric))

        def log(self, row):
            self.rows.append(row)

    run = Run()
    writer = ScalarWriter(str(tmp_path), mirror=WandbScalars(run))
    writer.add_scalar("charts/episodic_return", 3, 80)
    writer.add_scalar("charts/episodic_return", 5, 80)  # two episodes ended at step 80
    writer.add_scalar("losses/value_loss", 0.1, 80)
    writer.add_scalar("losses/value_loss", 0.2, 160)
    writer.add_scalar("charts/SPS", 7, walltime=1.0)  # TensorBoard's own path, step 0
    writer.close()
    float32_tenth = float(torch.tensor(0.1).item())  # the float32 TensorBoard stores
    assert run.rows == [
        {STEP_METRIC: 80, "charts/episodic_return": 3.0},
        {STEP_METRIC: 80, "charts/episodic_return": 5.0, "losses/value_loss": float32_tenth},
        {STEP_METRIC: 160, "losses/value_loss": float(torch.tensor(0.2).item())},
        {STEP_METRIC: 0, "charts/SPS": 7.0},
    ]
    assert run.metrics == [(STEP_METRIC, None), ("*", STEP_METRIC)]


def test_no_flag_counts_as_given_so_a_resume_can_turn_tracking_off():
    from dataclasses import dataclass

    @dataclass
    class Args:
        track: bool = False

    parsed = parse_args(Args, argv=["--no-track"])
    assert parsed.track is False
    assert "track" in given_flags(parsed)
    # An Args made in Python was given no flag, whatever was parsed before in the process
    # (a resume called as main(Args(resume=..., total_timesteps=...)) keeps its new budget).
    assert given_flags(Args()) == set()


# -- the sweep -----------------------------------------------------------------------------------

TRACKING = {"project": "P", "entity": "E"}


def test_the_sweep_passes_tracking_to_each_run_without_changing_its_key(tmp_path, monkeypatch):
    submitted = []

    class Backend:  # runs nothing: records what it was given and reports it finished
        def __init__(self, jobs):
            pass

        def submit(self, config, runs, cuda):
            submitted.append(config)
            return config["key"]

        def wait(self, handles, timeout):
            return [(h, {"key": h}) for h in handles]

        def close(self):
            pass

    monkeypatch.setattr(sweep, "LocalBackend", Backend)
    assert sweep.run_experiment("rl", "smoke", tmp_path / "a", stream=io.StringIO(),
                                tracking=TRACKING).ok
    assert sweep.run_experiment("rl", "smoke", tmp_path / "b", stream=io.StringIO()).ok
    tracked, plain = submitted[:len(submitted) // 2], submitted[len(submitted) // 2:]
    assert [c["key"] for c in tracked] == [c["key"] for c in plain]
    assert all(c["tracking"] == TRACKING for c in tracked)
    assert not any("tracking" in c for c in plain)
    for config in tracked:  # the run's config.json is the same with or without tracking
        on_disk = json.loads((tmp_path / "a" / "runs" / config["key"] / "config.json").read_text())
        assert on_disk == {k: v for k, v in config.items() if k != "tracking"}


def test_a_runs_command_line_carries_the_tracking_flags_when_started_and_resumed(tmp_path):
    config = {"key": "aaaaaaaaaaaa", "script": "rapl_a2c", "flags": {"seed": 1}}
    flags = ["--track", "--wandb-project-name", "P", "--wandb-entity", "E"]
    assert backends.command({**config, "tracking": TRACKING}, tmp_path, python="py")[-5:] == flags
    assert backends.command({**config, "tracking": {"project": "P", "entity": None}}, tmp_path,
                            python="py")[-3:] == flags[:3]
    assert "--track" not in backends.command(config, tmp_path, python="py")
    run = tmp_path / "aaaaaaaaaaaa" / "MinAtar-Breakout-v1__rapl_a2c-rapl__1__1"
    run.mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(b"")
    resumed = backends.command({**config, "tracking": TRACKING}, tmp_path, python="py")
    assert resumed[2:] == ["--resume", str(run), *flags]
    # Resumed without --track, a run started by a tracked sweep stops tracking.
    assert backends.command(config, tmp_path, python="py")[2:] == ["--resume", str(run),
                                                                   "--no-track"]


def test_sweep_wandb_flags_without_track_are_a_one_line_error(tmp_path):
    proc = subprocess.run([str(BIN / "routine-gym"), "experiment", "run", "rl", "--budget",
                           "smoke", "--out", str(tmp_path / "out"), "--wandb-project-name", "P"],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert_one_line_error(proc, "--wandb-project-name", "--track", prefix="routine-gym: error:")
    assert not (tmp_path / "out").exists()
