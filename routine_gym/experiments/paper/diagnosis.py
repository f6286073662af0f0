"""Diagnosis: why RAPL-A2C scores below A2C here. Not one of the paper's figures: each variant
tests one explanation on the rl experiment's games and seeds.

- `RAPL-A2C`, `A2C`: the rl experiment's runs (the same keys: trained once).
- `RAPL-A2C, decisions budget`: the budget counted in decisions (`--budget-unit decisions`), so
  RAPL makes as many gradient updates as A2C. Closing the gap says RAPL was update-starved.
- `RAPL-A2C, authors' code`: the authors' released code where it differs from the paper
  (`--authors`, SPEC §5b). Closing the gap says our implementation choices cost it.
- `MacroAction, decisions budget`: routines as black boxes at A2C's number of updates, to tell
  the routines' content from RAPL's use of them.

The figure: per game, the mean final score of each variant with its standard error over seeds
(top), then RAPL's primitive steps per decision and the share of its decisions that chose a
routine over training (mean over seeds); `diagnosis_runs`: each run's final score against its
gradient updates. The CSVs: per game and variant, and per run (its decisions, updates and steps
per decision, from `result.json`'s counters).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.drawing import COLOURS, figure, game_labels
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.run_counters import mean_bins as _binned
from routine_gym.experiments.run_counters import run_counter as _counter
from routine_gym.experiments.specs import Builder, Entry
from routine_gym.experiments.statistics import standard_error
from routine_gym.experiments.writing import Writer, num, pct, table

FILE = "diagnosis"
RUNS_FILE = "diagnosis_runs"
DECISIONS = "RAPL-A2C, decisions budget"
AUTHORS = "RAPL-A2C, authors' code"
MACRO = "MacroAction, decisions budget"
VARIANTS = ("A2C", "RAPL-A2C", DECISIONS, AUTHORS, MACRO)
VARIANT_COLOURS = {DECISIONS: "#ff9896", AUTHORS: "#8c564b", MACRO: "#aec7e8"}
#: Each variant's marker in the per-run figure (runs of two variants may sit on one point).
MARKERS = ("o", "s", "^", "D", "v")


def add_runs(b: Builder) -> None:
    """A2C and RAPL-A2C (the rl experiment's runs), and the three variants, on each rl game
    and seed; a decisions budget is the budget's agent steps counted as decisions."""
    decisions = [("budget-unit", "decisions")]
    for env_id in b.budget.rl_games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed, {"diagnosis": "decisions"}, extra=decisions)
            authors_run(b, env_id, seed)
            b.a2c("MacroAction", env_id, seed, {"diagnosis": "decisions"}, extra=decisions)


def authors_run(b: Builder, env_id: str, seed: int) -> Entry:
    """RAPL-A2C as the authors' code has it (`--authors`) on `env_id` and `seed`: this
    experiment's run, and the rl experiment's third method at the long budget (one key where
    both have it). Its variant `{"diagnosis": "authors"}` is what `label` names `AUTHORS`."""
    return b.a2c("RAPL-A2C", env_id, seed, {"diagnosis": "authors"}, extra=[("authors", True)])


def label(run: RunRecord) -> str | None:
    """The variant a run is: its method, and the `diagnosis` variant when it has one."""
    kind = run.variant.get("diagnosis")
    if kind is None:
        return run.method if run.method in ("A2C", "RAPL-A2C") else None
    return {("RAPL-A2C", "decisions"): DECISIONS, ("RAPL-A2C", "authors"): AUTHORS,
            ("MacroAction", "decisions"): MACRO}.get((run.method, kind))


class GameRow(NamedTuple):
    """One game's row of the diagnosis CSV: each variant's mean score and standard error."""

    env_id: str
    means: dict[str, float]
    errors: dict[str, float]
    verdict: str


def closes(score: float, error: float, a2c: float, a2c_error: float) -> bool:
    """Whether a variant closes the gap to A2C: its mean at least A2C's less the larger of the
    two standard errors over seeds (a NaN error counts as 0), so a variant and A2C whose
    spreads overlap by that much are level.

    Example:
        >>> closes(9.5, 0.0, 10.0, 1.0), closes(8.0, 0.0, 10.0, 1.0), closes(8.0, 2.5, 10.0, 0.0)
        (True, False, True)
    """
    def finite(x: float) -> float:
        return x if math.isfinite(x) else 0.0

    margin = max(finite(error), finite(a2c_error)) + 1e-9 * max(1.0, abs(a2c))  # rounding
    return math.isfinite(score) and score >= a2c - margin


