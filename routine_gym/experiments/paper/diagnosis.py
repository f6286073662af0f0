"""Diagnosis: why RAPL-A2C scores below A2C here. Not one of the paper's figures: each variant
tests one explanation on the rl experiment's games and seeds.

- `RAPL-A2C`, `A2C`: the rl experiment's runs (the same keys: trained once).
- `RAPL-A2C, decisions budget`: the budget counted in decisions (`--budget-unit decisions`), so
  RAPL makes as many gradient updates as A2C. Closing the gap says RAPL was update-starved.
- `RAPL-A2C, authors' code`: the authors' released code where it differs from the paper
  (`--authors`, SPEC §5b). Closing the gap says our implementation choices cost it.
- `MacroAction, decisions budget`: routines as black boxes at A2C's number of updates, to tell
  the routines' content from RAPL's use of them.

At a budget of the fair protocol (`tune_seeds`: `fair`), every arm learns with its method's
tuned settings (the tune experiment) and each arm changes one thing against the arm it is
compared with:

- `A2C, RAPL's updates`: A2C with rollouts of round(5 × RAPL-A2C's steps per decision) steps
  (`derived.rollout_for_updates`), so it makes RAPL-A2C's number of updates on its own frames:
  against A2C, the cost of fewer updates alone.
- `RAPL-A2C, A2C's updates`: RAPL-A2C with rollouts sized in primitive steps (`--rollout-unit
  steps`), so it makes A2C's number of updates on A2C's frames: against RAPL-A2C, the gain of
  more updates alone.
- `RAPL-A2C, authors' code` against `A2C, constant lr`: the preset's constant learning rate
  on both sides (each its method's best constant-lr grid point).
- `MacroAction, A2C's updates` against `RAPL-A2C, A2C's updates`: the same routines as black
  boxes, at the same updates and frames.

Each comparison's verdict comes from Welch's t-test over seeds (`statistics.welch`), worded
better / worse / no evidence with the difference and the p-value; the first protocol's budgets
get the same test of each variant against A2C (the rule before it, a margin of the larger
standard error, called a variant with more noise level with A2C).

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
from routine_gym.experiments.statistics import Comparison, standard_error, welch
from routine_gym.experiments.writing import Writer, num, pct, table

FILE = "diagnosis"
RUNS_FILE = "diagnosis_runs"
COMPARISONS_FILE = "diagnosis_comparisons"
DECISIONS = "RAPL-A2C, decisions budget"
AUTHORS = "RAPL-A2C, authors' code"
MACRO = "MacroAction, decisions budget"
# The fair protocol's arms.
A2C_AT_RAPL_UPDATES = "A2C, RAPL's updates"
RAPL_AT_A2C_UPDATES = "RAPL-A2C, A2C's updates"
A2C_CONSTANT = "A2C, constant lr"
MACRO_AT_A2C_UPDATES = "MacroAction, A2C's updates"
VARIANTS = ("A2C", "RAPL-A2C", DECISIONS, AUTHORS, MACRO, A2C_AT_RAPL_UPDATES,
            RAPL_AT_A2C_UPDATES, A2C_CONSTANT, MACRO_AT_A2C_UPDATES)
VARIANT_COLOURS = {DECISIONS: "#ff9896", AUTHORS: "#8c564b", MACRO: "#aec7e8",
                   A2C_AT_RAPL_UPDATES: "#98df8a", RAPL_AT_A2C_UPDATES: "#ff7f0e",
                   A2C_CONSTANT: "#2ca02c", MACRO_AT_A2C_UPDATES: "#9467bd"}
#: Each variant's marker in the per-run figure (runs of two variants may sit on one point).
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*", "h")
#: Each comparison: (what it isolates, the arm, the arm it is compared with, the protocol it
#: belongs to: `first`, `fair` or `both`). The first protocol's variants are each compared with
#: A2C; the fair protocol's arms as the module's docstring says.
COMPARISONS = (
    ("routines as published", "RAPL-A2C", "A2C", "both"),
    ("more updates, and more frames", DECISIONS, "A2C", "first"),
    ("the authors' code, and a constant lr against A2C's annealed one", AUTHORS, "A2C", "first"),
    ("black-box routines at more updates and frames", MACRO, "A2C", "first"),
    ("fewer updates alone", A2C_AT_RAPL_UPDATES, "A2C", "fair"),
    ("more updates alone", RAPL_AT_A2C_UPDATES, "RAPL-A2C", "fair"),
    ("the authors' code at the same lr schedule", AUTHORS, A2C_CONSTANT, "fair"),
    ("black-box routines at the same updates and frames", MACRO_AT_A2C_UPDATES,
     RAPL_AT_A2C_UPDATES, "fair"),
)
#: The arms only the fair protocol has (their presence says which protocol a sweep is).
FAIR_ARMS = (A2C_AT_RAPL_UPDATES, RAPL_AT_A2C_UPDATES, A2C_CONSTANT, MACRO_AT_A2C_UPDATES)


def add_runs(b: Builder) -> None:
    """A2C and RAPL-A2C (the rl experiment's runs), and the three variants, on each rl game
    and seed; a decisions budget is the budget's agent steps counted as decisions. At a
    budget with tuning, the fair protocol's arms instead (`fair_runs`)."""
    if b.budget.tune_seeds:
        fair_runs(b)
        return
    decisions = [("budget-unit", "decisions")]
    for env_id in b.budget.rl_games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed, {"diagnosis": "decisions"}, extra=decisions)
            authors_run(b, env_id, seed)
            b.a2c("MacroAction", env_id, seed, {"diagnosis": "decisions"}, extra=decisions)


