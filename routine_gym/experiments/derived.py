"""Flags a run takes from other runs' results, decided when the sweep starts it.

A run of the fair protocol (issue 47) learns with its method's tuned settings, which the tune
runs decide; a diagnosis arm makes as many updates as RAPL-A2C, whose steps per decision its
runs measure. Such a run names a *rule* and the runs it reads (`RunSpec.derived`); the runs
are among its `needs`, so the sweep starts it once they have finished, and `derived_flags`
turns their `result.json` into flags. The rule and the runs are in the run's key, the values
are not: the key is fixed before any run has trained, as `@run:KEY/` paths are.

Rules (each a pure function of the runs' results, tested with numbers by hand):

- `tuned`: `(points, keys)`: the grid point whose runs have the highest mean final score
  (`choose_point`); its flags. A run that diverged (`results.divergence`) scores -inf: its
  point loses, as a setting the method cannot learn with, and the choice is made among the
  others (`grid_keys` are the runs whose divergence is such an answer, not a fault).
- `updates-of`: `(num_steps, keys)`: `--num-steps` = round(num_steps × the runs' mean steps
  per decision): an A2C rollout of that many steps per env holds as many primitive steps as
  RAPL's rollout of `num_steps` decisions, so A2C makes RAPL's number of updates at its frames.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.errors import UsageError

__all__ = ["RULES", "choose_point", "derived_flags", "grid_keys", "grid_scores",
           "rollout_for_updates"]

#: A grid point: its flags as `(flag, value)` pairs, in the order the grid lists them.
Point = tuple[tuple[str, Any], ...]


def _result(runs: Path, key: str) -> Mapping[str, Any]:
    from routine_gym.experiments.results import divergence, load_result

    path = runs / key / "result.json"
    if not path.exists():
        diverged = divergence(runs / key)
        if diverged is not None:
            raise UsageError(f"run {key} diverged ({diverged}): the runs whose flags it "
                             "decides cannot start")
        raise UsageError(f"run {key} has not finished ({path} is missing): the runs whose "
                         "flags it decides cannot start yet")
    return load_result(path, key)


def grid_scores(points: Sequence[tuple[Point, Sequence[float]]]) -> list[float]:
    """Each grid point's mean final score over its runs (NaN for a point with none).

    Example:
        >>> grid_scores([((("lr", 1),), [2.0, 4.0]), ((("lr", 2),), [])])
        [3.0, nan]
    """
    return [float(np.mean(scores)) if len(scores) else math.nan for _, scores in points]


def choose_point(points: Sequence[tuple[Point, Sequence[float]]]) -> int:
    """The index of the grid point with the highest mean score over its runs; on a tie the
    first in grid order (the grids list the scripts' defaults first). A run that diverged
    scores -inf, so a point with one loses to every point whose runs all finished.

    Raises:
        ValueError: no point has a score, or every point has a run that diverged.

    Example:
        >>> choose_point([((("lr", 1),), [2.0, 4.0]), ((("lr", 2),), [5.0, 1.0]),
        ...               ((("lr", 3),), [3.5, 2.5])])
        0
        >>> choose_point([((("lr", 1),), [2.0, 4.0]), ((("lr", 2),), [9.0, -math.inf])])
        0
    """
    means = grid_scores(points)
    if all(math.isnan(m) for m in means):
        raise ValueError("no grid point has a finished run")
    if not any(math.isfinite(m) for m in means):
        raise ValueError("every grid point has a run that diverged")
    return int(np.nanargmax(means))  # the first of equal maxima


def rollout_for_updates(num_steps: int, steps_per_decision: Sequence[float]) -> int:
    """The `--num-steps` that gives A2C RAPL's updates at A2C's frames: RAPL's rollout of
    `num_steps` decisions runs `num_steps × spd` primitive steps per env (spd: the mean steps
    per decision of its runs), so A2C's rollout of that many steps ends after as many frames.

    Example:
        >>> rollout_for_updates(5, [1.3, 1.5]), rollout_for_updates(5, [4.0])
        (7, 20)
    """
    spd = float(np.mean(steps_per_decision))
    if not math.isfinite(spd) or spd < 1.0:
        raise ValueError(f"steps per decision {spd!r} is not a number ≥ 1")
    return max(int(round(num_steps * spd)), 1)


def _score(result: Mapping[str, Any]) -> float:
    return float(result["eval"]["mean_return"])


def _steps_per_decision(result: Mapping[str, Any]) -> float:
    """A run's steps per decision over its whole run: its primitive steps over its decisions
    (`result.json`'s counters)."""
    counters = result.get("counters") or {}
    steps, decisions = counters.get("primitive_steps"), counters.get("decisions")
    if not steps or not decisions:
        raise UsageError(f"run {result.get('key')} has no step and decision counters in its "
                         "result.json; rerun it with this routine-gym")
    return float(steps) / float(decisions)


def _tuned_score(runs: Path, key: str) -> float:
    """A tune run's final score; -inf for one that diverged (its point loses)."""
    from routine_gym.experiments.results import divergence

    if divergence(runs / key) is not None:  # None once the run has a result.json
        return -math.inf
    return _score(_result(runs, key))


def _tuned(params: Any, runs: Path) -> dict[str, Any]:
    points = [(tuple(map(tuple, point)), [_tuned_score(runs, k) for k in keys])
              for point, keys in params]
    try:
        return dict(points[choose_point(points)][0])
    except ValueError as exc:
        raise UsageError(f"cannot choose a tuned setting: {exc} (runs "
                         f"{', '.join(k for _, keys in params for k in keys)}); a grid whose "
                         "every point diverges needs lower rates, or delete the runs' "
                         "diverged.json to train them again") from None


def _updates_of(params: Any, runs: Path) -> dict[str, Any]:
    num_steps, keys = params
    spd = [_steps_per_decision(_result(runs, k)) for k in keys]
    return {"num-steps": rollout_for_updates(int(num_steps), spd)}


RULES = {"tuned": _tuned, "updates-of": _updates_of}


def grid_keys(derived: Sequence[Sequence[Any]]) -> tuple[str, ...]:
    """The runs a `tuned` rule of `derived` reads: grid points, whose divergence is an answer
    (the point loses) rather than a fault.

    Example:
        >>> grid_keys([("tuned", [([["lr", 1]], ["a", "b"]), ([["lr", 2]], ["c"])]),
        ...            ("updates-of", (5, ["d"]))])
        ('a', 'b', 'c')
    """
    keys = [k for rule, params in derived if rule == "tuned" for _, ks in params for k in ks]
    return tuple(dict.fromkeys(keys))


def derived_keys(derived: Sequence[tuple[str, Any]]) -> tuple[str, ...]:
    """Every run key the rules of `derived` read (a run's extra `needs`)."""
    keys: list[str] = []
    for rule, params in derived:
        if rule == "tuned":
            keys += [k for _, point_keys in params for k in point_keys]
        elif rule == "updates-of":
            keys += list(params[1])
        else:
            raise ValueError(f"unknown rule {rule!r}")
    return tuple(dict.fromkeys(keys))


def derived_flags(derived: Sequence[Sequence[Any]], runs: Path) -> dict[str, Any]:
    """The flags `derived`'s rules decide from the finished runs in `runs` (later rules win).

    Raises:
        UsageError: a run a rule reads has not finished, or lacks what the rule reads.
    """
    flags: dict[str, Any] = {}
    for rule, params in derived:
        if rule not in RULES:
            raise UsageError(f"unknown rule {rule!r} in a run's config; choose from "
                             f"{', '.join(RULES)}")
        flags.update(RULES[rule](params, runs))
    return flags