def verdict(means: dict[str, float], errors: dict[str, float]) -> str:
    """Which explanation a game's data supports (see the module's docstring).

    Example:
        >>> verdict({"A2C": 10, "RAPL-A2C": 5, DECISIONS: 9.8, AUTHORS: 6}, {"A2C": 0.5})
        'update-starved (the decisions budget closes the gap)'
    """
    a2c, rapl = means.get("A2C", math.nan), means.get("RAPL-A2C", math.nan)
    if not (math.isfinite(a2c) and math.isfinite(rapl)):
        return "not enough runs"

    def reaches(variant: str) -> bool:
        return closes(means.get(variant, math.nan), errors.get(variant, math.nan), a2c,
                      errors.get("A2C", math.nan))

    if reaches("RAPL-A2C"):
        return "no gap (RAPL-A2C level with A2C within a standard error, or above)"
    if not all(math.isfinite(means.get(v, math.nan)) for v in (DECISIONS, AUTHORS)):
        return "not yet: a variant has no finished run"
    found = []
    if reaches(DECISIONS):
        found.append("update-starved (the decisions budget closes the gap)")
    if reaches(AUTHORS):
        found.append("implementation choices (the authors' code closes the gap)")
    if found:
        return "; ".join(found)
    return "none of these (neither closes the gap; routine content: see Fig. 6)"


def _count(run: RunRecord, field: str) -> int | float:
    """A whole-number counter (decisions, updates, steps) as an int, NaN where none."""
    value = _counter(run, field)
    return int(value) if math.isfinite(value) else value


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """The variants' scores per game, each game's verdict, and RAPL's counters over training."""
    groups: dict[str, list[RunRecord]] = {}
    for run in runs:
        if run.role == "main" and run.finished and (name := label(run)) is not None:
            groups.setdefault(name, []).append(run)
    games = sorted({r.env_id for rs in groups.values() for r in rs})
    variants = [v for v in VARIANTS if v in groups]

    rows: list[GameRow] = []
    for g in games:
        means, errors = {}, {}
        for v in variants:
            scores = [r.score for r in groups[v] if r.env_id == g]
            means[v] = float(np.mean(scores)) if scores else math.nan
            errors[v] = standard_error(scores) if len(scores) > 1 else math.nan
        rows.append(GameRow(g, means, errors, verdict(means, errors)))
    w.csv(FILE, ("env_id", *(f"{v} {s}" for v in variants for s in ("mean", "se")), "verdict"),
          [(row.env_id, *(x for v in variants for x in (row.means[v], row.errors[v])),
            row.verdict) for row in rows])
    per_run = sorted((r for rs in groups.values() for r in rs),
                     key=lambda r: (r.env_id, VARIANTS.index(label(r)), r.seed))
    w.csv(RUNS_FILE, ("env_id", "variant", "seed", "score", "decisions", "updates",
                      "primitive_steps", "steps_per_decision", "routine_share", "episode_length"),
          [(r.env_id, label(r), r.seed, r.score, _count(r, "decisions"),
            _count(r, "updates"), _count(r, "primitive_steps"),
            _counter(r, "steps_per_decision"), 1.0 - _counter(r, "primitive_share"),
            _counter(r, "episode_length")) for r in per_run])

    _draw(w, games, variants, groups)
    _draw_runs(w, games, per_run)
    lines = ["Each variant tests one explanation of RAPL-A2C's deficit (see the experiment's "
             "docstring): the decisions budget gives RAPL as many gradient updates as A2C; the "
             "authors' code changes what SPEC §5b lists; MacroAction at the decisions budget "
             "uses the same routines as black boxes. S = mean over seeds of the final "
             "evaluation's mean return ± its standard error over seeds; a variant *closes the "
             "gap* when its S is at least A2C's less the larger of the two standard errors.",
             "",
             *table(("game", *variants, "verdict"),
                    [(g, *(f"{num(row.means[v], 1)} ± {num(row.errors[v], 1)}"
                           for v in variants), row.verdict)
                     for g, row in zip(games, rows, strict=True)])]
    count_rows = []
    for g in games:
        for v in variants:
            rs = [r for r in groups[v] if r.env_id == g]
            if rs:
                count_rows.append((g, v, len(rs),
                                   num(np.mean([_counter(r, "updates") for r in rs]), 0),
                                   num(np.mean([_counter(r, "decisions") for r in rs]), 0),
                                   num(np.mean([_counter(r, "primitive_steps") for r in rs]), 0),
                                   num(np.mean([_counter(r, "steps_per_decision") for r in rs])),
                                   pct(1.0 - np.mean([_counter(r, "primitive_share")
                                                      for r in rs]))))
    lines += ["What the runs counted (mean over seeds; – where a run predates the counters):",
              "", *table(("game", "variant", "runs", "updates", "decisions", "primitive steps",
                          "steps per decision", "routine share"), count_rows)]
    return lines


