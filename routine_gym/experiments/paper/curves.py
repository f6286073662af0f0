"""Fig. 3, training curves: A2C, MacroAction, OptionCritic, CompILE and RAPL-A2C, each game's
curves binned on one step grid, with the final scores' IQMs and rliable's performance profiles
(`fig3_profiles`).

Error bars: ± sample std over seeds of the binned curves; the IQM's 95 % CI.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.drawing import colour, figure, game_labels, legend_line
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.sections import (
    Aggregate,
    aggregate,
    aggregate_lines,
    group_runs,
    norm_axis_label,
    ordered,
    poi_lines,
)
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.statistics import performance_profiles
from routine_gym.experiments.training_curves import CURVE_BINS, RETURN_TAG, run_curve
from routine_gym.experiments.writing import Writer, interval, table

FILE = "fig3_curves"
PROFILE_FILE = "fig3_profiles"
METHODS = ("A2C", "MacroAction", "OptionCritic", "CompILE", "RAPL-A2C")


class MeanCurve(NamedTuple):
    """A method's curve on a game: the mean and sample std over seeds in each step bin."""

    steps: np.ndarray  # each bin's right edge
    mean: np.ndarray
    std: np.ndarray  # 0 with one run, NaN with none
    runs: np.ndarray  # runs with a value in each bin


