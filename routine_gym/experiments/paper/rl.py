"""Fig. 2, RL: the relative performance (S_R − S_A)/|S_A| of RAPL-A2C (R) over A2C (A) on each
game.

Error bars: the standard error over seeds of S_R divided by |S_A|.

At the long budget (`rl_authors`) a third method runs beside them: RAPL-A2C as the authors'
code has it, the diagnosis experiment's run (`diagnosis.authors_run`) under its label
(`diagnosis.AUTHORS`). It is kept out of Fig. 2's S_R, and has its own table and its place in
the aggregates.

Where the budget asks for it (`rl_ppo`: smoke and cpu) the same games and seeds also run PPO,
RAPL-PPO and MacroAction-PPO (`algos/rapl_ppo.py`, its env family's PPO defaults), beyond the
paper. Their part of the section comes after A2C's, whose numbers it leaves as they are: the
relative performance of RAPL-PPO and of MacroAction-PPO over PPO per game (`relative`, the
same error bar) beside RAPL-A2C's over A2C, drawn as a second figure `fig2_rl_ppo` (three bars a
game), and the PPO family's own aggregates: the IQMs over the games all three have finished and
P(RAPL-PPO > PPO). A sweep without PPO runs (made before them) writes the A2C part alone.
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
from routine_gym.experiments.sections import (
    aggregate,
    aggregate_lines,
    group_runs,
    poi_lines,
    poi_pairs_lines,
)
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.statistics import standard_error
from routine_gym.experiments.writing import Writer, interval, num, pct, table

FILE = "fig2_rl"
PPO_FILE = "fig2_rl_ppo"
METHODS = ("A2C", "RAPL-A2C")
#: The PPO family (`rapl_ppo.py`'s modes ppo, rapl, macro), where the budget has `rl_ppo`.
PPO_METHODS = ("PPO", "RAPL-PPO", "MacroAction-PPO")


class PPOGame(NamedTuple):
    """One game's row of `fig2_rl_ppo.csv`: each PPO method's runs and mean final score, and
    RAPL-PPO's and MacroAction-PPO's relative performance over PPO (RAPL-A2C's over A2C beside
    them, from Fig. 2's rows)."""

    env_id: str
    runs: dict[str, int]  # finished runs per PPO method
    means: dict[str, float]  # mean final score over seeds per PPO method (NaN: none)
    relative: dict[str, tuple[float, float]]  # RAPL-PPO, MacroAction-PPO: (%, error %)
    a2c: tuple[float, float]  # RAPL-A2C over A2C on this game: (%, error %), NaN where none


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
    """A2C and RAPL-A2C on each RL game and seed, RAPL-A2C as the authors' code has it where
    the budget asks for it (`rl_authors`), and PPO, RAPL-PPO and MacroAction-PPO where it asks
    for them (`rl_ppo`)."""
    for env_id in b.budget.rl_games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed)
            if b.budget.rl_authors:
                diagnosis.authors_run(b, env_id, seed)
    if b.budget.rl_ppo:  # after A2C's: a fresh sweep draws Fig. 2 first
        for env_id in b.budget.rl_games:
            for seed in b.seeds():
                for method in PPO_METHODS:
                    b.ppo(method, env_id, seed)


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

    draw_relative(w, FILE, [row.env_id for row in rows],
                  [("RAPL-A2C", [row.relative_pct for row in rows],
                    [row.error_pct for row in rows])],
                  f"Fig. 2 — RAPL-A2C over A2C: same or better on {better} of {len(rows)} "
                  "games")

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
    ppo = group_runs(runs, ppo_label)
    if ppo:
        lines += _ppo_lines(w, ppo, rows)
    return lines


def draw_relative(w: Writer, file: str, env_ids: Sequence[str],
                  series: Sequence[tuple[str, Sequence[float], Sequence[float]]],
                  title: str, legend: dict[str, str] | None = None,
                  title_size: float | None = None) -> None:
    """Fig. 2's bars: per game (in the order given) one bar per series `(method, relative %,
    error %)` in the method's colour (a NaN: no bar), side by side, with a legend (`legend`
    names each method's bars) when there are several."""
    labels = game_labels(env_ids)
    fig = figure(max(7.0, (0.45 + 0.25 * (len(series) - 1)) * len(env_ids) + 2.5), 4.5)
    ax = fig.subplots()
    x = np.arange(len(env_ids))
    width = 0.8 / len(series)
    for i, (method, values, errors) in enumerate(series):
        offset = x if len(series) == 1 else x + (i - (len(series) - 1) / 2) * width
        ax.bar(offset, [np.nan_to_num(v) for v in values], width, yerr=list(errors),
               color=COLOURS[method], capsize=4 if len(series) == 1 else 2,
               label=(legend or {}).get(method, method) if len(series) > 1 else None)
    ax.axhline(0.0, color="black", linewidth=0.8)
    many = len(env_ids) > 6
    ax.set_xticks(x, [labels[e] for e in env_ids], rotation=45 if many else 0,
                  ha="right" if many else "center")
    if len(series) > 1:
        ax.legend(fontsize=8)
    ax.set_ylabel("relative performance (S_R − S_A)/|S_A| (%)")
    ax.set_xlabel("game (error bar: standard error of S_R over seeds / |S_A|)")
    ax.set_title(title, **({} if title_size is None else {"fontsize": title_size}))
    w.png(fig, file)


def ppo_label(run: RunRecord) -> str | None:
    """The PPO method a run is (its method, without a variant), None for any other run."""
    return run.method if run.method in PPO_METHODS and not run.variant else None


