"""Fig. 6, discovery ablations: RAPL-A2C with its routine discovery replaced (RR, PbE, RF, RP:
other proposers; ID: the demo of an expert trained a tenth as long), against the full model
and A2C; and BPE, beyond the paper: Full's settings with byte-pair encoding proposing the
candidates instead of Sequitur (`routine_gym.mining.BPEMiner`, issue 29).

Error bars: the IQM's 95 % CI.
"""

from __future__ import annotations

import math

import numpy as np

from routine_gym.experiments.drawing import COLOURS, colour, figure, game_labels, iqm_bars
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.sections import (
    aggregate,
    aggregate_lines,
    group_runs,
    norm_axis_label,
    ordered,
    per_env_means,
)
from routine_gym.experiments.specs import Builder, has_shipped_demo
from routine_gym.experiments.writing import Writer, interval, table

FILE = "fig6_ablation"
#: The discovery ablations of the paper, then BPE, and the proposer each one is. A variant
#: added here adds its own runs: the flags, so the keys, of the others' runs stay as they were.
ABLATIONS = {"Full": "full", "RR": "random", "PbE": "enumerate", "RF": "random-fetch",
             "RP": "repeat", "BPE": "bpe"}
#: The discovery ablations of Fig. 6 in the paper's order, then BPE, and one colour each (Full
#: is the full RAPL-A2C, in its colour; the others are colours no method has, so a variant is
#: never read as a baseline; ID, the same discovery on a weaker demo, is a light shade of
#: Full's).
VARIANTS = ("Full", "RR", "PbE", "RF", "ID", "RP", "BPE")
VARIANT_COLOURS = {"Full": COLOURS["RAPL-A2C"], "RR": "#bcbd22", "PbE": "#393b79",
                   "RF": "#8c6d31", "ID": "#ff9896", "RP": "#7b4173", "BPE": "#637939"}


def add_runs(b: Builder) -> None:
    """A2C, and RAPL-A2C with each discovery variant, on each ablation game and seed (ID:
    with its weaker expert; BPE: `--proposer bpe`)."""
    budget = b.budget
    games = budget.games if budget.ablation_games is None else budget.ablation_games
    for env_id in games:
        full_steps = budget.shipped_expert_steps if has_shipped_demo(env_id) else (
            budget.expert_steps)
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            for name, proposer in ABLATIONS.items():
                b.a2c("RAPL-A2C", env_id, seed, {"discovery": name}, proposer=proposer)
            b.a2c("RAPL-A2C", env_id, seed, {"discovery": "ID"},
                  expert_steps=max(full_steps // 10, 1))


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Fig. 6: the IQM of each discovery variant and of A2C, and their per-game returns."""
    def label(run: RunRecord) -> str | None:
        if run.method == "A2C" and not run.variant:
            return "A2C"
        if run.method == "RAPL-A2C" and "discovery" in run.variant:
            return str(run.variant["discovery"])
        return None

    groups = group_runs(runs, label)
    names = ordered(groups, (*VARIANTS, "A2C"))
    agg = aggregate(w, groups)
    w.csv(FILE, ("variant", "runs", "score_iqm", "score_ci_lo", "score_ci_hi",
                              "score"),
          [(n, len(groups[n]), *agg.iqm.get(n, (math.nan,) * 3),
            "normalised" if agg.percent else "raw") for n in names])

    fig = figure(max(5.5, 1.0 * len(names) + 2), 4.2)
    ax = fig.subplots()
    iqm_bars(ax, names, agg, [colour(n, VARIANT_COLOURS) for n in names])
    ax.set_xticks(np.arange(len(names)), [n if n != "A2C" else "A2C\n(reference)"
                                          for n in names])
    ax.set_ylabel(norm_axis_label(w, agg))
    ax.set_xlabel("routine discovery (RAPL-A2C)")
    ax.set_title("Fig. 6 — Discovery ablations (IQM, 95 % bootstrap CI)")
    w.png(fig, FILE)

    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    labels = game_labels(envs)
    table_rows = []
    for n in names:
        per_env = per_env_means(groups[n], envs)
        table_rows.append((n, interval(agg.iqm.get(n), agg.percent), *per_env))
    return ["Variants of RAPL-A2C's routine discovery (Full: the paper's; RR, PbE, RF, RP: "
            "other proposers; ID: the demo of an expert trained a tenth as long; BPE, beyond "
            "the paper: byte-pair encoding proposes the candidates instead of Sequitur), and "
            "A2C for reference. Per-game columns: mean over seeds of the final mean return "
            "(raw).", "", *aggregate_lines(w, agg),
            *table(("variant", "IQM [95 % CI]", *[labels[e] for e in envs]), table_rows)]


EXPERIMENT = Experiment(
    name="ablation", version=1, title="Discovery ablations: Full, RR, PbE, RF, ID, RP, BPE",
    figure="Fig. 6", file=FILE, add_runs=add_runs, section=section, methods=VARIANTS,
    colours=VARIANT_COLOURS)
