"""Metrics of SPEC §5, checked against numbers worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from routine_gym.metrics import (
    HUMAN_RANDOM_SCORES,
    alignment_score,
    atari_game_name,
    human_normalized_score,
    iqm,
    relative_performance,
)

# -- alignment -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("demo", "agent", "expected"),
    [
        # padded to [0,1,3,-1]: delete 2 and insert -1 → distance 2 → 1 − 2/4
        ([0, 1, 2, 3], [0, 1, 3], 0.5),
        # cut to [0,1,2,3]: identical prefix
        ([0, 1, 2, 3], [0, 1, 2, 3, 5, 5], 1.0),
        ([0, 1, 2, 3], [0, 1, 2, 3], 1.0),
        # padded to [-1,-1,-1,-1]: four substitutions
        ([0, 1, 2, 3], [], 0.0),
        # a shift: one deletion and one insertion, where a position-wise match would give 0
        ([0, 1, 2, 3], [1, 2, 3, 0], 0.5),
        # cut to [2,2,2]: two substitutions → 1 − 2/3
        ([2, 5, 5], [2, 2, 2, 2], 1 / 3),
        ([4], [5], 0.0),
    ],
)
def test_alignment_score_hand_examples(demo, agent, expected):
    assert alignment_score(demo, agent) == pytest.approx(expected)


def test_alignment_score_accepts_numpy_arrays():
    demo = np.array([0, 1, 2, 3], dtype=np.int64)
    assert alignment_score(demo, np.array([0, 1, 3], dtype=np.int32)) == pytest.approx(0.5)


def test_alignment_score_errors():
    with pytest.raises(ValueError, match="empty"):
        alignment_score([], [0, 1])
    with pytest.raises(ValueError, match="negative"):
        alignment_score([0, 1], [-1, 1])
    with pytest.raises(TypeError, match="integer"):
        alignment_score([0.5, 1.0], [0, 1])
    with pytest.raises(ValueError, match="1-D"):
        alignment_score([[0, 1]], [0, 1])


@given(
    st.lists(st.integers(0, 5), min_size=1, max_size=30),
    st.lists(st.integers(0, 5), max_size=40),
)
def test_alignment_score_lies_in_unit_interval(demo, agent):
    score = alignment_score(demo, agent)
    assert 0.0 <= score <= 1.0
    assert alignment_score(demo, demo) == 1.0


# -- human-normalised score ------------------------------------------------------------------


def test_table_has_the_57_games_with_the_published_numbers():
    assert len(HUMAN_RANDOM_SCORES) == 57
    # Spot checks against DQN Zoo's atari_data.py.
    assert HUMAN_RANDOM_SCORES["Qbert"] == (163.9, 13455.0)
    assert HUMAN_RANDOM_SCORES["Pong"] == (-20.7, 14.6)
    assert HUMAN_RANDOM_SCORES["MontezumaRevenge"] == (0.0, 4753.3)
    assert HUMAN_RANDOM_SCORES["Qbert"].human == 13455.0
    assert all(s.human != s.random for s in HUMAN_RANDOM_SCORES.values())
    with pytest.raises(TypeError):
        HUMAN_RANDOM_SCORES["Qbert"] = (0.0, 1.0)  # read-only


@pytest.mark.parametrize(
    "env_id",
    [
        "ALE/Qbert-v5",
        "QbertNoFrameskip-v4",
        "Qbert-v4",
        "Qbert-ram-v5",
        "Qbert-ramNoFrameskip-v4",
        "QbertDeterministic-v4",
        "Qbert",
        "qbert",
    ],
)
def test_atari_game_name_strips_namespace_version_and_variants(env_id):
    assert atari_game_name(env_id) == "Qbert"


def test_atari_game_name_of_other_spellings():
    assert atari_game_name("ALE/MontezumaRevenge-v5") == "MontezumaRevenge"
    assert atari_game_name("bank_heist") == "BankHeist"  # DQN Zoo's spelling
    with pytest.raises(ValueError, match="Pacman"):
        atari_game_name("ALE/Pacman-v5")  # Pac-Man is not Ms. Pac-Man and is not in the table


@pytest.mark.parametrize("env_id", ["MiniQbert-v0", "procgen/CoinRun-v0", "CartPole-v1"])
def test_atari_game_name_rejects_other_envs_by_name(env_id):
    with pytest.raises(ValueError, match=env_id):
        atari_game_name(env_id)


def test_human_normalized_score_for_qbert():
    # Qbert: random 163.9, human 13455.0.
    assert human_normalized_score(163.9, "ALE/Qbert-v5") == pytest.approx(0.0)
    assert human_normalized_score(13455.0, "Qbert") == pytest.approx(1.0)
    assert human_normalized_score(6809.45, "QbertNoFrameskip-v4") == pytest.approx(0.5)
    # 1050 (the MiniQbert expert's score, as if it were Qbert): 886.1 / 13291.1
    assert human_normalized_score(1050.0, "Qbert") == pytest.approx(0.066669, abs=1e-6)


def test_human_normalized_score_of_an_array_and_negative_games():
    got = human_normalized_score(np.array([-20.7, 14.6, -3.05]), "Pong")
    np.testing.assert_allclose(got, [0.0, 1.0, 0.5])
    assert isinstance(human_normalized_score(0.0, "Pong"), float)


def test_human_normalized_score_unknown_game():
    with pytest.raises(ValueError, match="MiniQbert-v0"):
        human_normalized_score(100.0, "MiniQbert-v0")


# -- relative performance --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("rapl", "baseline", "expected"),
    [
        (150.0, 100.0, 0.5),
        (50.0, 100.0, -0.5),
        (100.0, 100.0, 0.0),
        (-10.0, -20.0, 0.5),
        (-30.0, -20.0, -0.5),
        (5.0, -5.0, 2.0),
    ],
)
def test_relative_performance(rapl, baseline, expected):
    assert relative_performance(rapl, baseline) == pytest.approx(expected)


def test_relative_performance_rejects_zero_baseline_and_nan():
    with pytest.raises(ValueError, match="baseline"):
        relative_performance(10.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        relative_performance(float("nan"), 1.0)


# -- IQM ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("values", "expected"),
    [
        (list(range(1, 9)), 4.5),  # drop 1,2 and 7,8 → mean(3,4,5,6)
        ([1, 2, 3, 4, 5], 3.0),  # ⌊5/4⌋ = 1 from each end → mean(2,3,4)
        ([1, 2, 3, 100], 2.5),  # the outlier is trimmed
        ([8, 1, 1000, 2, 7, 3, -500, 4], 4.0),  # sorted -500,1,[2,3,4,7],8,1000 → 16/4
        ([1, 2, 9], 4.0),  # fewer than 4 values: the plain mean
        ([7.0], 7.0),
        ([[1, 2, 3, 4], [5, 6, 7, 8]], 4.5),  # a matrix is flattened, as rliable does
        (list(range(1, 11)), 5.5),  # ⌊10/4⌋ = 2 from each end → mean(3..8)
    ],
)
def test_iqm_hand_examples(values, expected):
    assert iqm(values) == pytest.approx(expected)


def test_iqm_errors():
    with pytest.raises(ValueError, match="empty"):
        iqm([])
    with pytest.raises(ValueError, match="NaN"):
        iqm([1.0, float("nan")])

