"""The two sides of the budget comparison and their rows (`budget_comparison`, issue 28).

A `Side` is one sweep's rl experiment at its budget (`load_sides` reads both and orders them by
the steps of their runs); a `Row` is one game at one budget: its runs, scores, standard errors,
relative performances and verdicts per method (`compare`: Welch's t-test over seeds), and the
runs' counters. `budget_comparison` writes them as CSVs, figures and a section of `report.md`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from routine_gym.errors import UsageError
from routine_gym.experiments.paper import diagnosis
from routine_gym.experiments.paper.diagnosis import AUTHORS
from routine_gym.experiments.paper.rl import relative
from routine_gym.experiments.registry import EXPERIMENTS
from routine_gym.experiments.results import RunRecord, load_runs
from routine_gym.experiments.run_counters import run_counter
from routine_gym.experiments.statistics import standard_error, welch

__all__ = ["METHODS", "NO_RUNS", "ROUTINE_METHODS", "Row", "Side", "compare", "load_sides",
           "steps_label"]

#: The methods compared, in the order of the tables and figures.
METHODS = ("A2C", "RAPL-A2C", AUTHORS)
#: The methods that choose among routines (A2C has none).
ROUTINE_METHODS = ("RAPL-A2C", AUTHORS)
NO_RUNS = "no runs"


class Side(NamedTuple):
    """One sweep's rl experiment at its budget."""

    out: Path
    budget: str  # the manifest's budget name
    steps: int  # the agent steps of its runs
    runs: list[RunRecord]  # every run of METHODS it lists (finished or not), one per key
    authors_from: str | None  # the manifest the authors' runs come from: "rl", "diagnosis"

    @property
    def label(self) -> str:
        return steps_label(self.steps)

    def finished(self, method: str, env_id: str) -> list[RunRecord]:
        return [r for r in self.runs if r.finished and diagnosis.label(r) == method
                and r.env_id == env_id]

    @property
    def games(self) -> list[str]:
        return sorted({r.env_id for r in self.runs})


def steps_label(steps: int) -> str:
    """Agent steps as a reader says them: `10^6`, `5·10^5`, else with thousands separators.

    Example:
        >>> steps_label(10_000_000), steps_label(500_000), steps_label(1_234)
        ('10^7', '5·10^5', '1,234')
    """
    digits = str(steps)
    zeros = len(digits) - len(digits.rstrip("0"))
    head = digits[: len(digits) - zeros]
    if steps >= 10 and zeros >= 1 and len(head) == 1:
        return f"10^{zeros}" if head == "1" else f"{head}·10^{zeros}"
    return f"{steps:,}"


