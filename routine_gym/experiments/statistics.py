"""Statistics of a report: rliable's aggregates over `(runs, games)` score matrices (IQM with
95 % stratified-bootstrap intervals, performance profiles, probability of improvement) and the
plain ones (mean and sample std, standard error).

rliable loads when an aggregate is computed, not on import.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager

import numpy as np

from routine_gym.experiments.results import RunRecord

__all__ = ["iqm_intervals", "mean_std", "performance_profiles", "probability_of_improvement",
           "score_matrix", "standard_error"]


def score_matrix(runs: Sequence[RunRecord], games: Sequence[str],
                 value: Callable[[RunRecord], float]) -> np.ndarray | None:
    """The `(runs, games)` matrix rliable aggregates: column `g` holds `value(run)` of the
    finished runs of game `g` by increasing seed, cut to the fewest runs any game has (a
    rectangle); None when a game has none."""
    columns = []
    for game in games:
        done = sorted((r for r in runs if r.env_id == game and r.finished), key=lambda r: r.seed)
        columns.append([value(r) for r in done])
    if not columns or min(len(c) for c in columns) == 0:
        return None
    n = min(len(c) for c in columns)
    return np.array([c[:n] for c in columns], dtype=np.float64).T


@contextmanager
def _bootstrap_rng(seed: int) -> Iterator[np.random.RandomState]:
    # rliable 1.2's stratified bootstraps draw their indices from NumPy's global RNG
    # (np.random.choice) whatever random_state says, so the global RNG is seeded too, and
    # put back afterwards, to make the intervals reproducible.
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        with warnings.catch_warnings():
            # arch warns about the RandomState rliable hands it.
            warnings.filterwarnings("ignore", message="random_state is deprecated",
                                    category=FutureWarning)
            yield np.random.RandomState(seed)
    finally:
        np.random.set_state(state)  # noqa: NPY002


def iqm_intervals(score_dict: Mapping[str, np.ndarray], reps: int = 2000,
                  seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """`{name: (IQM, lo, hi)}`: rliable's IQM of each `(runs, games)` matrix and its 95 %
    stratified-bootstrap percentile interval (`reps` resamples of the runs within each game).
    Each matrix is resampled from the same seed, so its interval does not depend on the
    others."""
    from rliable import library as rly
    from rliable import metrics as rmetrics

    intervals = {}
    for name, scores in score_dict.items():
        with _bootstrap_rng(seed) as random_state:
            points, cis = rly.get_interval_estimates(
                {name: scores}, lambda x: np.array([rmetrics.aggregate_iqm(x)]), reps=reps,
                random_state=random_state)
        intervals[name] = (float(points[name][0]), float(cis[name][0, 0]),
                           float(cis[name][1, 0]))
    return intervals


def performance_profiles(score_dict: Mapping[str, np.ndarray], taus: np.ndarray,
                         reps: int = 2000, seed: int = 0
                         ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`{name: (profile, lo, hi)}`: rliable's score distribution, the fraction of runs (of every
    game) scoring above each threshold in `taus`, with its 95 % stratified-bootstrap band."""
    from rliable import library as rly

    with _bootstrap_rng(seed):
        profiles, cis = rly.create_performance_profile(dict(score_dict), taus, reps=reps)
    return {name: (np.asarray(profiles[name], dtype=np.float64),
                   np.asarray(cis[name][0], dtype=np.float64),
                   np.asarray(cis[name][1], dtype=np.float64)) for name in score_dict}


def probability_of_improvement(x: np.ndarray, y: np.ndarray, reps: int = 2000,
                               seed: int = 0) -> tuple[float, float, float]:
    """`(P(X > Y), lo, hi)`: rliable's probability that a run of X beats a run of Y on a game,
    averaged over games (ties count a half), with its 95 % stratified-bootstrap interval;
    `x` and `y` are `(runs, games)` matrices over the same games."""
    from rliable import library as rly
    from rliable import metrics as rmetrics

    with _bootstrap_rng(seed) as random_state:
        points, cis = rly.get_interval_estimates(
            {"X,Y": (x, y)},
            lambda a, b: np.array([rmetrics.probability_of_improvement(a, b)]), reps=reps,
            random_state=random_state)
    return float(points["X,Y"][0]), float(cis["X,Y"][0, 0]), float(cis["X,Y"][1, 0])


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value; NaN for none)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return math.nan, math.nan
    std = float(arr.std(ddof=1)) if arr.size > 1 else 0.0
    return float(arr.mean()), std


def standard_error(values: Sequence[float]) -> float:
    """The standard error of the mean (0 for one value)."""
    arr = np.asarray(values, dtype=np.float64)
    return float(arr.std(ddof=1) / math.sqrt(arr.size)) if arr.size > 1 else 0.0