def mean_curve(runs: Sequence[RunRecord], total: int, no_log: list[str] | None = None
               ) -> MeanCurve | None:
    """The runs' binned training curves (`run_curve` on the grid `(0, total]`) as their mean and
    sample std over seeds in each bin; None when no run logged an episode. Each run without
    one is described in `no_log`, when given."""
    binned = []
    x = None
    for run in runs:
        curve = run_curve(run, total)
        if curve is None:
            if no_log is not None:
                no_log.append(run.describe())
            continue
        x, values = curve
        binned.append(values)
    if not binned:
        return None
    values = np.vstack(binned)
    count = np.sum(np.isfinite(values), axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN leading bins
        mean = np.nanmean(values, axis=0)
        std = np.where(count > 1, np.nanstd(values, axis=0, ddof=1), 0.0)
    return MeanCurve(x, mean, np.where(count > 0, std, np.nan), count)


def add_runs(b: Builder) -> None:
    """The curves' methods on each game and seed."""
    budget = b.budget
    for env_id in budget.games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("MacroAction", env_id, seed)
            b.run("option_critic", "OptionCritic", env_id, seed, budget.steps, demo=False)
            b.run("compile_a2c", "CompILE", env_id, seed, budget.steps, budget.compile_flags)
            b.a2c("RAPL-A2C", env_id, seed)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Fig. 3: a panel of curves per game; the final scores' IQMs, P(RAPL > Y), profiles."""
    groups = group_runs(runs, lambda r: r.method)
    methods = ordered(groups, METHODS)
    games = sorted({r.env_id for rs in groups.values() for r in rs})
    curves: dict[tuple[str, str], MeanCurve] = {}
    no_log: list[str] = []
    for g in games:
        for m in methods:
            group = [r for r in groups[m] if r.env_id == g]
            if not group:
                continue
            # One grid per game and method: the budget of its runs (the manifest's steps).
            curve = mean_curve(group, max(r.steps for r in group), no_log)
            if curve is not None:
                curves[g, m] = curve
    w.csv(FILE, ("env_id", "method", "step", "mean_return", "std_return", "runs"),
          [(g, m, float(x[i]), mean[i], std[i], int(count[i]))
           for (g, m), (x, mean, std, count) in curves.items() for i in range(len(x))])

    plotted = [g for g in games if any((g, m) in curves for m in methods)]
    labels = game_labels(games)
    cols = min(3, max(1, len(plotted)))
    rows_n = max(1, math.ceil(len(plotted) / cols))
    width = max(6.5, 4.4 * cols)
    fig = figure(width, 3.3 * rows_n + 0.9)
    axes = np.atleast_1d(fig.subplots(rows_n, cols, squeeze=False)).ravel()
    for ax, g in zip(axes, plotted, strict=False):
        for m in methods:
            if (g, m) not in curves:
                continue
            x, mean, std, _ = curves[g, m]
            ax.plot(x, mean, color=colour(m), label=m, linewidth=1.6)
            ax.fill_between(x, mean - std, mean + std, color=colour(m), alpha=0.18,
                            linewidth=0)
        ax.set_title(labels[g])
        ax.set_xlabel("agent steps")
        ax.set_ylabel("episodic return")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    for ax in axes[len(plotted):]:
        ax.set_visible(False)
    fig.legend(handles=[legend_line(m) for m in methods], loc="outside lower center",
               ncols=min(len(methods), 5 if width >= 9 else 3))
    fig.suptitle("Fig. 3 — Training curves (mean ± std over seeds)")
    w.png(fig, FILE)

    agg = aggregate(w, groups)
    profile_lines = _profiles(w, agg, methods)
    lines = [f"Curves: each run's training episodes (`{RETURN_TAG}`) averaged in "
             f"{CURVE_BINS} equal step bins from 0 to its budget (an empty bin carries the "
             "last value forward), then mean ± sample std over seeds.", ""]
    if no_log:
        lines += [f"No TensorBoard returns in: {', '.join(no_log)}.", ""]
    lines += [*aggregate_lines(w, agg),
              *table(("method", "IQM [95 % CI]"),
                      [(m, interval(agg.iqm.get(m), agg.percent)) for m in methods
                       if m in agg.iqm])]
    lines += poi_lines(w, agg, "RAPL-A2C", [m for m in methods if m != "RAPL-A2C"])
    return lines + profile_lines


def _profiles(w: Writer, agg: Aggregate, methods: Sequence[str]) -> list[str]:
    """rliable's performance profiles of the final scores (`fig3_profiles.png/.csv`)."""
    names = [m for m in methods if m in agg.matrices]
    if not names:
        return []
    scale = 100.0 if agg.percent else 1.0
    top = max(float(np.max(agg.matrices[m])) for m in names)
    bottom = min(0.0, min(float(np.min(agg.matrices[m])) for m in names))
    taus = np.linspace(bottom, max(top, bottom + 1e-6) * 1.05, 41)
    profiles = performance_profiles({m: agg.matrices[m] for m in names}, taus, w.reps, w.seed)
    w.csv(PROFILE_FILE, ("method", "tau", "fraction_above", "ci_lo", "ci_hi"),
          [(m, float(t) * scale, p[i], lo[i], hi[i]) for m, (p, lo, hi) in profiles.items()
           for i, t in enumerate(taus)])
    fig = figure(6.5, 4.2)
    ax = fig.subplots()
    for m, (p, lo, hi) in profiles.items():
        ax.plot(taus * scale, p, color=colour(m), label=m, linewidth=1.8)
        ax.fill_between(taus * scale, lo, hi, color=colour(m), alpha=0.15, linewidth=0)
    unit = norm_axis_label(w, agg).replace(", IQM", "").replace(" (%)", ", %")
    ax.set_xlabel(f"threshold τ: {unit}")
    ax.set_ylabel("fraction of runs with score > τ")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(loc="best", framealpha=0.9)
    fig.suptitle("Fig. 3 (profiles) — score distributions over all runs and games")
    w.png(fig, PROFILE_FILE)
    return ["", f"Performance profiles (rliable, `{PROFILE_FILE}.png`): the fraction of runs "
            "of every game whose final score is above τ, with 95 % stratified-bootstrap "
            "bands, on the games of the aggregate above."]


EXPERIMENT = Experiment(
    name="curves", version=1,
    title="Training curves: A2C, MacroAction, OptionCritic, CompILE, RAPL-A2C", figure="Fig. 3",
    file=FILE, add_runs=add_runs, section=section, methods=METHODS,
    extra_files=(PROFILE_FILE,))
