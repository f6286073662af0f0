"""What the experiments' report sections share: grouping runs by label, the aggregate of the
groups' normalised scores (`Aggregate`) and the lines and tables that describe it.

A section is a function `(Writer, runs) -> lines of report.md` that writes its experiment's CSV
and PNG through the `Writer`; `runs` are the main runs of the experiment's manifest.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.reference import Reference
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.statistics import (
    iqm_intervals,
    probability_of_improvement,
    score_matrix,
)
from routine_gym.experiments.writing import Writer, interval, num, table

__all__ = ["Aggregate", "aggregate", "aggregate_lines", "group_runs", "norm_axis_label", "ordered",
           "per_env_means", "poi_lines", "poi_pairs_lines"]


def ordered(names: Iterable[str], order: Sequence[str]) -> list[str]:
    """`names` in `order` first, then the others sorted."""
    names = set(names)
    return [n for n in order if n in names] + sorted(names - set(order))


def per_env_means(runs: Sequence[RunRecord], envs: Sequence[str]) -> list[str]:
    """A table's per-game cells: the mean over seeds of the runs' final scores, or – for none."""
    cells = []
    for e in envs:
        scores = [r.score for r in runs if r.env_id == e]
        cells.append(num(float(np.mean(scores)), 1) if scores else "–")
    return cells


def group_runs(runs: Iterable[RunRecord], label: Callable[[RunRecord], str | None]
               ) -> dict[str, list[RunRecord]]:
    """The finished main runs by label (a label of None leaves the run out)."""
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        if run.role == "main" and run.finished and (name := label(run)) is not None:
            groups.setdefault(name, []).append(run)
    return groups


class Aggregate(NamedTuple):
    games: list[str]  # the normalised games every group has finished runs of
    matrices: dict[str, np.ndarray]  # group → (runs, games) normalised scores
    iqm: dict[str, tuple[float, float, float]]
    percent: bool  # normalised (shown in %) or, with no normalisable game, raw
    left_out: list[str]  # games left out: raw, or some group has no run of them


def aggregate(w: Writer, groups: Mapping[str, list[RunRecord]]) -> Aggregate:
    """IQMs over the games that every group has finished and that have a normalisation."""
    games = sorted({r.env_id for runs in groups.values() for r in runs})
    common = [g for g in games if all(any(r.env_id == g for r in runs)
                                      for runs in groups.values())]
    normalised = [g for g in common if w.references.get(g, Reference("raw")).kind != "raw"]
    percent = bool(normalised)
    used = normalised if percent else common

    def value(run: RunRecord) -> float:
        return w.references.get(run.env_id, Reference("raw")).normalise(run.score)

    matrices = {}
    for name, runs in groups.items():
        matrix = score_matrix(runs, used, value) if used else None
        if matrix is not None:
            matrices[name] = matrix
    iqm = iqm_intervals(matrices, reps=w.reps, seed=w.seed)
    return Aggregate(used, matrices, iqm, percent, [g for g in games if g not in used])


def aggregate_lines(w: Writer, agg: Aggregate, what: str = "final score") -> list[str]:
    if not agg.games:
        return ["No game has finished runs of every method: no aggregate.", ""]
    kinds: dict[str, list[str]] = {}
    for g in agg.games:
        kinds.setdefault(w.references.get(g, Reference("raw")).kind, []).append(g)
    names = {"human": "human-normalised", "demo": "demo-normalised", "raw": "raw"}
    unit = "; ".join(f"{names[k]} on {', '.join(gs)}" for k, gs in sorted(kinds.items()))
    unit = f"normalised ({unit}; see Normalisation)" if agg.percent else (
        f"raw ({unit}: no game here has a normalisation)")
    lines = [f"IQM of the {what}, {unit}, over {len(agg.games)} game(s) × the seeds every "
             f"game has, with 95 % stratified-bootstrap CIs (rliable):", ""]
    if agg.left_out:
        lines += [f"Left out of the aggregates: {', '.join(agg.left_out)} (raw scores, or not "
                  "every method finished there).", ""]
    return lines


def poi_lines(w: Writer, agg: Aggregate, winner: str, others: Sequence[str]) -> list[str]:
    """The probability of improvement of `winner` over each of `others` (a table)."""
    return poi_pairs_lines(w, agg, [(winner, other) for other in others])


def poi_pairs_lines(w: Writer, agg: Aggregate, pairs: Sequence[tuple[str, str]]) -> list[str]:
    """The probability of improvement P(X > Y) of each pair `(X, Y)` whose groups both have a
    matrix, in one table; nothing when none has."""
    rows = []
    for winner, other in pairs:
        if winner in agg.matrices and other in agg.matrices:
            rows.append((f"{winner} > {other}", interval(probability_of_improvement(
                agg.matrices[winner], agg.matrices[other], reps=w.reps, seed=w.seed),
                percent=False)))
    if not rows:
        return []
    return ["Probability of improvement P(X > Y) (rliable; a run of X beats a run of Y on a "
            "game, averaged over games), with 95 % CIs:", "",
            *table(("X > Y", "P(X > Y) [95 % CI]"), rows)]


def norm_axis_label(w: Writer, agg: Aggregate) -> str:
    if not agg.percent:
        return "raw score, IQM"
    kinds = sorted({w.references[g].kind for g in agg.games})
    return f"{'/'.join(kinds)}-normalised score, IQM (%)"