def _ppo_lines(w: Writer, groups: dict[str, list[RunRecord]], a2c_rows: list[GameBar]
               ) -> list[str]:
    """The PPO family beside A2C's: per game RAPL-PPO's and MacroAction-PPO's relative
    performance over PPO (and RAPL-A2C's over A2C), `fig2_rl_ppo`, and its aggregates."""
    base = groups.get("PPO", [])
    games = sorted({r.env_id for rs in groups.values() for r in rs})
    by_a2c = {row.env_id: (row.relative_pct, row.error_pct) for row in a2c_rows}
    rows: list[PPOGame] = []
    for g in games:
        scores = {m: [r.score for r in groups.get(m, []) if r.env_id == g] for m in PPO_METHODS}
        s_p = scores["PPO"]
        rel = {}
        for m in PPO_METHODS[1:]:
            value, error = relative(scores[m], s_p) if scores[m] and s_p else (math.nan,) * 2
            rel[m] = (100 * value, 100 * error)
        rows.append(PPOGame(g, {m: len(s) for m, s in scores.items()},
                            {m: float(np.mean(s)) if s else math.nan for m, s in scores.items()},
                            rel, by_a2c.get(g, (math.nan, math.nan))))
    rows.sort(key=lambda row: (-row.relative["RAPL-PPO"][0]
                               if math.isfinite(row.relative["RAPL-PPO"][0]) else math.inf,
                               row.env_id))
    w.csv(PPO_FILE, ("env_id", "runs_ppo", "runs_rapl_ppo", "runs_macro_ppo", "S_PPO",
                     "S_RAPL_PPO", "S_MacroAction_PPO", "rapl_ppo_relative_pct",
                     "rapl_ppo_error_pct", "macro_ppo_relative_pct", "macro_ppo_error_pct",
                     "rapl_a2c_relative_pct", "rapl_a2c_error_pct"),
          [(row.env_id, *row.runs.values(), *row.means.values(), *row.relative["RAPL-PPO"],
            *row.relative["MacroAction-PPO"], *row.a2c) for row in rows])
    compared = [row for row in rows if row.runs["PPO"] and row.runs["RAPL-PPO"]]
    better = sum(1 for row in compared if row.means["RAPL-PPO"] >= row.means["PPO"])
    draw_relative(w, PPO_FILE, [row.env_id for row in rows],
                  [("RAPL-A2C", *zip(*(row.a2c for row in rows), strict=True)),
                   *((m, *zip(*(row.relative[m] for row in rows), strict=True))
                     for m in PPO_METHODS[1:])],
                  f"Fig. 2 with PPO (beyond the paper) — RAPL-PPO same or better than PPO on "
                  f"{better} of {len(compared)} games\nbars: RAPL-A2C over A2C (as in Fig. 2), "
                  "RAPL-PPO and MacroAction-PPO over PPO",
                  legend={"RAPL-A2C": "RAPL-A2C over A2C", "RAPL-PPO": "RAPL-PPO over PPO",
                          "MacroAction-PPO": "MacroAction-PPO over PPO"}, title_size=10)

    agg = aggregate(w, {m: groups[m] for m in PPO_METHODS if m in groups})
    undefined = [row.env_id for row in rows if base and any(
        row.runs[m] and row.runs["PPO"] and not math.isfinite(row.relative[m][0])
        for m in PPO_METHODS[1:])]
    table_rows = [(row.env_id, "/".join(str(row.runs[m]) for m in PPO_METHODS),
                   *(num(row.means[m]) for m in PPO_METHODS),
                   *(_relative_cell(*row.relative[m]) for m in PPO_METHODS[1:]),
                   _relative_cell(*row.a2c)) for row in rows]
    lines = [f"**PPO, beyond the paper** (`rapl_ppo.py` at its env family's defaults; figure "
             f"`{PPO_FILE}.png`, data `{PPO_FILE}.csv`). The relative performance "
             "(S_X − S_PPO)/|S_PPO| of RAPL-PPO and of MacroAction-PPO over PPO, ± the "
             "standard error of S_X over seeds / |S_PPO|, beside RAPL-A2C's over A2C from the "
             "table above; runs: finished runs of PPO/RAPL-PPO/MacroAction-PPO.", "",
             *table(("game", "runs", "S_PPO", "S_RAPL-PPO", "S_MacroAction-PPO",
                     "RAPL-PPO over PPO", "MacroAction-PPO over PPO", "RAPL-A2C over A2C"),
                    table_rows),
             f"**RAPL-PPO same or better than PPO (S ≥ S_PPO) on {better} of {len(compared)} "
             "games** with runs of both.", ""]
    if undefined:
        lines += [f"Undefined (n/a) where S_PPO is 0 or too close to 0 "
                  f"({', '.join(undefined)}): no bar there.", ""]
    lines += [*aggregate_lines(w, agg),
              *table(("method", "IQM [95 % CI]"),
                     [(m, interval(agg.iqm.get(m), agg.percent)) for m in agg.iqm]),
              *poi_pairs_lines(w, agg, [("RAPL-PPO", "PPO"), ("RAPL-PPO", "MacroAction-PPO"),
                                        ("MacroAction-PPO", "PPO")])]
    return lines


def _relative_cell(value_pct: float, error_pct: float) -> str:
    """A relative performance in % and its error bar as `25.0 % ± 5.0 %`; – where none."""
    text = pct(value_pct / 100)
    if text in ("–", "n/a") or not math.isfinite(error_pct):
        return text
    return f"{text} ± {pct(error_pct / 100)}"


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
    figure="Fig. 2", file=FILE, add_runs=add_runs, section=section,
    methods=(*METHODS, AUTHORS, *PPO_METHODS),
    colours={AUTHORS: diagnosis.VARIANT_COLOURS[AUTHORS]}, extra_files=(PPO_FILE,))
