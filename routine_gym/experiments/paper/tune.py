"""Tune: every method's learning rate and schedule, chosen alike (the fair protocol, issue 47).
Not one of the paper's figures.

At a budget with tuning seeds (`Budget.tune_seeds`: `fair`, `fair-long`) each tuned method
(`specs.TUNED_METHODS`: A2C, RAPL-A2C, MacroAction, PPO, RAPL-PPO, MacroAction-PPO) trains on
each game at every point of its family's grid (`specs.TUNE_GRIDS`: the default learning rate,
half, two, four and eight times it, each annealed and constant) on the tuning seeds, whose env
seeds are disjoint from the evaluation seeds', for the budget's own agent steps. The point
with the highest mean final score over the tuning seeds is the method's setting on that game (a
tie keeps the first in grid order, the default; a point with a run that diverged loses), and
every run of the rl and diagnosis experiments at that budget learns with it (`derived.py`'s
`tuned` rule): no method gets a setting another was denied. A budget tunes the methods its
experiments run (`methods_at`): at `fair-long`, A2C and RAPL-A2C.

The section: per method and game, each grid point's score on each tuning seed ("diverged" for
a run that did), their mean and the choice; `tune.csv` holds the same (an empty mean where a
run of the point diverged).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence

import numpy as np

from routine_gym.experiments.derived import choose_point
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.specs import TUNED_METHODS, Builder
from routine_gym.experiments.writing import Writer, num, table

FILE = "tune"
#: The tuned methods in the order of the tables.
METHODS = tuple(TUNED_METHODS)


def methods_at(b: Builder) -> tuple[str, ...]:
    """The methods tuned at `b`'s budget, those its rl and diagnosis experiments run: A2C and
    RAPL-A2C; MacroAction where the diagnosis runs; the PPO family where rl runs it."""
    used = {"A2C", "RAPL-A2C"}
    if b.budget.has("diagnosis"):
        used.add("MacroAction")
    if b.budget.rl_ppo:
        used |= {"PPO", "RAPL-PPO", "MacroAction-PPO"}
    return tuple(m for m in METHODS if m in used)


def add_runs(b: Builder) -> None:
    """Every tuned method's grid on each rl game and tuning seed (none without tuning seeds)."""
    if not b.budget.tune_seeds:
        return
    for env_id in b.budget.rl_games:
        for method in methods_at(b):
            b.tune_runs(method, env_id, role="main")


def _point(run: RunRecord) -> tuple[float, bool]:
    return float(run.variant["learning_rate"]), bool(run.variant["anneal_lr"])


def choices(runs: Sequence[RunRecord]) -> dict[tuple[str, str], dict]:
    """Per (method, game): each grid point's tuning-seed scores (`points`, grid order; -inf for
    a run that diverged), the chosen index (`chosen`; None until every point has a finished
    or diverged run) and whether every run of the grid ended (`complete`)."""
    from routine_gym.experiments.specs import TUNE_GRIDS

    out: dict[tuple[str, str], dict] = {}
    for method in METHODS:
        family = TUNED_METHODS[method][1]
        grid = [(float(p[0][1]), bool(p[1][1])) for p in TUNE_GRIDS[family]]
        for env_id in sorted({r.env_id for r in runs if r.method == method}):
            mine = [r for r in runs if r.method == method and r.env_id == env_id]
            points = []
            for point in grid:
                at = [r for r in mine if _point(r) == point]
                if not at:  # a budget tuning fewer points (`Budget.tune_points`)
                    continue
                points.append((point, at, [r.score if r.finished else -math.inf
                                           for r in sorted(at, key=lambda r: r.seed)
                                           if r.finished or r.diverged]))
            chosen = None
            if all(len(scores) > 0 for _, _, scores in points):
                with contextlib.suppress(ValueError):  # every point diverged: no choice
                    chosen = choose_point([((), scores) for _, _, scores in points])
            complete = all(r.finished or r.diverged for _, at, _ in points for r in at)
            out[(method, env_id)] = {"points": points, "chosen": chosen, "complete": complete}
    return out


def _score_text(score: float, digits: int) -> str:
    """A tune score as the table shows it: -inf (a run that diverged) as "diverged"."""
    return "diverged" if score == -math.inf else num(score, digits)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Each method's grid per game: the scores on the tuning seeds, their mean, the choice."""
    found = choices([r for r in runs if r.role == "main"])
    rows, csv_rows = [], []
    for (method, env_id), c in found.items():
        for i, ((lr, anneal), _, scores) in enumerate(c["points"]):
            mean = float(np.mean(scores)) if scores else math.nan
            mark = "**chosen**" if c["chosen"] == i else ""
            if c["chosen"] == i and not c["complete"]:
                mark = "leading (grid not finished)"
            rows.append((method, env_id, f"{lr:g}", "annealed" if anneal else "constant",
                         ", ".join(_score_text(s, 1) for s in scores) or "–",
                         _score_text(mean, 2), mark))
            csv_rows.append((method, env_id, lr, anneal, len(scores), mean,
                             c["chosen"] == i and c["complete"]))
    w.csv(FILE, ("method", "env_id", "learning_rate", "anneal_lr", "runs", "mean_score",
                 "chosen"), csv_rows)
    _draw(w, found)
    return ["Each method's learning rate and schedule on each game: the grid point with the "
            "highest mean final score over the tuning seeds (their env seeds are disjoint from "
            "the evaluation seeds'), a tie keeping the script's default, a point with a run "
            "that diverged losing; every rl and "
            "diagnosis run of this budget learns with it.", "",
            *table(("method", "game", "learning rate", "schedule", "tuning seeds' scores",
                    "mean", "choice"), rows), ""]


