"""Fig. 5, scalability: RAPL-A2C and MacroAction with more routines (K) and longer ones (the
shortest routine's length), as relative performance over A2C.

Error bars: ± standard error over seeds of each seed's relative performance averaged over
games.
"""

from __future__ import annotations

import json
import math
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.drawing import COLOURS, colour, figure
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.sections import group_runs, ordered
from routine_gym.experiments.specs import Builder, shipped_demo_has_routine
from routine_gym.experiments.statistics import standard_error
from routine_gym.experiments.writing import Writer, num, table

FILE = "fig5_scalability"
METHODS = ("RAPL-A2C", "MacroAction")


class Setting(NamedTuple):
    """One point of Fig. 5 and one row of its CSV: a method at K routines of ≥ `min_length`
    actions, relative to A2C."""

    method: str
    k: int
    min_length: int
    games: int  # games with an A2C reference
    seeds: int
    relative_mean_pct: float  # mean over seeds of the relative performance, in %
    relative_se_pct: float  # its standard error over seeds, in %


def add_runs(b: Builder) -> None:
    """A2C, and RAPL-A2C and MacroAction at each K and minimum length, on each game and
    seed; a length a game's shipped demo has no routine of is left out (in the manifest)."""
    budget = b.budget
    settings = [(k, 2) for k in budget.scalability_k]
    settings += [(3, length) for length in budget.scalability_lengths if length != 2]
    for env_id in budget.games:
        # A minimum length the game's shipped demo has no routine of: no runs, a manifest note.
        usable = []
        for k, length in settings:
            if length == 2 or shipped_demo_has_routine(env_id, length, b.budget.demo_set):
                usable.append((k, length))
            else:
                b.left_out.append({
                    "env_id": env_id, "variant": {"K": k, "min_length": length},
                    "why": f"its shipped demo has no routine of ≥ {length} actions"})
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            for k, length in usable:
                for method in ("RAPL-A2C", "MacroAction"):
                    b.a2c(method, env_id, seed, {"K": k, "min_length": length}, k=k,
                          min_length=length)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Fig. 5: relative performance over A2C against K, and against the minimum length."""
    from routine_gym.metrics import relative_performance

    a2c = group_runs(runs, lambda r: r.method if r.method == "A2C" and not r.variant else None)
    baseline = {}
    for g in sorted({r.env_id for r in a2c.get("A2C", [])}):
        s_a = float(np.mean([r.score for r in a2c["A2C"] if r.env_id == g]))
        if s_a != 0.0:
            baseline[g] = s_a

    def label(run: RunRecord) -> str | None:
        k, length = run.variant.get("K"), run.variant.get("min_length", 2)
        if run.method == "A2C" or not all(isinstance(v, int) and not isinstance(v, bool)
                                          for v in (k, length)):
            return None  # not a scalability setting (or not one of whole numbers)
        return json.dumps([run.method, k, length])

    points: list[Setting] = []
    for name, group in group_runs(runs, label).items():
        method, k, length = json.loads(name)
        per_seed: dict[int, list[float]] = {}
        for r in group:
            if r.env_id in baseline:
                per_seed.setdefault(r.seed, []).append(
                    relative_performance(r.score, baseline[r.env_id]))
        if per_seed:
            seed_means = [float(np.mean(v)) for v in per_seed.values()]
            games = len({r.env_id for r in group if r.env_id in baseline})
            points.append(Setting(method, k, length, games, len(seed_means),
                                  100 * float(np.mean(seed_means)),
                                  100 * standard_error(seed_means)))
    order = METHODS
    points.sort(key=lambda p: (order.index(p.method) if p.method in order else len(order), p.k,
                               p.min_length))
    # Each panel: its name in the CSV, its points, the setting on its x axis, the axis label.
    panels = [("K", [p for p in points if p.min_length == 2], "k",
               "K (number of routines), minimum length 2"),
              ("min_length", [p for p in points if p.k == 3], "min_length",
               "minimum routine length, K = 3")]
    w.csv(FILE, ("panel", "method", "K", "min_length", "games", "seeds",
                                 "relative_mean_pct", "relative_se_pct"),
          [(panel, *p) for panel, chosen, _, _ in panels for p in chosen])

    fig = figure(10, 4.2)
    for ax, (_, chosen, axis, xlabel) in zip(fig.subplots(1, 2), panels, strict=True):
        ax.axhline(0.0, color=COLOURS["A2C"], linestyle="--", linewidth=1, label="A2C")
        values = sorted({getattr(p, axis) for p in chosen})
        for m in ordered({p.method for p in chosen}, order):
            line = sorted((p for p in chosen if p.method == m), key=lambda p: getattr(p, axis))
            ax.errorbar([getattr(p, axis) for p in line], [p.relative_mean_pct for p in line],
                        yerr=[p.relative_se_pct for p in line], color=colour(m), marker="o",
                        capsize=4, linewidth=1.6, label=m)
        if values:
            ax.set_xticks(values)
        else:
            why = "no finished A2C reference" if not baseline else "no finished run here"
            ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative performance over A2C (%)\nmean ± s.e. over seeds")
        ax.legend()
    fig.suptitle("Fig. 5 — Scalability: more routines (K) and longer routines")
    w.png(fig, FILE)

    lines = ["Relative performance over A2C: for each seed, (S − S_A)/|S_A| averaged over the "
             "games, with S the run's final mean return and S_A A2C's mean over seeds on that "
             "game; then mean ± standard error over seeds. Games where A2C scored 0 are left "
             "out.", ""]
    if not baseline:
        lines += ["No finished A2C run (or A2C scored 0 everywhere): no reference.", ""]
    return lines + table(("method", "K", "min length", "games", "seeds", "relative ± s.e."),
                          [(m, k, n, g, s, f"{num(mean, 1)} % ± {num(se, 1)}"
                            if math.isfinite(mean) else "n/a")
                           for m, k, n, g, s, mean, se in points])


EXPERIMENT = Experiment(
    name="scalability", version=1,
    title="Scalability: more (K) and longer routines, RAPL-A2C against MacroAction",
    figure="Fig. 5", file=FILE, add_runs=add_runs, section=section, normalised=False,
    methods=METHODS)
