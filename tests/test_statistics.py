"""The report's IQM and P(X > Y) of one resample (`statistics.iqm`, `statistics.improvement`)
are rliable's own numbers, bit for bit, so the bootstrap intervals built on them are rliable's
intervals: checked against rliable on matrices with ties, and on whole intervals."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rliable import library as rly
from rliable import metrics as rmetrics

from routine_gym.experiments.statistics import (
    _bootstrap_rng,
    improvement,
    iqm,
    iqm_intervals,
    probability_of_improvement,
)

# Small integers: ties within and across the two matrices are common, as in MinAtar scores.
SCORE = st.integers(min_value=-3, max_value=6).map(float) | st.floats(-100, 100, width=32)


def matrix(runs: int, games: int) -> st.SearchStrategy[np.ndarray]:
    return st.lists(st.lists(SCORE, min_size=games, max_size=games), min_size=runs,
                    max_size=runs).map(lambda rows: np.array(rows, dtype=np.float64))


@st.composite
def two_matrices(draw) -> tuple[np.ndarray, np.ndarray]:
    games = draw(st.integers(1, 5))
    return (draw(matrix(draw(st.integers(1, 7)), games)),
            draw(matrix(draw(st.integers(1, 7)), games)))


@settings(max_examples=300, deadline=None)
@given(two_matrices())
def test_improvement_is_rlables_probability_of_improvement_bit_for_bit(pair):
    x, y = pair
    assert improvement(x, y) == rmetrics.probability_of_improvement(x, y)
    assert improvement(x, x) == 0.5


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 9).flatmap(lambda runs: matrix(runs, 3)))
def test_iqm_is_rliables_aggregate_iqm_bit_for_bit(scores):
    assert iqm(scores) == rmetrics.aggregate_iqm(scores)


def test_by_hand():
    # 8 scores, 2 cut from each end: the mean of 3, 4, 5, 6
    assert iqm(np.array([[1.0, 3.0, 5.0, 7.0], [100.0, 4.0, 6.0, -2.0]])) == 4.5
    # game 1: X {3, 1} against Y {2, 1}: 3 > 2, 3 > 1, 1 = 1 (a half), 1 < 2: 2.5 of 4;
    # game 2: X {0, 0} against Y {5, 5}: 0 of 4; the mean of 0.625 and 0
    x, y = np.array([[3.0, 0.0], [1.0, 0.0]]), np.array([[2.0, 5.0], [1.0, 5.0]])
    assert improvement(x, y) == pytest.approx(0.3125)


def test_the_intervals_are_rliables_intervals():
    """The bootstrap of each, from the same seed, with rliable's functions and with ours."""
    rng = np.random.default_rng(0)
    x = rng.integers(0, 12, size=(5, 5)).astype(np.float64)
    y = rng.integers(0, 12, size=(5, 5)).astype(np.float64)
    with _bootstrap_rng(3) as random_state:
        points, cis = rly.get_interval_estimates(
            {"X,Y": (x, y)},
            lambda a, b: np.array([rmetrics.probability_of_improvement(a, b)]), reps=300,
            random_state=random_state)
    assert probability_of_improvement(x, y, reps=300, seed=3) == (
        float(points["X,Y"][0]), float(cis["X,Y"][0, 0]), float(cis["X,Y"][1, 0]))
    with _bootstrap_rng(3) as random_state:
        points, cis = rly.get_interval_estimates(
            {"x": x}, lambda a: np.array([rmetrics.aggregate_iqm(a)]), reps=300,
            random_state=random_state)
    assert iqm_intervals({"x": x}, reps=300, seed=3)["x"] == (
        float(points["x"][0]), float(cis["x"][0, 0]), float(cis["x"][1, 0]))
