"""Table 1, imitation: BC, GAIL, SQIL and RAPL-SQIL learning from the demo, compared by the
alignment of their episodes with it and by their normalised score.

Error bars: alignment ± sample std over all runs; score IQM with its 95 % CI.
"""

from __future__ import annotations

import math

import numpy as np

from routine_gym.experiments.drawing import colour, figure, game_labels, iqm_bars
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord, is_number
from routine_gym.experiments.sections import (
    aggregate,
    aggregate_lines,
    group_runs,
    norm_axis_label,
    ordered,
    per_env_means,
    poi_lines,
)
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.statistics import mean_std
from routine_gym.experiments.writing import Writer, interval, num, pct, table

FILE = "table1_imitation"
METHODS = ("BC", "GAIL", "SQIL", "RAPL-SQIL")
#: The paper's Table 1 (Atari): method → (alignment, human-normalised score).
PAPER_TABLE1 = {"BC": (0.18, 0.183), "GAIL": (0.16, 0.264), "SQIL": (0.28, 0.294),
                "RAPL-SQIL": (0.34, 0.361)}


def add_runs(b: Builder) -> None:
    """BC, GAIL, SQIL and RAPL-SQIL on each imitation game and seed."""
    budget = b.budget
    for env_id in budget.imitation_games:
        for seed in b.seeds():
            b.run("bc", "BC", env_id, seed, budget.bc_steps)
            b.run("gail", "GAIL", env_id, seed, budget.gail_steps)
            b.run("rapl_sqil", "SQIL", env_id, seed, budget.sqil_steps, [("num-routines", 0)])
            b.run("rapl_sqil", "RAPL-SQIL", env_id, seed, budget.sqil_steps)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Table 1: alignment and score IQM per method, per-game returns, P(RAPL-SQIL > Y)."""
    groups = group_runs(runs, lambda r: r.method)
    methods = ordered(groups, METHODS)
    agg = aggregate(w, groups)
    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    alignment = {m: mean_std([a for r in groups[m]
                               if is_number(a := r.result["eval"].get("mean_alignment"))
                               and math.isfinite(a)]) for m in methods}

    rows = []
    for m in methods:
        point, lo, hi = agg.iqm.get(m, (math.nan,) * 3)
        rows.append((m, len(groups[m]), *alignment[m], point, lo, hi,
                     "normalised" if agg.percent else "raw"))
    w.csv(FILE, ("method", "runs", "alignment_mean", "alignment_std",
                               "score_iqm", "score_ci_lo", "score_ci_hi", "score"), rows)

    fig = figure(10, 4.2)
    left, right = fig.subplots(1, 2)
    x = np.arange(len(methods))
    colours = [colour(m) for m in methods]
    means = np.array([alignment[m][0] for m in methods])
    stds = np.array([alignment[m][1] for m in methods])
    left.bar(x, np.nan_to_num(means), yerr=stds, color=colours, capsize=5)
    left.set_xticks(x, methods)
    left.set_ylabel("alignment score")
    left.set_title("Alignment with the demo (mean ± std over runs)")
    iqm_bars(right, methods, agg, colours)
    right.set_ylabel(norm_axis_label(w, agg))
    right.set_title("Score (IQM, 95 % bootstrap CI)")
    paper = [(i, PAPER_TABLE1[m]) for i, m in enumerate(methods) if m in PAPER_TABLE1]
    if paper:
        marker = {"marker": "D", "facecolors": "none", "edgecolors": "black", "zorder": 3,
                  "label": "paper (Atari)"}
        left.scatter([i for i, _ in paper], [p[0] for _, p in paper], **marker)
        right.scatter([i for i, _ in paper], [100 * p[1] for _, p in paper], **marker)
        left.legend(loc="upper left")
    fig.suptitle("Table 1 — Imitation: BC, GAIL, SQIL, RAPL-SQIL")
    w.png(fig, FILE)

    labels = game_labels(envs)
    header = ("method", "alignment (mean ± std)", "score IQM [95 % CI]",
              *[f"{labels[e]} return" for e in envs], "paper alignment", "paper HNS (Atari)")
    table_rows = []
    for m in methods:
        per_env = per_env_means(groups[m], envs)
        paper_align, paper_hns = PAPER_TABLE1.get(m, (None, None))
        a_mean, a_std = alignment[m]
        a_text = f"{num(a_mean, 3)} ± {num(a_std, 3)}" if math.isfinite(a_mean) else "–"
        table_rows.append((m, a_text, interval(agg.iqm.get(m), agg.percent), *per_env,
                      num(paper_align) if paper_align is not None else "–",
                      pct(paper_hns) if paper_hns is not None else "–"))
    lines = ["Alignment: each run's mean alignment of its evaluation episodes with the demo, "
             "mean ± sample std over all runs (every env and seed). Per-env returns: mean "
             "over seeds of the final evaluation's mean return (raw).", "",
             *aggregate_lines(w, agg), *table(header, table_rows)]
    return lines + poi_lines(w, agg, "RAPL-SQIL", [m for m in methods if m != "RAPL-SQIL"])


EXPERIMENT = Experiment(
    name="imitation", version=1,
    title="Imitation: BC, GAIL, SQIL, RAPL-SQIL (alignment and score)", figure="Table 1",
    file=FILE, add_runs=add_runs, section=section, methods=METHODS)