def _draw(w: Writer, found: dict[tuple[str, str], dict]) -> None:
    """A panel per method: per game, each grid point's mean score over the tuning seeds (its
    seeds as dots), the chosen point outlined."""
    from matplotlib.patches import Patch

    from routine_gym.experiments.drawing import figure, game_labels
    from routine_gym.experiments.specs import TUNE_GRIDS

    methods = [m for m in METHODS if any(k[0] == m for k in found)]
    games = sorted({k[1] for k in found})
    labels = game_labels(games)
    fig = figure(max(8.0, 2.2 * len(games)), 2.6 * len(methods) + 0.8)
    axes = fig.subplots(len(methods), 1, squeeze=False)[:, 0]
    # A pair (annealed, constant) per factor of the family's default, the same in every figure:
    # blue the default, orange half, green twice, red four, purple eight times it.
    colours = {1.0: ("#1f77b4", "#aec7e8"), 0.5: ("#ff7f0e", "#ffbb78"),
               2.0: ("#2ca02c", "#98df8a"), 4.0: ("#d62728", "#ff9896"),
               8.0: ("#9467bd", "#c5b0d5")}
    legend: dict[tuple[float, bool], tuple[str, Patch]] = {}
    diverged_seen = False
    for ax, method in zip(axes, methods, strict=True):
        for gi, g in enumerate(games):
            c = found.get((method, g))
            if c is None:
                continue
            width = 0.8 / max(len(c["points"]), 1)
            default = c["points"][0][0][0]  # the grids list the scripts' default first
            # left to right by learning rate, annealed before constant
            order = sorted(range(len(c["points"])),
                           key=lambda i: (c["points"][i][0][0], not c["points"][i][0][1]))
            for slot, i in enumerate(order):
                (lr, anneal), _, scores = c["points"][i]
                x = gi - 0.4 + width * (slot + 0.5)
                if scores:
                    chosen = c["chosen"] == i
                    factor = lr / default
                    colour = colours.get(factor, ("#7f7f7f", "#c7c7c7"))[0 if anneal else 1]
                    finite = [s for s in scores if math.isfinite(s)]
                    if len(finite) < len(scores):  # a run diverged: an x at 0, no bar
                        ax.scatter([x], [0.0], marker="x", color=colour, s=40, zorder=3)
                        diverged_seen = True
                    else:
                        ax.bar(x, np.mean(scores), width, color=colour,
                               edgecolor="black" if chosen else "none",
                               linewidth=1.5 if chosen else 0)
                    ax.scatter([x] * len(finite), finite, color="black", s=6, zorder=3)
                    # every grid point once, without the outline a choice has in a panel
                    legend.setdefault(
                        (factor, not anneal),
                        (f"{factor:g}× default, {'annealed' if anneal else 'constant'}",
                         Patch(facecolor=colour)))
        ax.set_xticks(range(len(games)), [labels[g] for g in games])
        ax.set_xlim(-0.5, len(games) - 0.5)  # the same slots in every panel
        ax.set_ylabel(f"{method}\nfinal score")
    if legend:
        entries = [legend[k] for k in sorted(legend)]
        if diverged_seen:
            from matplotlib.lines import Line2D

            entries.append(("a run diverged (no bar)", Line2D([], [], marker="x", color="black",
                                                              linestyle="none")))
        fig.legend([e[1] for e in entries], [e[0] for e in entries], fontsize=8,
                   ncols=min(len(entries), 5), loc="outside lower center")
    fig.suptitle("Tuning: each grid point's mean final score over the tuning seeds (dots: the "
                 "seeds; outlined: the choice)\nlearning rates as multiples of each family's "
                 f"default (A2C's RMSprop {TUNE_GRIDS['a2c'][0][0][1]:g}, PPO's Adam "
                 f"{TUNE_GRIDS['ppo'][0][0][1]:g})", fontsize=10)
    w.png(fig, FILE)


EXPERIMENT = Experiment(
    name="tune", version=1,
    title="The fair protocol's tuning: each method's learning rate and schedule on each game",
    figure="Tuning", file=FILE, add_runs=add_runs, section=section, normalised=False,
    methods=METHODS, grid=True)