def _load_side(out: Path, flag: str) -> Side:
    """`out`'s rl experiment (and the authors' runs of its diagnosis experiment where the rl
    experiment has none); UsageError naming the folder or file for anything else."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: a file, not a sweep folder ({flag} names the --out of "
                         "`routine-gym experiment run`)")
    if not out.is_dir():
        raise UsageError(f"{out}: no such sweep folder ({flag} names the --out of "
                         "`routine-gym experiment run`)")
    if not any((out / f"{name}.json").is_file() for name in EXPERIMENTS):
        raise UsageError(f"{out}: not a sweep folder: none of "
                         f"{', '.join(n + '.json' for n in EXPERIMENTS)} is there")
    results: dict[str, Any] = {}
    rl = load_runs(out, "rl", results)
    if rl is None:
        raise UsageError(f"{out}: no rl experiment there (no rl.json): the budget comparison "
                         "compares the rl experiment's runs at two budgets")
    runs = {r.key: r for r in rl.runs if r.role == "main" and diagnosis.label(r) in METHODS}
    if not any(diagnosis.label(r) in ("A2C", "RAPL-A2C") for r in runs.values()):
        raise UsageError(f"{out / 'rl.json'}: no run of A2C or RAPL-A2C: nothing to compare")
    steps = max(r.steps for r in runs.values())
    authors_from = "rl" if any(diagnosis.label(r) == AUTHORS for r in runs.values()) else None
    if authors_from is None:
        found = load_runs(out, "diagnosis", results)
        extra = [r for r in (found.runs if found else []) if r.role == "main"
                 and diagnosis.label(r) == AUTHORS and r.steps == steps]
        if extra:
            authors_from = "diagnosis"
            runs.update((r.key, r) for r in extra)
    return Side(out, rl.budget, steps, list(runs.values()), authors_from)


def load_sides(out: str | Path, beside: str | Path) -> tuple[Side, Side]:
    """`(shorter, longer)`: the rl experiments of the sweep `out` and of `beside`, ordered by
    the steps of their runs.

    Raises:
        UsageError: one line: a folder missing, a file, not a sweep folder, without an rl
            experiment or without an A2C or RAPL-A2C run in it; both at the same steps.
    """
    sides = [_load_side(Path(out), "the sweep"), _load_side(Path(beside), "--beside")]
    a, b = sides
    if a.steps == b.steps:
        budgets = a.budget if a.budget == b.budget else f"{a.budget} and {b.budget}"
        raise UsageError(f"{a.out} and {b.out}: both at {steps_label(a.steps)} agent steps "
                         f"(budget {budgets}): --beside needs the rl experiment at another "
                         "budget (e.g. cpu's 10^6 steps beside long's 10^7)")
    short, long = sorted(sides, key=lambda s: s.steps)
    return short, long


def compare(scores: Sequence[float], a2c: Sequence[float]) -> str:
    """RAPL's verdict against A2C on a game from the final scores of their runs: Welch's
    t-test over seeds (`statistics.welch`): `better`, `worse` or `no evidence`, with the
    p-value; `no runs` without both.

    Example:
        >>> compare([4, 6, 5], [5, 5, 6]), compare([7, 8, 9], [1, 2, 3]), compare([2, 3], [5])
        ('no evidence (p = 0.667)', 'better (p = 0.018)', 'not enough runs')
    """
    if not scores or not a2c:
        return NO_RUNS
    c = welch(scores, a2c)
    return c.verdict if c.verdict == "not enough runs" else f"{c.verdict} (p = {c.p:.3f})"


class Row(NamedTuple):
    """One game at one budget: a row of `budgets_fig2.csv`."""

    env_id: str
    side: Side
    runs: dict[str, int]  # finished runs per method
    expected: dict[str, int]  # runs the manifest lists per method
    means: dict[str, float]
    errors: dict[str, float]  # standard error over seeds
    relative: dict[str, tuple[float, float]]  # RAPL-A2C, AUTHORS: (relative %, error %)
    verdicts: dict[str, str]  # RAPL-A2C, AUTHORS
    updates: dict[str, float]  # mean over seeds
    steps_per_decision: dict[str, float]
    routine_share: dict[str, float]


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _row(side: Side, env_id: str) -> Row:
    finished = {m: side.finished(m, env_id) for m in METHODS}
    scores = {m: [r.score for r in rs] for m, rs in finished.items()}
    rel, verdicts = {}, {}
    for m in ROUTINE_METHODS:
        if scores[m] and scores["A2C"]:
            value, error = relative(scores[m], scores["A2C"])
            rel[m] = (100 * value, 100 * error)
        else:
            rel[m] = (math.nan, math.nan)
        verdicts[m] = compare(scores[m], scores["A2C"])
    return Row(
        env_id, side, {m: len(rs) for m, rs in finished.items()},
        {m: sum(1 for r in side.runs if diagnosis.label(r) == m and r.env_id == env_id)
         for m in METHODS},
        {m: float(np.mean(s)) if s else math.nan for m, s in scores.items()},
        {m: standard_error(s) if s else math.nan for m, s in scores.items()},
        rel, verdicts,
        {m: _mean([run_counter(r, "updates") for r in rs]) for m, rs in finished.items()},
        {m: _mean([run_counter(r, "steps_per_decision") for r in rs])
         for m, rs in finished.items()},
        {m: 1.0 - _mean([run_counter(r, "primitive_share") for r in rs])
         for m, rs in finished.items()})
