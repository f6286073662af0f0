"""Fig. 2, RL: the relative performance (S_R − S_A)/|S_A| of RAPL-A2C (R) over A2C (A) on each
game.

Error bars: the standard error over seeds of S_R divided by |S_A|.

At the long budget (`rl_authors`) a third method runs beside them: RAPL-A2C as the authors'
code has it, the diagnosis experiment's run (`diagnosis.authors_run`) under its label
(`diagnosis.AUTHORS`). It is kept out of Fig. 2's S_R, and has its own table and its place in
the aggregates.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.drawing import COLOURS, figure, game_labels
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.paper import diagnosis
from routine_gym.experiments.paper.diagnosis import AUTHORS
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.sections import aggregate, aggregate_lines, group_runs, poi_lines
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.statistics import standard_error
from routine_gym.experiments.writing import Writer, interval, num, pct, table

FILE = "fig2_rl"
METHODS = ("A2C", "RAPL-A2C")


class GameBar(NamedTuple):
    """One bar of Fig. 2 and one row of its CSV: RAPL-A2C over A2C on a game."""

    env_id: str
    runs_a2c: int
    runs_rapl: int
    s_a: float  # A2C's mean final score over seeds
    s_r: float  # RAPL-A2C's
    relative_pct: float  # (S_R − S_A)/|S_A| in %, NaN where undefined
    error_pct: float  # standard error of S_R over seeds / |S_A|, in %


def add_runs(b: Builder) -> None:
    """A2C and RAPL-A2C on each RL game and seed, and RAPL-A2C as the authors' code has it
    where the budget asks for it (`rl_authors`)."""
    for env_id in b.budget.rl_games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed)
            if b.budget.rl_authors:
                diagnosis.authors_run(b, env_id, seed)


def relative(rapl: Sequence[float], a2c: Sequence[float]) -> tuple[float, float]:
    """(S_R − S_A)/|S_A| and its error bar, the standard error of S_R over seeds / |S_A|, from
    the final scores of RAPL's runs and A2C's on one game; (NaN, NaN) where S_A is 0 or too
    close to 0 (the budget comparison draws its bars with it too)."""
    from routine_gym.metrics import relative_performance

    s_a = float(np.mean(a2c))
    try:
        value = relative_performance(float(np.mean(rapl)), s_a)
    except ValueError:
        return math.nan, math.nan
    error = standard_error(rapl) / abs(s_a)
    if not (math.isfinite(value) and math.isfinite(error)):  # S_A too close to 0
        return math.nan, math.nan
    return value, error


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Fig. 2: a bar per game, sorted by relative performance; the IQMs and P(RAPL > A2C); the
    authors' code's relative performance per game where it ran."""
    groups = group_runs(runs, diagnosis.label)  # the authors' code is not RAPL-A2C's S_R
    a2c, rapl = groups.get("A2C", []), groups.get("RAPL-A2C", [])
    games = sorted({r.env_id for r in a2c} & {r.env_id for r in rapl})
    rows: list[GameBar] = []
    for g in games:
        s_a = [r.score for r in a2c if r.env_id == g]
        s_r = [r.score for r in rapl if r.env_id == g]
        rel, err = relative(s_r, s_a)
        rows.append(GameBar(g, len(s_a), len(s_r), float(np.mean(s_a)), float(np.mean(s_r)),
                            100 * rel, 100 * err))
    rows.sort(key=lambda row: -row.relative_pct if math.isfinite(row.relative_pct) else math.inf)
    w.csv(FILE, ("env_id", "runs_a2c", "runs_rapl", "S_A", "S_R",
                        "relative_performance_pct", "error_pct"), rows)
    better = sum(1 for row in rows if row.s_r >= row.s_a)
    undefined = [row.env_id for row in rows if not math.isfinite(row.relative_pct)]

    labels = game_labels(games)
    fig = figure(max(7.0, 0.45 * len(rows) + 2.5), 4.5)
    ax = fig.subplots()
    x = np.arange(len(rows))
    ax.bar(x, [np.nan_to_num(row.relative_pct) for row in rows],
           yerr=[row.error_pct for row in rows],
           color=COLOURS["RAPL-A2C"], capsize=4)
    ax.axhline(0.0, color="black", linewidth=0.8)
    ax.set_xticks(x, [labels[row.env_id] for row in rows], rotation=45 if len(rows) > 6 else 0,
                  ha="right" if len(rows) > 6 else "center")
    ax.set_ylabel("relative performance (S_R − S_A)/|S_A| (%)")
    ax.set_xlabel("game (error bar: standard error of S_R over seeds / |S_A|)")
    ax.set_title(f"Fig. 2 — RAPL-A2C over A2C: same or better on {better} of {len(rows)} "
                 "games")
    w.png(fig, FILE)

    agg = aggregate(w, {m: groups[m] for m in ("A2C", "RAPL-A2C", AUTHORS) if m in groups})
    table_rows = [(g, n_a, n_r, num(s_a), num(s_r), pct(rel / 100), pct(err / 100))
             for g, n_a, n_r, s_a, s_r, rel, err in rows]
    lines = ["S = mean over seeds of the final evaluation's mean return (raw). Relative "
             "performance (S_R − S_A)/|S_A| of RAPL-A2C (R) over A2C (A); ± is the standard "
             "error of S_R over seeds divided by |S_A| (A2C's own spread is not in it).", "",
             *table(("game", "A2C runs", "RAPL runs", "S_A", "S_R", "relative", "±"), table_rows),
             f"**RAPL-A2C same or better than A2C (S_R ≥ S_A) on {better} of {len(rows)} "
             "games** (paper: same or better on 25 of 33 Atari games).", "",
             *([f"The relative performance is undefined (n/a) where S_A is 0 or too close to 0 "
                f"({', '.join(undefined)}): no bar there.", ""] if undefined else []),
             *aggregate_lines(w, agg),
             *table(("method", "IQM [95 % CI]"),
                     [(m, interval(agg.iqm.get(m), agg.percent)) for m in agg.iqm])]
    lines += poi_lines(w, agg, "RAPL-A2C", ["A2C"])
    if AUTHORS in groups:
        lines += [*_authors_lines(groups[AUTHORS], a2c),
                  *poi_lines(w, agg, AUTHORS, ["A2C", "RAPL-A2C"])]
    return lines


def _authors_lines(authors: list[RunRecord], a2c: list[RunRecord]) -> list[str]:
    """The authors' code's S per game and its relative performance over A2C, as Fig. 2's."""
    rows = []
    for g in sorted({r.env_id for r in authors} & {r.env_id for r in a2c}):
        s_a = [r.score for r in a2c if r.env_id == g]
        s_x = [r.score for r in authors if r.env_id == g]
        rel, err = relative(s_x, s_a)
        rows.append((g, len(s_x), num(float(np.mean(s_a))), num(float(np.mean(s_x))),
                     pct(rel), pct(err)))
    return [f"{AUTHORS} (`--authors`, the diagnosis experiment's run) over A2C, as above:", "",
            *table(("game", "authors' runs", "S_A", "S_authors", "relative", "±"), rows)]


EXPERIMENT = Experiment(
    name="rl", version=2, title="RL: relative performance of RAPL-A2C over A2C per game",
    figure="Fig. 2", file=FILE, add_runs=add_runs, section=section, methods=(*METHODS, AUTHORS),
    colours={AUTHORS: diagnosis.VARIANT_COLOURS[AUTHORS]})
