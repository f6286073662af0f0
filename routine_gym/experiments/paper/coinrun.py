"""Fig. 4, CoinRun generalisation: A2C and RAPL-A2C trained on 100 easy levels, evaluated on
them, on unseen easy levels and on hard levels. Scores stay raw (not normalised).

Error bars: ± sample std over seeds.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from routine_gym.experiments.drawing import colour, figure, game_labels
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.sections import group_runs, ordered
from routine_gym.experiments.specs import COINRUN, Builder
from routine_gym.experiments.statistics import mean_std
from routine_gym.experiments.writing import Writer, num, table

FILE = "fig4_coinrun"
METHODS = ("A2C", "RAPL-A2C")
#: The evaluations of a run (`result.json`'s `evals` name, the final one is `easy`) and their
#: labels.
LEVELS = (("train", "train levels"), ("easy", "unseen easy"), ("hard", "hard"))


class LevelStats(NamedTuple):
    """A method's returns on one kind of levels: mean and sample std over its runs."""

    mean: float
    std: float
    runs: int


NO_RUNS = LevelStats(math.nan, math.nan, 0)


def add_runs(b: Builder) -> None:
    """A2C and RAPL-A2C on CoinRun's 100 easy training levels, each seed; evaluated also on
    the training and hard levels."""
    extra = [("extra-evals", ("train", "hard"))]
    for seed in b.seeds():
        for method in ("A2C", "RAPL-A2C"):
            b.a2c(method, COINRUN, seed, steps=b.budget.coinrun_steps, extra=extra)


def _level_score(run: RunRecord, levels: str) -> float | None:
    if levels == "easy":
        return run.score
    evaluation = (run.result.get("evals") or {}).get(levels)
    return None if evaluation is None else float(evaluation["mean_return"])


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Fig. 4: per method, the raw returns on each kind of levels (a panel per env)."""
    groups = group_runs(runs, lambda r: r.method)
    methods = ordered(groups, METHODS)
    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    stats: dict[tuple[str, str, str], LevelStats] = {}
    for e in envs:
        for m in methods:
            for levels, _ in LEVELS:
                scores = [s for r in groups[m] if r.env_id == e
                          and (s := _level_score(r, levels)) is not None]
                if scores:
                    stats[e, m, levels] = LevelStats(*mean_std(scores), len(scores))
    w.csv(FILE, ("env_id", "method", "levels", "mean_return", "std_return", "runs"),
          [(e, m, levels, *values) for (e, m, levels), values in stats.items()])

    fig = figure(max(5.5, 4.5 * len(envs)), 4.2)
    axes = np.atleast_1d(fig.subplots(1, max(1, len(envs)), squeeze=False)).ravel()
    width = 0.8 / max(1, len(methods))
    for ax, e in zip(axes, envs, strict=False):
        x = np.arange(len(LEVELS))
        for i, m in enumerate(methods):
            values = [stats.get((e, m, levels), NO_RUNS) for levels, _ in LEVELS]
            ax.bar(x + (i - (len(methods) - 1) / 2) * width,
                   [np.nan_to_num(v.mean) for v in values], width,
                   yerr=[v.std for v in values], color=colour(m), label=m, capsize=4)
        ax.set_xticks(x, [name for _, name in LEVELS])
        ax.set_ylabel("return (mean ± std over seeds)")
        ax.set_title(game_labels(envs)[e])
        ax.legend()
    fig.suptitle("Fig. 4 — CoinRun: training levels, unseen easy and hard levels")
    w.png(fig, FILE)

    table_rows = []
    for e in envs:
        for m in methods:
            cells = []
            for levels, _ in LEVELS:
                mean, std, n = stats.get((e, m, levels), NO_RUNS)
                cells.append(f"{num(mean)} ± {num(std)} (n={n})" if n else "–")
            table_rows.append((e, m, *cells))
    return ["Raw returns (CoinRun scores 10 for a finished level), mean ± sample std over "
            "seeds: `train` is the 100 training levels, `unseen easy` the final evaluation, "
            "`hard` unseen hard levels.", "",
            *table(("env", "method", *[name for _, name in LEVELS]), table_rows)]


EXPERIMENT = Experiment(
    name="coinrun", version=1,
    title="CoinRun generalisation: train, unseen easy and hard levels", figure="Fig. 4",
    file=FILE, add_runs=add_runs, section=section, normalised=False, methods=METHODS)
