"""A tuning grid's point whose run diverges is an answer, not a fault: the script exits with
code 3 (`routine_gym.plumbing.divergence.EXIT_CODE`), the sweep records `diverged.json`, the
point loses the choice (`derived`'s `tuned` rule scores the run -inf), the runs it decides start,
and a second sweep does not train it again. A divergence anywhere else fails as before."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import pytest

from routine_gym.errors import UsageError
from routine_gym.experiments import sweep
from routine_gym.experiments.derived import derived_flags, grid_keys
from routine_gym.experiments.paper import tune
from routine_gym.experiments.results import divergence, load_runs
from routine_gym.experiments.specs import Entry, RunSpec
from routine_gym.experiments.writing import Writer

GAME = "MinAtar/Breakout-v1"


def _record(runs: Path, key: str, score: float | None) -> None:
    """A finished run (its score) or, with None, one that diverged."""
    folder = runs / key
    folder.mkdir(parents=True)
    if score is None:
        (folder / "diverged.json").write_text(json.dumps(
            {"key": key, "error": "rapl_a2c.py: error: training stopped at step 64: ..."}))
    else:
        (folder / "result.json").write_text(json.dumps({"key": key,
                                                        "eval": {"mean_return": score}}))


def _tuned(*points):
    return [["tuned", [[[["learning-rate", lr]], keys] for lr, keys in points]]]


def test_a_point_with_a_run_that_diverged_loses_the_choice(tmp_path):
    # 0.0007: 2 and 4, mean 3; 0.0014: 9 and a divergence, mean -inf; 0.0028: 1 and 1.
    for key, score in (("a1", 2.0), ("a2", 4.0), ("b1", 9.0), ("b2", None), ("c1", 1.0),
                       ("c2", 1.0)):
        _record(tmp_path, key, score)
    derived = _tuned((7e-4, ["a1", "a2"]), (1.4e-3, ["b1", "b2"]), (2.8e-3, ["c1", "c2"]))
    assert derived_flags(derived, tmp_path) == {"learning-rate": 7e-4}
    assert grid_keys(derived) == ("a1", "a2", "b1", "b2", "c1", "c2")
    # every point with a divergence: no setting can be chosen, said in one line
    _record(tmp_path, "d1", None)
    with pytest.raises(UsageError, match="every grid point has a run that diverged"):
        derived_flags(_tuned((7e-4, ["b2"]), (1.4e-3, ["d1"])), tmp_path)
    # another rule cannot use a diverged run
    with pytest.raises(UsageError, match="run b2 diverged"):
        derived_flags([["updates-of", [5, ["b2"]]]], tmp_path)


def test_divergence_reads_the_record_until_the_run_finishes(tmp_path):
    _record(tmp_path, "x", None)
    assert divergence(tmp_path / "x").startswith("rapl_a2c.py: error: training stopped")
    assert divergence(tmp_path / "nothing") is None
    (tmp_path / "x" / "result.json").write_text("{}")  # finished since: no longer diverged
    assert divergence(tmp_path / "x") is None
    (tmp_path / "y").mkdir()
    (tmp_path / "y" / "diverged.json").write_text('{"error": 3}')
    with pytest.raises(UsageError, match="diverged.json: `error` is 3, not the run's report"):
        divergence(tmp_path / "y")


def _entry(lr: float, anneal: bool, role: str, *, scale: float | None = None,
           derived=(), needs=()) -> Entry:
    flags = {"env-id": GAME, "seed": 101, "total-timesteps": 1000, "eval-episodes": 1,
             "seed-stride": 1000, "mode": "a2c", "num-envs": 4}
    if lr:
        flags |= {"learning-rate": lr, "anneal-lr": anneal}
    if scale is not None:
        flags["reward-scale"] = scale
    run = RunSpec("rapl_a2c", tuple(flags.items()), 1000, needs=tuple(needs),
                  derived=tuple(derived))
    variant = {"learning_rate": lr, "anneal_lr": anneal} if lr else {}
    return Entry(run, "A2C", GAME, 1, variant, role)


def _sweep(name: str, out: Path, entries: list[Entry]) -> tuple[sweep.SweepSummary, str]:
    stream = io.StringIO()
    (out / "runs").mkdir(parents=True, exist_ok=True)  # as `run_experiment` makes it
    summary = sweep._sweep(name, "smoke-fair", out, entries, jobs=2, backend="local", address=None,
                           whole=False, cuda=False, cpus_per_run=1, stream=stream, poll=0.2)
    return summary, stream.getvalue()


def test_a_sweep_goes_on_past_a_diverged_grid_point_and_fails_any_other_divergence(tmp_path):
    out = tmp_path / "sweep"
    # Two points of A2C's grid; the second's rewards scaled by 1e30 make its value loss inf
    # within the first updates.
    good, bad = _entry(7e-4, True, "main"), _entry(1.4e-3, False, "main", scale=1e30)
    summary, printed = _sweep("tune", out, [good, bad])
    assert summary.ok and summary.finished == [good.run.key], printed
    assert list(summary.diverged) == [bad.run.key]
    # the diverged run's steps are not counted, as done or to do
    assert ("runs 1/2 done, 0 running, 0 failed, 1 diverged (grid points) · agent steps "
            "1,000/1,000 · ") in printed
    record = json.loads((out / "runs" / bad.run.key / "diverged.json").read_text())
    assert record["error"].startswith("rapl_a2c.py: error: training stopped at ")
    assert not (out / "runs" / bad.run.key / "result.json").exists()

    # The tune report: the diverged point shown so, the other chosen.
    runs = load_runs(out, "tune").runs
    assert {r.key: r.diverged is not None for r in runs} == {good.run.key: False,
                                                              bad.run.key: True}
    text = "\n".join(tune.section(Writer(tmp_path, references={}, reps=10, seed=0), runs))
    assert "| A2C | MinAtar/Breakout-v1 | 0.0014 | constant | diverged | diverged |  |" in text
    assert "| A2C | MinAtar/Breakout-v1 | 0.0007 | annealed |" in text
    assert text.count("**chosen**") == 1 and (tmp_path / "tune.png").stat().st_size > 0
    (chosen,) = [row for row in text.splitlines() if "**chosen**" in row]
    assert "| 0.0007 | annealed |" in chosen
    assert tune.choices(runs)[("A2C", GAME)]["points"][1][2] == [-math.inf]

    # rl: a run tuned over both points learns with the one that finished; a run outside the
    # grid that diverges fails; the diverged point is not trained again.
    points = [(((("learning-rate", 7e-4), ("anneal-lr", True))), (good.run.key,)),
              (((("learning-rate", 1.4e-3), ("anneal-lr", False))), (bad.run.key,))]
    tuned = _entry(0, True, "main", derived=(("tuned", tuple(points)),),
                   needs=(good.run.key, bad.run.key))
    lone = _entry(7e-4, False, "main", scale=1e30)
    grid = [Entry(e.run, e.method, e.env_id, e.seed, e.variant, "tune") for e in (good, bad)]
    summary, printed = _sweep("rl", out, [*grid, tuned, lone])
    assert "1 finished before, 1 grid point(s) diverged before, 2 to run" in printed
    assert summary.finished == [tuned.run.key], printed
    assert list(summary.failed) == [lone.run.key]
    assert summary.failed[lone.run.key].startswith("diverged: rapl_a2c.py: error: training ")
    assert list(summary.diverged) == [bad.run.key] and not summary.ok
    log = (out / "runs" / tuned.run.key / "log.txt").read_text()
    assert "--learning-rate 0.0007 --anneal-lr" in log
    assert (out / "runs" / bad.run.key / "log.txt").read_text().count("\n# ") == 0  # once


def test_a_run_whose_every_grid_point_diverged_fails_in_one_line_without_a_process(tmp_path):
    from routine_gym.experiments.backends import execute_run

    runs = tmp_path / "runs"
    _record(runs, "b2", None)
    _record(runs, "d1", None)
    config = {"key": "tuned000001", "script": "rapl_a2c", "steps": 1000, "needs": ["b2", "d1"],
              "flags": {"env-id": GAME, "mode": "a2c"},
              "derived": _tuned((7e-4, ["b2"]), (1.4e-3, ["d1"]))}
    (runs / "tuned000001").mkdir()
    outcome = execute_run(config, str(runs))
    assert outcome == {"key": "tuned000001", "error": (
        "cannot choose a tuned setting: every grid point has a run that diverged (runs b2, d1); "
        "a grid whose every point diverges needs lower rates, or delete the runs' "
        "diverged.json to train them again")}
    assert not (runs / "tuned000001" / "log.txt").exists()  # no process was started