def _draw(w: Writer, games: list[str], variants: list[str],
          groups: dict[str, list[RunRecord]]) -> None:
    labels = game_labels(games)
    colours = {**COLOURS, **VARIANT_COLOURS}
    fig = figure(max(10.0, 2.6 * len(games)), 8.5)
    axes = fig.subplots(3, len(games), squeeze=False)
    rapl_like = [v for v in variants if v not in ("A2C",)]
    for col, g in enumerate(games):
        ax = axes[0, col]
        for i, v in enumerate(variants):
            scores = [r.score for r in groups[v] if r.env_id == g]
            if scores:
                error = standard_error(scores) if len(scores) > 1 else 0.0
                ax.bar(i, np.mean(scores), yerr=error, color=colours.get(v, "#333333"),
                       capsize=3)
        ax.set_xticks(range(len(variants)), [str(i + 1) for i in range(len(variants))])
        ax.set_title(labels[g])
        for row, field, ylabel in ((1, "steps_per_decision", "steps per decision"),
                                   (2, "primitive_share", "routine share")):
            ax = axes[row, col]
            for v in rapl_like:
                values = _binned([r for r in groups[v] if r.env_id == g], field)
                if values is None:
                    continue
                if field == "primitive_share":
                    values = 1.0 - values
                x = np.linspace(0.0, 1.0, len(values) + 1)[1:]
                ax.plot(x, values, color=colours.get(v, "#333333"), label=v)
            ax.set_xlabel("fraction of the run's budget")
            if col == 0:
                ax.set_ylabel(ylabel)
    axes[0, 0].set_ylabel("final score (mean ± s.e.)")
    from matplotlib.patches import Patch

    fig.legend(handles=[Patch(color=colours.get(v, "#333333"), label=f"{i + 1}: {v}")
                        for i, v in enumerate(variants)],
               loc="outside lower center", ncols=min(len(variants), 3), fontsize=8)
    fig.suptitle("Diagnosis: why RAPL-A2C scores below A2C\ntop: final score (mean ± s.e. over "
                 "seeds); middle, bottom: the routine variants' counters over training (mean "
                 "over seeds)", fontsize=10)
    w.png(fig, FILE)


def _draw_runs(w: Writer, games: list[str], runs: list[RunRecord]) -> None:
    """Each run's final score against the gradient updates it made, a panel per game."""
    from matplotlib.lines import Line2D
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    labels = game_labels(games)
    colours = {**COLOURS, **VARIANT_COLOURS}
    fig = figure(max(10.0, 2.6 * len(games)), 4.0)
    axes = fig.subplots(1, len(games), squeeze=False)[0]
    for ax, g in zip(axes, games, strict=True):
        for r in (r for r in runs if r.env_id == g):
            ax.scatter(_counter(r, "updates"), r.score, color=colours.get(label(r), "#333333"),
                       marker=MARKERS[VARIANTS.index(label(r))], s=28, alpha=0.85)
        ax.set_title(labels[g])
        ax.set_xlabel("gradient updates (thousands)")
        # Thousands, at most four ticks: 12,500 updates in full digits ran into each other.
        ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x / 1000:g}"))
    axes[0].set_ylabel("final score")

    present = [v for v in VARIANTS if any(label(r) == v for r in runs)]

    fig.legend(handles=[Line2D([], [], color=colours.get(v, "#333333"), linestyle="",
                               marker=MARKERS[VARIANTS.index(v)], label=v) for v in present],
               loc="outside lower center", ncols=min(len(present), 3), fontsize=8)
    fig.suptitle("Diagnosis: each run's final score against its gradient updates\n(a run "
                 "without counters is left out)", fontsize=10)
    w.png(fig, RUNS_FILE)


EXPERIMENT = Experiment(
    name="diagnosis", version=1,
    title="Why RAPL-A2C loses to A2C: at equal updates, and as the authors' code has it",
    figure="Diagnosis", file=FILE, add_runs=add_runs, section=section, normalised=False,
    methods=VARIANTS, colours=VARIANT_COLOURS, extra_files=(RUNS_FILE,))
