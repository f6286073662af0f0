"""The rl experiment at two budgets side by side (`routine-gym experiment report SWEEP --beside
OTHER`, `routine_gym.experiments.budget_comparison`): two hand-made sweep folders with
hand-chosen scores, curves and counters, and the CSV numbers worked out by hand.

The shorter sweep (budget `cpu`, 1,000 steps) has A2C and RAPL-A2C on Breakout, Asterix and
Seaquest and the authors' code on Breakout in its diagnosis experiment (as the real cpu sweep
has it); the longer one (budget `long`, 10,000 steps) has Breakout finished, Asterix partly
(one A2C run) and no Seaquest, with the authors' code in its rl experiment.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from one_line import assert_one_line_error

from routine_gym.experiments import budget_comparison as bc
from routine_gym.experiments import report
from routine_gym.experiments.reference import REFERENCE_EPISODES, REFERENCE_SEED
from routine_gym.experiments.training_curves import CURVE_BINS
from routine_gym.plumbing.errors import UsageError

BREAKOUT, ASTERIX, SEAQUEST = "MinAtar/Breakout-v1", "MinAtar/Asterix-v1", "MinAtar/Seaquest-v1"
SHORT, LONG = 1_000, 10_000
AUTHORS = {"diagnosis": "authors"}
REPS = 50
CLI = Path(sys.executable).parent / "routine-gym"


class Sweep:
    """A sweep folder as `routine-gym experiment run` leaves it, run by run."""

    def __init__(self, out: Path, budget: str, steps: int) -> None:
        self.out, self.budget, self.steps = out, budget, steps
        self.manifests: dict[str, list[dict]] = {}

    def run(self, method: str, env_id: str, seed: int, score: float | None, *,
            experiment: str = "rl", variant: dict | None = None, updates: int = 0,
            per_decision: float = 1.0, curve: float = 0.0,
            shares: tuple[float, list[float]] | None = None) -> None:
        """One run: `score=None` leaves it unfinished; `curve`: its return in every bin;
        `updates`: its total, made at an even pace; `shares`: (primitive share, each
        routine's share) in every bin."""
        variant = variant or {}
        tag = "".join(f"-{v}" for v in variant.values())
        key = f"{self.budget}-{experiment}-{method[:4]}{tag}-{env_id[8:12]}-{seed}"
        self.manifests.setdefault(experiment, []).append(
            {"key": key, "script": "rapl_a2c", "method": method, "env_id": env_id,
             "seed": seed, "variant": variant, "role": "main", "steps": self.steps})
        if score is None:
            return
        folder = self.out / "runs" / key
        folder.mkdir(parents=True, exist_ok=True)
        primitive, routines = shares or (1.0, [])
        bins = {"total_steps": self.steps, "bins": CURVE_BINS,
                "updates": [round(updates * (b + 1) / CURVE_BINS) for b in range(CURVE_BINS)],
                "steps_per_decision": [per_decision] * CURVE_BINS,
                "primitive_share": [primitive] * CURVE_BINS,
                "shares": [[share] * CURVE_BINS for share in routines]}
        (folder / "result.json").write_text(json.dumps({
            "key": key, "eval": {"mean_return": score, "returns": [score]},
            "curve": {"total_steps": self.steps, "bins": CURVE_BINS,
                      "sums": [curve] * CURVE_BINS, "counts": [1] * CURVE_BINS},
            "finished": "2026-12-04T10:00:00Z",
            "counters": {"updates": updates, "decisions": int(self.steps / per_decision),
                         "steps_per_decision": per_decision, "primitive_share": primitive,
                         "shares": routines, "bins": bins}}))

    def write(self) -> Path:
        for experiment, runs in self.manifests.items():
            (self.out / f"{experiment}.json").write_text(json.dumps(
                {"experiment": experiment, "version": 2, "budget": self.budget,
                 "description": "test", "runs": runs}))
        # The random policy's scores, cached: the report plays no game.
        (self.out / "report").mkdir(exist_ok=True)
        (self.out / "report" / "reference_scores.json").write_text(json.dumps(
            {"episodes": REFERENCE_EPISODES, "seed": REFERENCE_SEED,
             "envs": {g: {"random": 0.5} for g in (BREAKOUT, ASTERIX, SEAQUEST)}}))
        return self.out


def _short(out: Path) -> Path:
    s = Sweep(out, "cpu", SHORT)
    # Breakout: A2C 4, 6 (S_A 5 ± 1); RAPL 2, 4 (S_R 3 ± 1): −40 % ± 20 %, worse (3 < 5 − 1).
    for seed, a, r in ((1, 4, 2), (2, 6, 4)):
        s.run("A2C", BREAKOUT, seed, a, updates=100, curve=seed + 2)  # curves 3 and 4
        s.run("RAPL-A2C", BREAKOUT, seed, r, updates=30 + 10 * seed, per_decision=1.5 + seed / 2,
              curve=1.0, shares=((0.5, [0.3, 0.2]) if seed == 1 else (0.7, [0.1, 0.2])))
    # The authors' code, from the diagnosis experiment: 5, 7 (6 ± 1): +20 % ± 20 %, same.
    for seed, x in ((1, 5), (2, 7)):
        s.run("RAPL-A2C", BREAKOUT, seed, x, experiment="diagnosis", variant=AUTHORS,
              updates=20, per_decision=3.0)
    # Asterix: A2C 10, 10 (10 ± 0); RAPL 8, 9 (8.5 ± 0.5): −15 % ± 5 %, worse.
    # Seaquest: A2C 2, 2; RAPL 1, 1: −50 % ± 0 %, worse.
    for seed in (1, 2):
        s.run("A2C", ASTERIX, seed, 10, updates=100)
        s.run("RAPL-A2C", ASTERIX, seed, 7 + seed, updates=50)
        s.run("A2C", SEAQUEST, seed, 2, updates=100)
        s.run("RAPL-A2C", SEAQUEST, seed, 1, updates=50)
    return s.write()


def _long(out: Path) -> Path:
    s = Sweep(out, "long", LONG)
    # Breakout: A2C 6, 8 (7 ± 1); RAPL 10, 10 (10 ± 0): +42.86 % ± 0 %, better (7 < 10 − 1);
    # the authors' code 7, 7: 0 % ± 0 %, same.
    for seed, a in ((1, 6), (2, 8)):
        s.run("A2C", BREAKOUT, seed, a, updates=1000, curve=6.0)
        s.run("RAPL-A2C", BREAKOUT, seed, 10, updates=400 + 100 * (seed - 1), per_decision=2.0,
              curve=9.0, shares=(0.4, [0.6]))
        s.run("RAPL-A2C", BREAKOUT, seed, 7, variant=AUTHORS, updates=300, per_decision=3.0)
    # Asterix: one A2C run finished, none of RAPL's; no Seaquest at all.
    s.run("A2C", ASTERIX, 1, 12, updates=1000)
    s.run("A2C", ASTERIX, 2, None)
    for seed in (1, 2):
        s.run("RAPL-A2C", ASTERIX, seed, None)
        s.run("RAPL-A2C", ASTERIX, seed, None, variant=AUTHORS)
    return s.write()


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """(short, long): the long sweep's report written with the short one beside it."""
    root = tmp_path_factory.mktemp("budgets")
    short, long = _short(root / "short"), _long(root / "long")
    report.write_report(long, reps=REPS, beside=short)
    return short, long


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _fig2(long: Path) -> dict[tuple[str, str], dict[str, str]]:
    return {(r["env_id"], r["budget"]): r
            for r in _rows(long / "report" / f"{bc.FIG2}.csv")}


def test_relative_performance_standard_errors_and_verdicts_by_hand(sweeps):
    _, long = sweeps
    rows = _fig2(long)
    b = rows[BREAKOUT, "cpu"]
    assert (b["steps"], b["runs_A2C"], b["runs_RAPL"], b["runs_authors"]) == ("1000", "2", "2", "2")
    assert [float(b[k]) for k in ("S_A", "S_A_se", "S_R", "S_R_se", "S_authors", "S_authors_se")
            ] == [5.0, 1.0, 3.0, 1.0, 6.0, 1.0]
    assert float(b["relative_pct"]) == pytest.approx(-40.0)
    assert float(b["error_pct"]) == pytest.approx(20.0)
    assert float(b["authors_relative_pct"]) == pytest.approx(20.0)
    # Welch's t over 2 seeds a side, ν = 1: p = 1 − (2/π)·atan|t|. RAPL: t = −2/√2,
    # p = 0.392; the authors': t = 1/√2, p = 0.608. Two seeds make no verdict here.
    assert (b["verdict"], b["authors_verdict"]) == ("no evidence (p = 0.392)",
                                                    "no evidence (p = 0.608)")
    b = rows[BREAKOUT, "long"]
    assert float(b["relative_pct"]) == pytest.approx(300 / 7)
    assert float(b["error_pct"]) == 0.0
    assert float(b["authors_relative_pct"]) == 0.0
    # RAPL 10 ± 0 against 7 ± 1: t = 3, p = 1 − (2/π)·atan 3 = 0.205; the authors' t = 0.
    assert (b["verdict"], b["authors_verdict"]) == ("no evidence (p = 0.205)",
                                                    "no evidence (p = 1.000)")
    a = rows[ASTERIX, "cpu"]
    assert float(a["relative_pct"]) == pytest.approx(-15.0)
    assert float(a["error_pct"]) == pytest.approx(5.0)
    # 8.5 ± 0.5 against 10 ± 0: t = −3, p = 0.205.
    assert a["verdict"] == "no evidence (p = 0.205)" and a["authors_verdict"] == "no runs"
    assert float(rows[SEAQUEST, "cpu"]["relative_pct"]) == pytest.approx(-50.0)


def test_update_counts_and_steps_per_decision_are_means_over_seeds(sweeps):
    _, long = sweeps
    rows = _fig2(long)
    b = rows[BREAKOUT, "cpu"]
    # RAPL: 40 and 50 updates, 2 and 2.5 steps per decision; the authors' 20, 3.
    assert [float(b[k]) for k in ("updates_A2C", "updates_RAPL", "updates_authors",
                                  "steps_per_decision_RAPL", "steps_per_decision_authors")
            ] == [100.0, 45.0, 20.0, 2.25, 3.0]
    # Routine share 1 − primitive share: 1 − (0.5 + 0.7)/2.
    assert float(b["routine_share_RAPL"]) == pytest.approx(0.4)
    b = rows[BREAKOUT, "long"]
    assert [float(b[k]) for k in ("updates_A2C", "updates_RAPL", "updates_authors")
            ] == [1000.0, 450.0, 300.0]


def test_a_game_missing_at_one_budget_is_reported_as_missing(sweeps):
    _, long = sweeps
    rows = _fig2(long)
    s = rows[SEAQUEST, "long"]  # not in the long sweep at all
    assert (s["runs_A2C"], s["expected_A2C"], s["S_A"], s["verdict"]) == ("0", "0", "", "no runs")
    a = rows[ASTERIX, "long"]  # one A2C run of two finished, no RAPL run
    assert (a["runs_A2C"], a["expected_A2C"], a["runs_RAPL"], a["expected_RAPL"]) == (
        "1", "2", "0", "2")
    assert (float(a["S_A"]), a["S_R"], a["relative_pct"], a["verdict"]) == (
        12.0, "", "", "no runs")
    text = (long / "report" / "report.md").read_text()
    assert "- At 10^4 steps (budget long, " in text and "7 of 12 runs finished:" in text
    assert (f"  - {ASTERIX}: A2C seed 2; RAPL-A2C seeds 1, 2; RAPL-A2C, authors' code seeds "
            "1, 2 not finished.") in text
    assert f"  - {SEAQUEST}: no runs at this budget (not in this sweep's rl experiment)." in text
    assert "- At 10^3 steps (budget cpu, " in text and "14 of 14 runs finished (the authors' " \
        "code's from its `diagnosis.json`)." in text
    # The table and the verdicts (Welch, 2 seeds a side: no evidence either way); S_R ≥ S_A
    # on 0 of 3 games, 1 of 1.
    assert (f"| {BREAKOUT} | 10^3 | 2/2/2 | 5.00 ± 1.00 | 3.00 ± 1.00 | 6.00 ± 1.00 | "
            "-40.0 % ± 20.0 % | no evidence (p = 0.392) | 20.0 % ± 20.0 % | no evidence "
            "(p = 0.608) | 100 | 45 | 20 | 2.25 | 3.00 |") in text
    assert (f"| {SEAQUEST} | 10^4 | 0/0/0 | – | – | – | – | no runs | – | no runs | – | – | – "
            "| – | – |") in text
    assert ("**RAPL-A2C same or better than A2C (S_R ≥ S_A, as Fig. 2 counts) on 0 of 3 games "
            "at 10^3 steps and 1 of 1 games at 10^4 steps**") in text
    assert (f"{BREAKOUT}: no evidence (p = 0.392) → no evidence (p = 0.205) (-40.0 % ± 20.0 % "
            "→ 42.9 % ± 0.0 %).") in text


def test_curves_with_updates_and_routine_shares_by_hand(sweeps):
    _, long = sweeps
    curves = {(r["env_id"], r["budget"], r["method"], float(r["step"])): r
              for r in _rows(long / "report" / f"{bc.CURVES}.csv")}
    # A2C on Breakout at 10^3 steps: returns 3 and 4 in every bin, 100 updates at the end.
    last = curves[BREAKOUT, "cpu", "A2C", 1000.0]
    assert float(last["mean_return"]) == 3.5 and float(last["runs"]) == 2
    assert float(last["std_return"]) == pytest.approx(math.sqrt(0.5))
    assert float(last["updates"]) == 100.0
    assert float(curves[BREAKOUT, "long", "RAPL-A2C", 5000.0]["updates"]) == 225.0  # 450 / 2
    # Breakout: 3 methods at each budget; Asterix: 2 at 10^3, A2C at 10^4; Seaquest: 2 at 10^3.
    assert len(curves) == CURVE_BINS * 11
    shares = {(r["env_id"], r["budget"], r["method"], r["choice"]): float(r["share"])
              for r in _rows(long / "report" / f"{bc.ROUTINES}.csv") if r["step"] == "1000.0"}
    # (0.5, 0.3, 0.2) and (0.7, 0.1, 0.2): their means.
    assert shares[BREAKOUT, "cpu", "RAPL-A2C", "primitives"] == pytest.approx(0.6)
    assert shares[BREAKOUT, "cpu", "RAPL-A2C", "routine 1"] == pytest.approx(0.2)
    assert shares[BREAKOUT, "cpu", "RAPL-A2C", "routine 2"] == pytest.approx(0.2)
    # The long sweep's authors' runs counted no routine's share: primitives only.
    assert shares[BREAKOUT, "long", "RAPL-A2C, authors' code", "primitives"] == 1.0


def test_update_marks_sit_where_the_mean_runs_had_made_each_power_of_ten():
    steps = np.linspace(0.0, 10_000, CURVE_BINS + 1)[1:]
    mean = steps / 1000  # the return: a straight line
    curve = bc._Curve(bc.MeanCurve(steps, mean, np.zeros(CURVE_BINS), np.ones(CURVE_BINS)),
                      steps / 10, steps)  # 1,000 updates at 10^4 steps
    # 10 updates at step 100, before the first bin (200): no mark; 100 at step 1,000 (return
    # 1); 1,000 at step 10,000.
    assert bc.update_marks(curve) == [(2, 1000.0, 1.0), (3, 10000.0, 10.0)]


def test_sides_are_ordered_by_steps_not_by_the_arguments(sweeps):
    short, long = sweeps
    for a, b in ((short, long), (long, short)):
        first, second = bc.load_sides(a, b)
        assert (first.out, first.steps, second.out, second.steps) == (short, SHORT, long, LONG)
    assert bc.steps_label(10_000_000) == "10^7" and bc.steps_label(500_000) == "5·10^5"


def test_bad_folders_are_one_line_errors(sweeps, tmp_path):
    short, long = sweeps
    (tmp_path / "curves.json").write_text(json.dumps({"budget": "cpu", "runs": []}))
    (tmp_path / "file").write_text("")
    no_rl_runs = tmp_path / "empty_rl"
    no_rl_runs.mkdir()
    (no_rl_runs / "rl.json").write_text(json.dumps({"budget": "cpu", "runs": []}))
    cases = [(tmp_path / "nowhere", "nowhere: no such sweep folder (--beside names"),
             (tmp_path / "file", "file: a file, not a sweep folder"),
             (long / "runs", "runs: not a sweep folder: none of imitation.json"),
             (tmp_path, f"{tmp_path}: no rl experiment there (no rl.json)"),
             (no_rl_runs, "rl.json: no run of A2C or RAPL-A2C: nothing to compare"),
             (long, f"{long} and {long}: both at 10^4 agent steps (budget long): --beside "
                    "needs the rl experiment at another budget")]
    for beside, message in cases:
        with pytest.raises(UsageError) as error:
            report.write_report(long, reps=REPS, beside=beside)
        assert message in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(UsageError, match="no rl experiment there"):
        report.write_report(tmp_path, reps=REPS, beside=short)


def test_the_cli_writes_the_comparison_as_a_user_does(sweeps, tmp_path):
    import shutil

    short, long = sweeps
    out = tmp_path / "short"
    shutil.copytree(short, out)
    proc = subprocess.run([str(CLI), "experiment", "report", str(out), "--beside", str(long)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    names = {Path(line).name for line in proc.stdout.splitlines()}
    assert {f"{stem}.{ext}" for stem in bc.FILES for ext in ("png", "csv")} <= names
    for stem in bc.FILES:
        assert (out / "report" / f"{stem}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # The same numbers whichever folder is named first.
    assert (out / "report" / f"{bc.FIG2}.csv").read_text() == \
        (long / "report" / f"{bc.FIG2}.csv").read_text()
    assert f"The rl experiment of this sweep (`{out}`) beside `{long}`'s" in \
        (out / "report" / "report.md").read_text()
    same = subprocess.run([str(CLI), "experiment", "report", str(out), "--beside", str(short)],
                          capture_output=True, text=True, timeout=120)
    assert_one_line_error(same, "both at 10^3 agent steps (budget cpu)",
                          prefix="routine-gym: error: ")
    # A report without --beside leaves no comparison behind.
    report.write_report(out, reps=REPS)
    assert not any((out / "report" / f"{stem}.{ext}").exists() for stem in bc.FILES
                   for ext in ("png", "csv"))


def test_the_docstring_examples_hold():
    import doctest

    from routine_gym.experiments import run_counters

    for module in (bc, run_counters):  # the verdict rule, steps' labels, the routine shares
        assert doctest.testmod(module).failed == 0, module.__name__


def test_same_or_better_counts_as_fig2_does_not_by_the_verdicts():
    # MiniQbert in the committed sweeps: S_R 1047.8 against S_A 1050, within a standard error,
    # so its verdict is *same*; Fig. 2 counts S_R ≥ S_A, and the two reports must agree.
    side = bc.Side(Path("."), "cpu", 1000, [], None)

    def row(env_id, s_a, s_r, verdict):
        return bc.Row(env_id, side, {}, {}, {"A2C": s_a, "RAPL-A2C": s_r}, {}, {},
                      {"RAPL-A2C": verdict}, {}, {}, {})

    rows = {("MiniQbert-v0", 1000): row("MiniQbert-v0", 1050.0, 1047.8, "same"),
            ("Freeway", 1000): row("Freeway", 20.0, 20.0, "same"),
            ("Breakout", 1000): row("Breakout", 5.0, 7.0, "better"),
            ("Asterix", 1000): row("Asterix", 3.0, 1.0, "worse"),
            ("Seaquest", 1000): row("Seaquest", math.nan, math.nan, bc.NO_RUNS)}
    games = ["MiniQbert-v0", "Freeway", "Breakout", "Asterix", "Seaquest"]
    assert bc._same_or_better(rows, games, side) == (2, 4)  # Freeway (equal) and Breakout