def fair_runs(b: Builder) -> None:
    """The fair protocol's arms (the module's docstring) on each rl game and seed, each at
    its method's tuned settings."""
    steps = [("rollout-unit", "steps")]
    for env_id in b.budget.rl_games:
        rapl = [b.a2c("RAPL-A2C", env_id, seed) for seed in b.seeds()]
        spd = (("updates-of", (5, tuple(e.run.key for e in rapl))),)
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("A2C", env_id, seed, {"diagnosis": "rapl-updates"}, derived=spd)
            b.a2c("RAPL-A2C", env_id, seed, {"diagnosis": "a2c-updates"}, extra=steps)
            authors_run(b, env_id, seed)
            b.a2c("A2C", env_id, seed, {"diagnosis": "constant-lr"}, constant_lr=True)
            b.a2c("MacroAction", env_id, seed, {"diagnosis": "a2c-updates"}, extra=steps)


def authors_run(b: Builder, env_id: str, seed: int) -> Entry:
    """RAPL-A2C as the authors' code has it (`--authors`) on `env_id` and `seed`: this
    experiment's run, and the rl experiment's third method at the long budget (one key where
    both have it). Its variant `{"diagnosis": "authors"}` is what `label` names `AUTHORS`.
    With tuning, RAPL-A2C's best constant-lr grid point (the preset's schedule)."""
    return b.a2c("RAPL-A2C", env_id, seed, {"diagnosis": "authors"}, extra=[("authors", True)],
                 constant_lr=True)


def label(run: RunRecord) -> str | None:
    """The variant a run is: its method, and the `diagnosis` variant when it has one."""
    kind = run.variant.get("diagnosis")
    if kind is None:
        return run.method if run.method in ("A2C", "RAPL-A2C") else None
    return {("RAPL-A2C", "decisions"): DECISIONS, ("RAPL-A2C", "authors"): AUTHORS,
            ("MacroAction", "decisions"): MACRO, ("A2C", "rapl-updates"): A2C_AT_RAPL_UPDATES,
            ("RAPL-A2C", "a2c-updates"): RAPL_AT_A2C_UPDATES,
            ("A2C", "constant-lr"): A2C_CONSTANT,
            ("MacroAction", "a2c-updates"): MACRO_AT_A2C_UPDATES}.get((run.method, kind))


class GameRow(NamedTuple):
    """One game's row of the diagnosis CSV: each variant's mean score and standard error, and
    the comparisons' verdicts in one line."""

    env_id: str
    means: dict[str, float]
    errors: dict[str, float]
    verdict: str


def comparisons(scores: dict[str, list[float]]) -> list[tuple[str, str, str, Comparison]]:
    """Each comparison of `COMPARISONS` of the sweep's protocol whose two arms have runs in
    `scores` (a game's final scores per variant): `(question, arm, against, Welch's test of
    arm − against)`.

    Example:
        >>> [(q, c.verdict) for q, _, _, c in comparisons({"A2C": [6, 7, 8],
        ...                                                 "RAPL-A2C": [1, 2, 3]})]
        [('routines as published', 'worse')]
    """
    protocol = "fair" if any(scores.get(arm) for arm in FAIR_ARMS) else "first"
    out = []
    for question, arm, against, belongs in COMPARISONS:
        if belongs not in ("both", protocol):
            continue
        if scores.get(arm) and scores.get(against):
            out.append((question, arm, against, welch(scores[arm], scores[against])))
    return out


def verdict(scores: dict[str, list[float]]) -> str:
    """A game's verdicts in one line: each comparison's arm, against, verdict, Δ and p.

    Example:
        >>> verdict({"A2C": [6, 7, 8], "RAPL-A2C": [1, 2, 3]})
        'RAPL-A2C vs A2C: worse (Δ -5.00, p = 0.026)'
        >>> verdict({"A2C": [6.0]})
        'not enough runs'
    """
    found = comparisons(scores)
    if not found:
        return "not enough runs"
    return "; ".join(f"{arm} vs {against}: {c.describe()}" for _, arm, against, c in found)


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
    found: list[tuple[str, str, str, str, Comparison]] = []
    for g in games:
        means, errors, scores = {}, {}, {}
        for v in variants:
            scores[v] = [r.score for r in groups[v] if r.env_id == g]
            means[v] = float(np.mean(scores[v])) if scores[v] else math.nan
            errors[v] = standard_error(scores[v]) if len(scores[v]) > 1 else math.nan
        rows.append(GameRow(g, means, errors, verdict(scores)))
        found += [(g, *c) for c in comparisons(scores)]
    w.csv(COMPARISONS_FILE, ("env_id", "question", "arm", "against", "difference", "t", "df",
                             "p", "verdict"),
          [(g, q, arm, against, c.difference, c.t, c.df, c.p, c.verdict)
           for g, q, arm, against, c in found])
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
             "docstring). S = mean over seeds of the final evaluation's mean return ± its "
             "standard error over seeds. Each comparison is Welch's t-test over seeds (ν = the "
             "smaller count − 1), two-sided at 5 %: *better*, *worse* or *no evidence*, with "
             "the difference of the means (Δ) and the p-value.",
             "",
             *table(("game", *variants),
                    [(g, *(f"{num(row.means[v], 1)} ± {num(row.errors[v], 1)}"
                           for v in variants))
                     for g, row in zip(games, rows, strict=True)]),
             "",
             *table(("game", "what it isolates", "arm", "against", "verdict"),
                    [(g, q, arm, against, c.describe()) for g, q, arm, against, c in found])]
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
    methods=VARIANTS, colours=VARIANT_COLOURS, extra_files=(RUNS_FILE, COMPARISONS_FILE))
