"""The `long` budget (issue 28): the rl experiment alone at the paper's 10^7 agent steps on
MinAtar's five games, 3 seeds, with RAPL-A2C as the authors' code beside A2C and RAPL-A2C; the
other experiments have no runs there. Also each run's provenance (wall time, machine) in its
`result.json`, and `bench/sweep_long.sh`."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from one_line import assert_one_line_error

from routine_gym.errors import UsageError
from routine_gym.experiments import backends, provenance, reference, registry, report, sweep
from routine_gym.experiments.paper import diagnosis
from routine_gym.experiments.paper.diagnosis import AUTHORS
from routine_gym.experiments.specs import BUDGETS, MINATAR

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent  # the venv a user installs into
OTHERS = ["imitation", "curves", "coinrun", "scalability", "ablation", "diagnosis"]


def _user(*words: str, cwd: Path) -> subprocess.CompletedProcess:
    """A command as a user's shell runs it: PATH with the venv's bin first, HOME, nothing else."""
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    return subprocess.run(list(words), cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=300, stdin=subprocess.DEVNULL)


# -- the runs ------------------------------------------------------------------------------------

def test_long_budget_of_rl_is_45_runs_of_ten_million_steps():
    entries = registry.build("rl", "long")
    # 5 games × 3 seeds × {A2C, RAPL-A2C, RAPL-A2C as the authors' code} = 45; MinAtar's demos
    # ship, so no expert runs first.
    assert len(entries) == len({e.run.key for e in entries}) == 45
    assert {e.env_id for e in entries} == set(MINATAR) and len(MINATAR) == 5
    assert "MiniQbert-v0" not in {e.env_id for e in entries}
    assert Counter(diagnosis.label(e) for e in entries) == {
        "A2C": 15, "RAPL-A2C": 15, AUTHORS: 15}
    assert {e.seed for e in entries} == {1, 2, 3} and {e.role for e in entries} == {"main"}
    for e in entries:
        flags = dict(e.run.flags)
        assert e.run.steps == flags["total-timesteps"] == 10_000_000
        assert flags["checkpoint-every"] == 1_000_000  # a tenth of the run
        assert e.run.needs == ()
    assert registry.count_runs("rl", "long") == (45, 450_000_000)


def _flags_at_long(flags: dict) -> dict:
    """A cpu-budget run's flags with the long budget's steps and checkpoint interval."""
    return {**flags, "total-timesteps": 10_000_000, "checkpoint-every": 1_000_000}


def test_long_runs_are_the_cpu_budgets_runs_with_only_the_steps_changed():
    long = {(diagnosis.label(e), e.env_id, e.seed): dict(e.run.flags)
            for e in registry.build("rl", "long")}
    rl_cpu = {(e.method, e.env_id, e.seed): dict(e.run.flags)
              for e in registry.build("rl", "cpu")}
    authors_cpu = {(AUTHORS, e.env_id, e.seed): dict(e.run.flags)
                   for e in registry.build("diagnosis", "cpu")
                   if diagnosis.label(e) == AUTHORS}
    for label, env_id, seed in long:
        cpu = (authors_cpu if label == AUTHORS else rl_cpu)[(label, env_id, seed)]
        assert long[(label, env_id, seed)] == _flags_at_long(cpu), (label, env_id, seed)
    breakout = long[(AUTHORS, "MinAtar/Breakout-v1", 2)]
    assert breakout["authors"] is True and breakout["mode"] == "rapl"


def test_a_checkpoint_every_tenth_at_long_and_every_fifth_elsewhere():
    assert BUDGETS["long"].checkpoint_every(10**7) == 10**6
    assert BUDGETS["cpu"].checkpoint_every(10**6) == 200_000
    assert BUDGETS["paper"].checkpoint_every(10**7) == 2_000_000
    assert BUDGETS["smoke"].checkpoint_every(1_000) == 200
    assert BUDGETS["smoke"].checkpoint_every(3) == 1  # never 0 (0 means no checkpoints)


# -- the other experiments ---------------------------------------------------------------------

@pytest.mark.parametrize("name", OTHERS)
def test_other_experiments_have_no_runs_at_long(name):
    assert not registry.available(name, "long") and registry.available(name, "cpu")
    with pytest.raises(UsageError, match=f"the long budget has no runs of the {name} "
                                         "experiment \\(it holds rl only\\)"):
        registry.build(name, "long")


def test_all_at_long_plans_rl_alone():
    assert sweep.plan("all", "long") == [("rl", None)]
    assert sweep.plan("all", "long", envs=["MinAtar/Seaquest-v1"]) == [
        ("rl", ["MinAtar/Seaquest-v1"])]


def test_experiment_list_as_a_user_shows_the_long_budget(tmp_path):
    proc = _user(str(BIN / "routine-gym"), "experiment", "list", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert lines[0].split() == ["experiment", "figure", "smoke", "cpu", "paper", "long",
                                "smoke-fair", "fair", "fair-long"]
    rows = {line.split()[0]: line for line in lines[1:] if line[:1].isalpha()}

    def long_cell(row: str) -> str:  # name (12) and figure (8), then cells of 22 + 2 spaces
        return row[22 + 3 * 24: 22 + 4 * 24].strip()

    assert long_cell(rows["rl"]) == "45 runs 450.0M steps"
    for name in OTHERS:
        assert long_cell(rows[name]) == "–", rows[name]
    assert "Traceback" not in proc.stderr
    assert any(line.startswith("long   the paper's 10^7 agent steps on MinAtar's five games, "
                               "rl only") for line in lines)


def test_an_experiment_without_runs_at_long_is_a_one_line_error(tmp_path):
    proc = _user(str(BIN / "routine-gym"), "experiment", "run", "ablation", "--budget", "long",
                 "--out", "X", cwd=tmp_path)
    assert_one_line_error(proc, "the long budget has no runs of the ablation experiment",
                          "run ablation at smoke, cpu, paper", prefix="routine-gym: error: ")
    assert not (tmp_path / "X").exists()


# -- the report ------------------------------------------------------------------------------

def test_rl_report_keeps_the_authors_code_apart_from_rapl(tmp_path, monkeypatch):
    breakout = "MinAtar/Breakout-v1"  # demo-normalised: random 0, demo 10
    monkeypatch.setattr(reference, "demo_score", {breakout: 10.0}.get)
    monkeypatch.setattr(reference, "random_policy_scores", lambda *a: {"mean": 0.0})
    scores = {("A2C", ()): (4.0, 6.0), ("RAPL-A2C", ()): (6.0, 8.0),
              ("RAPL-A2C", (("diagnosis", "authors"),)): (2.0, 4.0)}
    rows = []
    for n, ((method, variant), pair) in enumerate(scores.items()):
        for seed, score in enumerate(pair, start=1):
            key = f"{n:06d}{seed:06d}"
            rows.append({"key": key, "script": "rapl_a2c", "method": method,
                         "env_id": breakout, "seed": seed, "variant": dict(variant),
                         "role": "main", "steps": 100})
            folder = tmp_path / "runs" / key
            folder.mkdir(parents=True)
            (folder / "result.json").write_text(json.dumps(
                {"key": key, "eval": {"mean_return": score, "returns": [score]},
                 "finished": "2026-12-04T10:00:00Z"}))
    (tmp_path / "rl.json").write_text(json.dumps(
        {"experiment": "rl", "version": 2, "budget": "long", "description": "test",
         "runs": rows}))
    report.write_report(tmp_path, reps=50)
    with open(tmp_path / "report" / "fig2_rl.csv", newline="") as f:
        (row,) = list(csv.DictReader(f))
    # A2C 4, 6 → S_A 5; RAPL-A2C 6, 8 → S_R 7: +40 % (with the authors' 2 and 4 in it,
    # S_R would be 5: 0 %).
    assert float(row["S_R"]) == 7.0 and row["runs_rapl"] == "2"
    assert float(row["relative_performance_pct"]) == pytest.approx(40.0)
    text = (tmp_path / "report" / "report.md").read_text()
    # The authors' code: 2, 4 → S 3, (3 − 5)/5 = −40 %; s.e. 1 (std √2 / √2) → 1/5 = 20 %.
    assert f"| {breakout} | 2 | 5.00 | 3.00 | -40.0 % | 20.0 % |" in text
    assert "P(X > Y)" in text and f"| {AUTHORS} > A2C |" in text


# -- provenance -------------------------------------------------------------------------------

def _fake_run(monkeypatch, folder: Path, resumed: bool, sleep: float = 0.0) -> None:
    """`execute_run` starts a process that sleeps and writes an `eval.json`, as a script
    (resumed from a checkpoint or not) would."""
    code = (f"import json, os, time; time.sleep({sleep}); os.makedirs('run', exist_ok=True); "
            "json.dump({'mean_return': 1.0, 'returns': [1.0]}, open('run/eval.json', 'w'))")
    words = [sys.executable, "-c", code, *(["--resume"] if resumed else [])]
    monkeypatch.setattr(backends, "command", lambda config, runs, cuda=False: words)


def test_result_json_records_the_wall_time_and_the_machine(tmp_path, monkeypatch):
    monkeypatch.setattr(backends, "NOTE_EVERY", 0.05)  # notes while the process runs
    folder = tmp_path / "runs" / "aaaaaaaaaaaa"
    folder.mkdir(parents=True)
    _fake_run(monkeypatch, folder, resumed=False, sleep=0.3)
    config = {"key": "aaaaaaaaaaaa", "script": "rapl_a2c", "flags": {}, "steps": 0}
    result = backends.execute_run(config, str(tmp_path / "runs"))
    record = result["provenance"]
    assert json.loads((folder / "result.json").read_text())["provenance"] == record
    assert 0.3 <= record["wall_seconds"] < 30 and len(record["attempts"]) == 1
    assert record["attempts"][0]["resumed"] is False
    machine = record["machine"]
    assert machine == provenance.machine() and machine["cores"] >= 1 and machine["host"]


def test_wall_time_adds_the_resumes_to_the_last_fresh_start(tmp_path, monkeypatch):
    folder = tmp_path / "runs" / "bbbbbbbbbbbb"
    folder.mkdir(parents=True)
    # Killed before its first checkpoint (50 s, started over), then killed after one (3,600 s).
    (folder / "attempts.json").write_text(json.dumps({"attempts": [
        {"started": "2026-12-04T00:00:00Z", "resumed": False, "seconds": 50.0, "machine": {}},
        {"started": "2026-12-04T00:01:00Z", "resumed": False, "seconds": 3600.0,
         "machine": {"host": "elsewhere"}}]}))
    _fake_run(monkeypatch, folder, resumed=True)
    start = time.time()
    config = {"key": "bbbbbbbbbbbb", "script": "rapl_a2c", "flags": {}, "steps": 0}
    record = backends.execute_run(config, str(tmp_path / "runs"))["provenance"]
    this = record["attempts"][-1]["seconds"]
    assert [a["resumed"] for a in record["attempts"]] == [False, False, True]
    assert 0 <= this <= time.time() - start + 0.1
    assert record["wall_seconds"] == pytest.approx(3600.0 + this, abs=0.11)
    assert record["machine"]["host"] != "elsewhere"  # the machine that finished it


def test_wall_seconds_by_hand():
    assert provenance.wall_seconds([{"resumed": False, "seconds": 50.0},
                                    {"resumed": False, "seconds": 3600.0},
                                    {"resumed": True, "seconds": 1800.5}]) == 5400.5
    # No fresh start noted (its record was started afresh): every attempt noted counts.
    assert provenance.wall_seconds([{"resumed": True, "seconds": 7.0},
                                    {"resumed": True, "seconds": 2.5}]) == 9.5


# -- the sweep script -------------------------------------------------------------------------

def test_sweep_long_runs_rl_at_the_long_budget_niced(tmp_path):
    # PYTHON=echo prints the command it would run: nothing trains.
    proc = subprocess.run([str(REPO / "bench" / "sweep_long.sh"), str(tmp_path / "S"), "3"],
                          env={"PATH": "/usr/bin:/bin", "PYTHON": "echo"},
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert (f"-m routine_gym.cli experiment run rl --budget long --out {tmp_path / 'S'} "
            "--jobs 3") in proc.stdout
    assert "3 at a time, nice 10" in proc.stdout


def test_the_docstring_examples_hold():
    import doctest

    from routine_gym.experiments import specs

    for module in (provenance, specs):
        assert doctest.testmod(module).failed == 0, module.__name__


def test_the_committed_long_snapshot_has_every_run_finished_with_its_provenance():
    snapshot = REPO / "bench" / "results" / "experiments" / "long"
    built = {e.run.key: e for e in registry.build("rl", "long")}
    rows = json.loads((snapshot / "rl.json").read_text())["runs"]
    assert sorted(row["key"] for row in rows) == sorted(built) and len(rows) == 45
    for row in rows:
        assert row == built[row["key"]].manifest(), row["key"]
        result = json.loads((snapshot / "runs" / row["key"] / "result.json").read_text())
        assert result["finished"], row["key"]
        assert result["curve"]["total_steps"] == 10_000_000, row["key"]
        prov = result["provenance"]
        assert prov["wall_seconds"] > 0 and prov["machine"]["cores"] >= 1, row["key"]
        assert sum(a["seconds"] for a in prov["attempts"]) == pytest.approx(
            prov["wall_seconds"], abs=1.0), row["key"]
    assert json.loads((snapshot / "provenance.json").read_text())["experiments"]["rl"] == {
        "runs": 45, "finished": 45}
