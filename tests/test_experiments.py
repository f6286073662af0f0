"""`routine-gym experiment`: the seven experiments' specs, sweeps of real runs of the scripts at the
`smoke` budget (locally and through a real local Ray instance), rerun, kill and resume, failed
runs, and the report of a real sweep."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from routine_gym.errors import UsageError
from routine_gym.experiments import backends, registry, specs, sweep, training_curves
from routine_gym.experiments import report as report_mod
from routine_gym.experiments.registry import EXPERIMENTS, build, count_runs
from routine_gym.experiments.specs import BUDGETS, RunSpec

NAMES = ["tune", "imitation", "rl", "curves", "coinrun", "scalability", "ablation", "diagnosis",
         "equal-frames"]
#: The experiments with runs at the smoke budget (tune and equal-frames have runs only where a
#: budget tunes).
SMOKE = [n for n in NAMES if n not in ("tune", "equal-frames")]
CLI = [sys.executable, "-m", "routine_gym.cli"]
REPO = Path(__file__).resolve().parents[1]


# -- specs ---------------------------------------------------------------------------------------

def test_the_nine_experiments_and_seven_budgets():
    assert list(EXPERIMENTS) == NAMES
    # long: rl alone (test_long_budget); the fair protocol's three: tests/test_fair_protocol.py
    assert list(BUDGETS) == ["smoke", "cpu", "paper", "long", "smoke-fair", "fair", "fair-long"]
    assert len(specs.PAPER_GAMES) == 30 and "ALE/WizardOfWor-v5" in specs.PAPER_GAMES


@pytest.mark.parametrize(("name", "runs", "steps"), [
    # 6 games (MinAtar's five and MiniQbert) × 3 seeds × 4 methods; BC counts gradient steps.
    ("imitation", 72, 18 * (10_000 + 500_000 + 2 * 100_000)),
    # 6 games × 3 seeds × {A2C, RAPL-A2C, PPO, RAPL-PPO, MacroAction-PPO}
    ("rl", 90, 90 * 10**6),
    ("curves", 75, 75 * 10**6),  # 5 games × 3 seeds × 5 methods
    ("coinrun", 6, 6 * 500_000),  # 3 seeds × {A2C, RAPL-A2C}
    # 5 games × 3 seeds × (A2C + 2 methods × {K 1, 3, 6 at length 2; length 5 at K 3}),
    # less Seaquest's length 5 (3 seeds × 2 methods): its demo has no routine of 5 actions
    ("scalability", 129, 129 * 10**6),
    # 5 games × 3 seeds × (A2C + Full RR PbE RF RP BPE ID) + 5 ID experts of 5M / 10 steps
    ("ablation", 125, 120 * 10**6 + 5 * 500_000),
    # 6 games × 3 seeds × (A2C, RAPL-A2C, and RAPL-A2C and MacroAction at a budget of 10^6
    # decisions, RAPL-A2C as the authors' code has it)
    ("diagnosis", 90, 90 * 10**6),
])
def test_cpu_budget_run_counts_worked_out_by_hand(name, runs, steps):
    assert count_runs(name, "cpu") == (runs, steps)


def test_paper_budget_is_the_papers_settings():
    entries = build("rl", "paper")
    assert {e.env_id for e in entries} == set(specs.PAPER_GAMES)
    assert {e.seed for e in entries} == {1, 2, 3, 4, 5}
    assert {e.run.steps for e in entries if e.role == "main"} == {10**7}
    # Games without a shipped demo first train a 10^7-step A2C expert that records one.
    experts = {e.env_id: e for e in entries if e.role == "expert"}
    assert "ALE/Amidar-v5" in experts and "ALE/Qbert-v5" not in experts
    assert experts["ALE/Amidar-v5"].run.steps == 10**7
    rapl = next(e for e in entries if e.env_id == "ALE/Amidar-v5" and e.method == "RAPL-A2C")
    assert rapl.run.needs == (experts["ALE/Amidar-v5"].run.key,)
    assert dict(rapl.run.flags)["demo"] == f"@run:{experts['ALE/Amidar-v5'].run.key}/demo.npz"


def test_the_same_run_in_two_experiments_has_one_key():
    rl = {(e.method, e.env_id, e.seed): e.run.key for e in build("rl", "cpu")}
    curves = {(e.method, e.env_id, e.seed): e.run.key for e in build("curves", "cpu")}
    scal = {(e.method, e.env_id, e.seed): e.run.key for e in build("scalability", "cpu")
            if e.variant in ({}, {"K": 3, "min_length": 2})}
    shared = ("RAPL-A2C", "MinAtar/Breakout-v1", 2)
    assert rl[shared] == curves[shared] == scal[shared]
    assert rl[("A2C", "MinAtar/Seaquest-v1", 3)] == curves[("A2C", "MinAtar/Seaquest-v1", 3)]


def test_a_key_is_a_hash_of_script_and_flags():
    a = RunSpec("rapl_a2c", (("env-id", "MinAtar/Breakout-v1"), ("seed", 1)), 10)
    same = RunSpec("rapl_a2c", (("seed", 1), ("env-id", "MinAtar/Breakout-v1")), 99)
    other = RunSpec("rapl_a2c", (("env-id", "MinAtar/Breakout-v1"), ("seed", 2)), 10)
    assert a.key == same.key  # flag order and the step count are not part of it
    assert a.key != other.key and len(a.key) == 12
    assert a.key != RunSpec("option_critic", a.flags, 10).key


def test_ablation_id_uses_a_demo_of_an_expert_trained_a_tenth_as_long():
    entries = build("ablation", "cpu")
    ident = [e for e in entries if e.variant == {"discovery": "ID"}]
    experts = {e.run.key: e for e in entries if e.role == "expert"}
    assert len(ident) == 15 and len(experts) == 5
    for entry in ident:
        (need,) = entry.run.needs
        assert experts[need].env_id == entry.env_id
        assert experts[need].run.steps == BUDGETS["cpu"].shipped_expert_steps // 10 == 500_000
        assert dict(experts[need].run.flags)["record-demo"] == "@self/demo.npz"
    proposers = {e.variant["discovery"]: dict(e.run.flags).get("proposer", "full")
                 for e in entries if "discovery" in e.variant}
    assert proposers == {"Full": "full", "RR": "random", "PbE": "enumerate",
                         "RF": "random-fetch", "RP": "repeat", "BPE": "bpe", "ID": "full"}


@pytest.mark.parametrize("budget", ["smoke", "cpu", "paper"])
def test_adding_the_bpe_variant_keeps_every_other_runs_key_and_config(budget, monkeypatch):
    # A sweep folder from before BPE resumes without rerunning anything: the runs it holds
    # are the experiment's runs less BPE's, with the same keys and flags.
    from routine_gym.experiments.paper import ablation

    def configs():
        return {e.run.key: e.run.config() for e in build("ablation", budget)
                if e.variant.get("discovery") != "BPE"}

    now = configs()
    bpe = [e for e in build("ablation", budget) if e.variant.get("discovery") == "BPE"]
    monkeypatch.setattr(ablation, "ABLATIONS",
                        {k: v for k, v in ablation.ABLATIONS.items() if k != "BPE"})
    assert configs() == now
    sizes = BUDGETS[budget]
    games = sizes.games if sizes.ablation_games is None else sizes.ablation_games
    assert len(bpe) == sizes.seeds * len(games)  # one BPE run per game and seed
    assert {dict(e.run.flags)["proposer"] for e in bpe} == {"bpe"}
    assert not {e.run.key for e in bpe} & set(now)


def test_scalability_varies_k_and_the_shortest_routine_length():
    flags = {tuple(sorted(e.variant.items())): dict(e.run.flags)
             for e in build("scalability", "cpu") if e.method == "MacroAction"
             and e.env_id == "MinAtar/Asterix-v1" and e.seed == 1}
    assert flags[(("K", 1), ("min_length", 2))]["num-routines"] == 1
    assert flags[(("K", 6), ("min_length", 2))]["num-routines"] == 6
    assert flags[(("K", 3), ("min_length", 5))]["min-routine-length"] == 5
    assert "num-routines" not in flags[(("K", 3), ("min_length", 2))]


def test_scalability_leaves_out_a_length_the_shipped_demo_has_no_routine_of():
    entries = build("scalability", "cpu")
    seaquest = {json.dumps(e.variant, sort_keys=True) for e in entries
                if e.env_id == "MinAtar/Seaquest-v1" and e.method == "RAPL-A2C"}
    assert seaquest == {'{"K": 1, "min_length": 2}', '{"K": 3, "min_length": 2}',
                        '{"K": 6, "min_length": 2}'}
    assert registry.left_out("scalability", "cpu") == [{
        "env_id": "MinAtar/Seaquest-v1", "variant": {"K": 3, "min_length": 5},
        "why": "its shipped demo has no routine of ≥ 5 actions"}]
    assert registry.left_out("scalability", "cpu", envs=["MinAtar/Breakout-v1"]) == []
    assert registry.left_out("rl", "cpu") == []


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"name": "nope", "budget": "cpu"},
     "unknown experiment 'nope'; choose from tune, imitation, rl"),
    ({"name": "rl", "budget": "huge"}, "unknown budget 'huge'; choose from smoke, cpu, paper"),
    ({"name": "rl", "budget": "cpu", "seeds": [4]}, "--seeds 4 is outside the cpu budget's seeds"),
    ({"name": "rl", "budget": "cpu", "envs": ["ALE/Pong-v5"]},
     r"--envs ALE/Pong-v5 is not a game of the rl experiment at the cpu budget \(its games: "
     r"MinAtar/Asterix-v1, MinAtar/Breakout-v1, .*MiniQbert-v0\)"),
    # A game of the budget, but not of this experiment: nothing would run.
    ({"name": "coinrun", "budget": "cpu", "envs": ["MinAtar/Breakout-v1"]},
     r"--envs MinAtar/Breakout-v1 is not a game of the coinrun experiment at the cpu budget "
     r"\(its games: procgen/CoinRun-v0\)"),
    ({"name": "curves", "budget": "cpu", "envs": ["MiniQbert-v0"]},
     "--envs MiniQbert-v0 is not a game of the curves experiment"),
    ({"name": "rl", "budget": "smoke", "envs": ["MinAtar/Breakout-v1", "MinAtar/Breakout"]},
     "--envs MinAtar/Breakout is not a game of the rl experiment at the smoke budget"),
    ({"name": "rl", "budget": "smoke", "seeds": [0]}, "--seeds 0 is outside the smoke budget's"),
])
def test_bad_experiment_requests_are_one_line_errors(kwargs, match):
    with pytest.raises(UsageError, match=match):
        build(**kwargs)


def test_seeds_and_envs_select_runs():
    entries = build("rl", "cpu", seeds=[2], envs=["MinAtar/Breakout-v1"])
    assert {(e.method, e.env_id, e.seed) for e in entries} == {
        (m, "MinAtar/Breakout-v1", 2)
        for m in ("A2C", "RAPL-A2C", "PPO", "RAPL-PPO", "MacroAction-PPO")}


def test_command_resolves_run_references_and_resumes_from_a_checkpoint(tmp_path):
    config = {"key": "aaaaaaaaaaaa", "script": "rapl_a2c",
              "flags": {"env-id": "MinAtar/Breakout-v1", "demo": "@run:bbbbbbbbbbbb/demo.npz",
                        "record-demo": "@self/demo.npz", "extra-evals": ["train", "hard"]}}
    words = backends.command(config, tmp_path, python="py")
    assert words[2:] == ["--env-id", "MinAtar/Breakout-v1",
                         "--demo", str(tmp_path / "bbbbbbbbbbbb" / "demo.npz"),
                         "--record-demo", str(tmp_path / "aaaaaaaaaaaa" / "demo.npz"),
                         "--extra-evals", "train", "hard",
                         "--run-dir", str(tmp_path / "aaaaaaaaaaaa"), "--torch-threads", "1"]
    assert words[1].endswith("algos/rapl_a2c.py")
    run = tmp_path / "aaaaaaaaaaaa" / "MinAtar-Breakout-v1__rapl_a2c-rapl__1__1"
    run.mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(b"")
    # Untracked (no `tracking`), a resume turns off the tracking a checkpoint may hold.
    assert backends.command(config, tmp_path, python="py")[2:] == ["--resume", str(run),
                                                                   "--no-track"]


# -- sweeps of real runs ---------------------------------------------------------------------------

def _results(out: Path) -> dict[str, float]:
    return {p.parent.name: p.stat().st_mtime for p in out.glob("runs/*/result.json")}


def _manifest_keys(out: Path, name: str) -> set[str]:
    return {r["key"] for r in json.loads((out / f"{name}.json").read_text())["runs"]}


def _sweep_all(out: Path, backend: str, names: tuple[str, ...] = SMOKE) -> io.StringIO:
    stream = io.StringIO()
    for name in names:
        summary = sweep.run_experiment(name, "smoke", out, jobs=2, backend=backend,
                                       stream=stream)
        assert summary.ok, (name, summary.failed)
    return stream


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("sweep") / "smoke"
    return out, _sweep_all(out, "local").getvalue()


@pytest.mark.slow
def test_smoke_sweep_of_all_seven_finishes_every_run(local_sweep):
    out, printed = local_sweep
    done = _results(out)
    for name in SMOKE:
        keys = _manifest_keys(out, name)
        assert keys and keys <= set(done), name
        for key in keys:
            result = json.loads((out / "runs" / key / "result.json").read_text())
            assert result["eval"]["episodes"] == BUDGETS["smoke"].eval_episodes
            assert (out / "runs" / key / result["run_dir"] / "eval.json").is_file()
    # CoinRun runs carry the training-level and hard-level evaluations too.
    for key in _manifest_keys(out, "coinrun"):
        result = json.loads((out / "runs" / key / "result.json").read_text())
        assert set(result["evals"]) == {"train", "hard"}
        assert result["evals"]["hard"]["env_kwargs"]["distribution_mode"] == "hard"
    # The ID expert recorded the demo the ID run mined.
    ablation = json.loads((out / "ablation.json").read_text())["runs"]
    (expert,) = [r for r in ablation if r["role"] == "expert"]
    assert (out / "runs" / expert["key"] / "demo.npz").is_file()
    assert "[ablation] runs 9/9 done, 0 running, 0 failed · agent steps 8,500/8,500" in printed
    # Every rapl_a2c run keeps its counters: at 1,000 steps (or decisions) of 4 envs × 5,
    # A2C and RAPL-A2C with the budget in decisions both make 50 updates of 20 decisions.
    rows = json.loads((out / "diagnosis.json").read_text())["runs"]
    counters = {(r["method"], r["variant"].get("diagnosis")):
                json.loads((out / "runs" / r["key"] / "result.json").read_text())["counters"]
                for r in rows}
    for which in (("A2C", None), ("RAPL-A2C", "decisions"), ("MacroAction", "decisions")):
        assert (counters[which]["updates"], counters[which]["decisions"]) == (50, 1000), which
    assert counters[("A2C", None)]["steps_per_decision"] == 1.0
    assert counters[("RAPL-A2C", "decisions")]["primitive_steps"] > 1000
    assert counters[("RAPL-A2C", None)]["updates"] < 50
    assert counters[("RAPL-A2C", None)]["bins"]["updates"][-1] == counters[("RAPL-A2C", None)][
        "updates"]
    assert "[diagnosis] runs 5/5 done" in printed
    # rl runs rapl_ppo.py's three modes beside A2C's, each to its evaluation; a run's
    # counters say which mode it was (PPO: one step a decision; the others chose routines).
    assert "[rl] runs 5/5 done, 0 running, 0 failed · agent steps 5,000/5,000" in printed
    rl = {r["method"]: json.loads((out / "runs" / r["key"] / "result.json").read_text())
          for r in json.loads((out / "rl.json").read_text())["runs"]}
    assert set(rl) == {"A2C", "RAPL-A2C", "PPO", "RAPL-PPO", "MacroAction-PPO"}
    for method, name, mode in (("PPO", "ppo", "ppo"), ("RAPL-PPO", "rapl-ppo", "rapl"),
                               ("MacroAction-PPO", "macro-ppo", "macro")):
        result = rl[method]
        assert result["eval"]["method"] == name, method
        assert result["run_dir"].split("__")[1] == f"rapl_ppo-{mode}", method
        assert result["counters"]["primitive_steps"] >= 1000
    assert rl["PPO"]["counters"]["steps_per_decision"] == 1.0
    assert rl["RAPL-PPO"]["counters"]["steps_per_decision"] > 1.0


@pytest.mark.slow
def test_rerunning_a_finished_sweep_is_a_no_op(local_sweep):
    out, _ = local_sweep
    before = _results(out)
    logs = {k: (out / "runs" / k / "log.txt").read_text() for k in before}
    stream = _sweep_all(out, "local")
    assert _results(out) == before
    assert {k: (out / "runs" / k / "log.txt").read_text() for k in before} == logs
    assert "0 to run" in stream.getvalue() and "runs 2/2 done" in stream.getvalue()


@pytest.mark.slow
def test_report_of_a_real_smoke_sweep_writes_seven_figures_csvs_and_report_md(local_sweep):
    out, _ = local_sweep
    proc = subprocess.run([*CLI, "experiment", "report", str(out)], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    report = out / "report"
    for stem in ("table1_imitation", "fig2_rl", "fig3_curves", "fig4_coinrun",
                 "fig5_scalability", "fig6_ablation", "diagnosis"):
        png = (report / f"{stem}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000, stem
        assert (report / f"{stem}.csv").read_text().count(",") >= 2, stem  # a header at least
    # Smoke runs are too short to score, but every run of the sweep is in the tables.
    rows = (report / "fig6_ablation.csv").read_text().splitlines()
    assert {r.split(",")[0] for r in rows[1:]} >= {"Full", "RR", "PbE", "RF", "ID", "RP", "BPE"}
    text = (report / "report.md").read_text()
    assert "Budget: **smoke**" in text
    for heading in ("Table 1", "Fig. 2", "Fig. 3", "Fig. 4", "Fig. 5", "Fig. 6", "Diagnosis"):
        assert f"## {heading} " in text
    assert "9 of 9 runs finished" in text


@pytest.mark.slow
def test_a_snapshot_keeps_results_not_checkpoints_and_continues_as_a_sweep(local_sweep,
                                                                          tmp_path):
    import shutil

    out, _ = local_sweep
    snapshot = REPO / "bench" / "snapshot_experiments.py"
    dest = tmp_path / "committed"
    proc = subprocess.run([sys.executable, str(snapshot), str(out), str(dest), "--command",
                           "routine-gym experiment run all --budget smoke"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "ablation     9/9 runs finished" in proc.stdout
    kept = {p.relative_to(dest).parts[2] for p in dest.glob("runs/*/*")}
    assert kept == {"config.json", "result.json", "demo.npz"}  # no logs, no checkpoints
    # The report is drawn from the copy: it names the snapshot, not the sweep folder.
    assert (dest / "report" / "report.md").read_text().startswith(
        f"# routine-gym report: `{dest}`\n")
    assert {p.parent.name for p in dest.glob("runs/*/result.json")} == set(_results(out))
    provenance = json.loads((dest / "provenance.json").read_text())
    assert provenance["experiments"]["rl"] == {"runs": 5, "finished": 5}
    assert len(provenance["snapshots"]) == 1
    # A new machine continues from the snapshot: nothing is rerun, and Fig. 3 is drawn from
    # the curves kept in result.json (the TensorBoard logs stayed behind).
    again = tmp_path / "again"
    shutil.copytree(dest, again)
    assert "0 to run" in _sweep_all(again, "local").getvalue()
    assert not list(again.glob("runs/*/*/events.out.tfevents.*"))
    report_mod.write_report(again, reps=100)
    report_mod.write_report(out, reps=100)
    curves = (out / "report" / "fig3_curves.csv").read_text()
    assert (again / "report" / "fig3_curves.csv").read_text() == curves
    assert curves.count("\n") == 1 + 5 * training_curves.CURVE_BINS  # every method has its curve
    # Snapshotting a sweep that did not start from the snapshot would lose its results.
    proc = subprocess.run([sys.executable, str(snapshot), str(tmp_path / "fresh"), str(dest)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 1
    assert proc.stderr.strip().endswith("before snapshotting it")
    assert "finished run(s) that" in proc.stderr and proc.stderr.count("\n") == 1


@pytest.mark.slow
def test_smoke_sweeps_through_a_real_local_ray_instance(tmp_path, monkeypatch):
    # The local sweep above runs all seven; through Ray, what differs in kind: a run that waits
    # on another (the ablation's expert and an ID run that mines the expert's demo). To Ray a run
    # is a command, so the local sweep covers the other flags; the kill test below sweeps rl's
    # runs of both RAPL scripts through Ray, on an instance it starts itself. Here the sweep
    # joins the instance its process already has.
    ray = pytest.importorskip("ray")
    real_build = sweep.build

    def expert_and_one_follower(*args, **kwargs):
        entries = real_build(*args, **kwargs)
        (expert,) = [e for e in entries if e.role == "expert"]
        follower = next(e for e in entries if expert.run.key in e.run.needs)
        return [follower, expert]  # the follower first: the sweep must still wait for it

    monkeypatch.setattr(sweep, "build", expert_and_one_follower)
    out = tmp_path / "ray"
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             configure_logging=False)
    try:
        printed = _sweep_all(out, "ray", ("ablation",)).getvalue()
        assert len(_manifest_keys(out, "ablation")) == 2
        assert _manifest_keys(out, "ablation") <= set(_results(out))
        assert "[ablation] runs 2/2 done, 0 running, 0 failed" in printed
        before = _results(out)
        _sweep_all(out, "ray", ("ablation",))  # again: nothing is redone
        assert _results(out) == before
    finally:
        ray.shutdown()


def _children_of(pid: int) -> list[int]:
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                stat = (proc / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(proc.name))
    return found


def _script_processes() -> list[str]:
    """The command lines of the processes running a script of `algos/`."""
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                line = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if "/algos/" in line:
                found.append(line)
    return found


@pytest.mark.slow
@pytest.mark.parametrize(("backend", "how"), [("local", signal.SIGKILL),
                                               ("ray", signal.SIGTERM)])
def test_a_killed_sweep_resumes_without_redoing_finished_runs(tmp_path, backend, how):
    if backend == "ray":
        pytest.importorskip("ray")
    # rl at smoke: 5 runs of both RAPL scripts (the Ray smoke test has runs that wait on others).
    out = tmp_path / "killed"
    cmd = [*CLI, "experiment", "run", "rl", "--budget", "smoke", "--out", str(out),
           "--jobs", "2", "--backend", backend]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 240
    while len(_results(out)) < 2 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert proc.poll() is None, "the sweep ended before it could be killed"
    children = _children_of(proc.pid)
    os.kill(proc.pid, how)
    proc.wait(timeout=60)
    time.sleep(1.0)
    # Its runs died with it (none is left writing into the folder).
    assert not [p for p in _script_processes() if str(out) in p]
    assert all(not Path(f"/proc/{c}").exists() or "zombie" in Path(f"/proc/{c}/status")
               .read_text().lower() for c in children)
    finished = _results(out)
    assert 2 <= len(finished) < 5
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    assert f"{len(finished)} finished before" in rerun.stdout
    after = _results(out)
    assert set(after) >= _manifest_keys(out, "rl")
    assert {k: after[k] for k in finished} == finished  # not redone


def test_a_failed_run_is_reported_and_the_others_go_on(tmp_path, monkeypatch):
    bad = RunSpec("rapl_a2c", (("env-id", "NoSuchEnv-v0"), ("total-timesteps", 10)), 10)
    after_bad = RunSpec("rapl_a2c", (("env-id", "MiniQbert-v0"), ("total-timesteps", 100),
                                     ("mode", "a2c"), ("eval-episodes", 1),
                                     ("demo", f"@run:{bad.key}/demo.npz")), 100, (bad.key,))
    good = RunSpec("rapl_a2c", (("env-id", "MiniQbert-v0"), ("total-timesteps", 100),
                                ("mode", "a2c"), ("eval-episodes", 1)), 100)
    entries = [specs.Entry(r, "A2C", "MiniQbert-v0", 1) for r in (bad, after_bad, good)]
    monkeypatch.setattr(sweep, "build", lambda *a, **k: entries)
    stream = io.StringIO()
    summary = sweep.run_experiment("rl", "smoke", tmp_path, jobs=2, stream=stream)
    assert summary.finished == [good.key]
    assert "NoSuchEnv-v0" in summary.failed[bad.key] and "exit code 2" in summary.failed[bad.key]
    assert summary.failed[after_bad.key] == f"needs run {bad.key}, which failed"
    assert not (tmp_path / "runs" / after_bad.key / "log.txt").exists()  # never started
    assert f"failed {bad.key} (rapl_a2c): exit code 2" in stream.getvalue()


def test_an_out_folder_holds_one_budget_per_experiment(tmp_path, monkeypatch):
    good = RunSpec("rapl_a2c", (("env-id", "MiniQbert-v0"), ("total-timesteps", 100),
                                ("mode", "a2c"), ("eval-episodes", 1)), 100)
    monkeypatch.setattr(sweep, "build",
                        lambda *a, **k: [specs.Entry(good, "A2C", "MiniQbert-v0", 1)])
    assert sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO()).ok
    with pytest.raises(UsageError, match="already holds experiment rl at budget smoke"):
        sweep.run_experiment("rl", "cpu", tmp_path, stream=io.StringIO())


@pytest.mark.parametrize(("argv", "message"), [
    (["run", "rl", "--budget", "huge", "--out", "X"], "unknown budget 'huge'"),
    (["run", "rl", "--budget", "smoke", "--out", "X", "--backend", "slurm"],
     "--backend needs to be local or ray, actual value: slurm"),
    (["run", "rl", "--budget", "smoke", "--out", "X", "--address", "h:1"],
     "--address joins a Ray cluster: it needs --backend ray"),
    (["report", "nowhere"], "nowhere"),
])
def test_cli_errors_are_one_line(tmp_path, argv, message):
    proc = subprocess.run([*CLI, "experiment", *argv], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 2
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert not (tmp_path / "X").exists()


def test_cli_list_shows_every_experiment_with_its_runs_per_budget():
    proc = subprocess.run([*CLI, "experiment", "list"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = {line.split()[0]: line for line in proc.stdout.splitlines() if line[:1].isalpha()}
    for name in SMOKE:
        assert name in rows
    assert "90 runs 90.0M steps" in rows["rl"] and "325 runs" in rows["rl"]
    assert "125 runs" in rows["ablation"]
    assert "90 runs 90.0M steps" in rows["diagnosis"]


def test_a_sweep_of_some_seeds_lists_the_whole_experiment(tmp_path, monkeypatch):
    ran = []
    monkeypatch.setattr(sweep, "LocalBackend", lambda jobs: _NoRuns(ran))
    sweep.run_experiment("rl", "cpu", tmp_path, seeds=[1], envs=["MinAtar/Breakout-v1"],
                         stream=io.StringIO())
    manifest = json.loads((tmp_path / "rl.json").read_text())
    assert len(manifest["runs"]) == 90  # the whole experiment: the report counts the rest
    assert len(ran) == 5  # only A2C, RAPL-A2C and the three PPO runs, seed 1, Breakout ran


class _NoRuns:
    """A backend that records what it was asked to run and finishes it at once."""

    def __init__(self, ran: list) -> None:
        self.ran = ran

    def submit(self, config, runs, cuda):
        self.ran.append(config["key"])
        return config["key"]

    def wait(self, handles, timeout):
        return [(h, {"key": h}) for h in handles]

    def close(self):
        pass
