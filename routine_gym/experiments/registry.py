"""The registry of experiments: one line per experiment, in the order of `experiment list` and
of the report. Adding an experiment is one file in `routine_gym/experiments/paper/` holding an
`Experiment`, and one `register` line here.

`build(name, budget)` makes an experiment's entries (its runs with their labels) at a budget;
`left_out`, `games` and `count_runs` say what it leaves out, which games it has and how big it
is. A budget may hold only some experiments (`long`: rl alone); `available` says which, and
building another there is a one-line `UsageError`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from routine_gym.errors import UsageError
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.paper import (
    ablation,
    coinrun,
    curves,
    diagnosis,
    equal_frames,
    imitation,
    rl,
    scalability,
    tune,
)
from routine_gym.experiments.specs import BUDGETS, Builder, Entry

__all__ = ["EXPERIMENTS", "available", "build", "count_runs", "games", "left_out",
           "register"]

#: The experiments by name, in the order of `experiment list` and of the report.
EXPERIMENTS: dict[str, Experiment] = {}


def register(experiment: Experiment) -> Experiment:
    """Add `experiment` to `EXPERIMENTS` (after those there).

    Raises:
        ValueError: an experiment of that name is registered already.
    """
    if experiment.name in EXPERIMENTS:
        raise ValueError(f"an experiment named {experiment.name!r} is registered already")
    EXPERIMENTS[experiment.name] = experiment
    return experiment


register(tune.EXPERIMENT)
register(imitation.EXPERIMENT)
register(rl.EXPERIMENT)
register(curves.EXPERIMENT)
register(coinrun.EXPERIMENT)
register(scalability.EXPERIMENT)
register(ablation.EXPERIMENT)
register(diagnosis.EXPERIMENT)
register(equal_frames.EXPERIMENT)


def build(name: str, budget: str, seeds: Sequence[int] | None = None,
          envs: Sequence[str] | None = None) -> list[Entry]:
    """The entries of experiment `name` at `budget`, optionally only some seeds and envs
    (`envs` filters the games of every part; CoinRun's experiment has one game).

    Raises:
        UsageError: an unknown experiment or budget, an experiment the budget has no runs of
            (`available`), a seed outside the budget's, or an env that is not one of the
            experiment's games at that budget (`games`).
    """
    return _build(name, budget, seeds, envs)[0]


def available(name: str, budget: str) -> bool:
    """Whether experiment `name` has runs at `budget` (the `long` budget has rl's alone).

    Raises:
        UsageError: an unknown experiment or budget.
    """
    _check(name, budget)
    return BUDGETS[budget].has(name)


def _check(name: str, budget: str) -> None:
    if name not in EXPERIMENTS:
        raise UsageError(f"unknown experiment {name!r}; choose from {', '.join(EXPERIMENTS)}")
    if budget not in BUDGETS:
        raise UsageError(f"unknown budget {budget!r}; choose from {', '.join(BUDGETS)}")


def left_out(name: str, budget: str, envs: Sequence[str] | None = None
             ) -> list[dict[str, Any]]:
    """The settings of experiment `name` at `budget` that have no runs, each with its env,
    variant and why (the scalability experiment's minimum lengths a shipped demo has no
    routine of)."""
    return _build(name, budget, None, envs)[1]


def _build(name: str, budget: str, seeds: Sequence[int] | None,
           envs: Sequence[str] | None) -> tuple[list[Entry], list[dict[str, Any]]]:
    if not available(name, budget):
        holds = [n for n in EXPERIMENTS if BUDGETS[budget].has(n)]
        raise UsageError(f"the {budget} budget has no runs of the {name} experiment (it holds "
                         f"{', '.join(holds)} only); run {name} at "
                         f"{', '.join(b for b in BUDGETS if BUDGETS[b].has(name))}")
    sizes = BUDGETS[budget]
    if envs:
        known = games(name, budget)
        unknown = [e for e in envs if e not in known]
        if unknown:
            raise UsageError(f"--envs {unknown[0]} is not a game of the {name} experiment at "
                             f"the {budget} budget (its games: {', '.join(known)})")
        keep = set(envs)
        sizes = replace(sizes, games=tuple(g for g in sizes.games if g in keep),
                        rl_games=tuple(g for g in sizes.rl_games if g in keep),
                        imitation_games=tuple(g for g in sizes.imitation_games if g in keep),
                        ablation_games=None if sizes.ablation_games is None else tuple(
                            g for g in sizes.ablation_games if g in keep))
    builder = Builder(sizes)
    EXPERIMENTS[name].add_runs(builder)
    entries = list(builder.entries.values())
    if seeds:
        bad = [s for s in seeds if not 1 <= s <= sizes.seeds]
        if bad:
            raise UsageError(f"--seeds {bad[0]} is outside the {budget} budget's seeds "
                             f"1..{sizes.seeds}")
        entries = _with_needs(entries, [e for e in entries
                                        if e.role != "main" or e.seed in set(seeds)])
    return entries, builder.left_out


def _with_needs(every: list[Entry], chosen: list[Entry]) -> list[Entry]:
    """`chosen` and every run of `every` they need, all the way down, in `every`'s order: a
    seed's run may need other seeds' (a diagnosis arm sized by RAPL-A2C's steps per decision
    over all seeds), and a sweep of one seed must train those too."""
    by_key = {e.run.key: e for e in every}
    wanted = {e.run.key for e in chosen}
    todo = [k for e in chosen for k in e.run.needs]
    while todo:
        key = todo.pop()
        if key in by_key and key not in wanted:
            wanted.add(key)
            todo.extend(by_key[key].run.needs)
    return [e for e in every if e.run.key in wanted]


@functools.cache
def games(name: str, budget: str) -> tuple[str, ...]:
    """The games experiment `name` has at `budget` (what `--envs` may name), sorted.

    Raises:
        UsageError: an unknown experiment or budget.
    """
    return tuple(sorted({e.env_id for e in build(name, budget) if e.role == "main"}))


def count_runs(name: str, budget: str) -> tuple[int, int]:
    """(runs, agent steps) of experiment `name` at `budget`, experts included."""
    entries = build(name, budget)
    runs = {e.run.key: e.run.steps for e in entries}
    return len(runs), sum(runs.values())
