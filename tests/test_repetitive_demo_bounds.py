"""A repetitive demo keeps what it stores and how long its alignment takes bounded (issue 46
case 4): a routine of a periodic demo occurs tens of thousands of times, and a library that
kept every occurrence was a 128 MB `routines.json` copied into every run folder and checkpoint;
the alignment with a long demo took 50 s an episode."""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest
from test_as_a_user import ok, user

import routine_gym  # noqa: F401  (registers MiniQbert-v0)
from routine_gym import library as library_module
from routine_gym.demo import Demo
from routine_gym.imitation.demo_buffer import _decision_occurrences, decision_steps
from routine_gym.library import MAX_KEPT_OCCURRENCES, RoutineLibrary
from routine_gym.metrics import ALIGNMENT_MAX_LENGTH, alignment_score
from routine_gym.mining import SequiturMiner
from routine_gym.plumbing.evaluation import evaluate_policy

PERIOD = [1, 1, 2, 0, 2, 2, 1, 0]


def periodic_demo(n: int, env_id: str = "MinAtar/Breakout-v1") -> Demo:
    """One episode of `n` actions repeating `PERIOD` (a 200,000-step one is 9 KB on disk)."""
    actions = np.tile(PERIOD, n // len(PERIOD) + 1)[:n]
    return Demo(actions=actions, rewards=np.zeros(n), terminated=np.arange(n) == n - 1,
                truncated=np.zeros(n, bool), episode_lengths=np.array([n]),
                meta={"env_id": env_id, "seeds": [0]})


@pytest.mark.parametrize("proposer", ["bpe", "full"])
def test_mining_a_repetitive_demo_writes_a_small_library(proposer, tmp_path):
    periodic_demo(200_000).save(tmp_path / "rep.npz", include_observations=False)
    assert os.path.getsize(tmp_path / "rep.npz") < 20_000
    ok(user("routine-gym", "mine", "rep.npz", "--proposer", proposer, "--out", "lib.json",
            cwd=tmp_path))
    data = json.loads((tmp_path / "lib.json").read_text())
    # The period (8 actions) occurs 200,000 / 8 = 25,000 times: the full count is kept as the
    # frequency, the occurrences only up to the bound (the first ones, in order).
    assert data["routines"][0] == PERIOD and data["frequencies"][0] == 25_000
    assert [len(o) for o in data["occurrences"]] == [MAX_KEPT_OCCURRENCES] * 3
    assert data["occurrences"][0][:2] == [[0, 0], [0, 8]]
    # Kept whole, the three routines' ~75,000 occurrences were 3.2 MB (128 MB for the 24 KB
    # demo of the issue); 5,000 pairs of ~40 bytes of indented JSON each, three times, < 1 MB.
    assert os.path.getsize(tmp_path / "lib.json") < 1_000_000


def test_a_library_of_a_shipped_size_keeps_every_occurrence_as_before():
    library = SequiturMiner().mine(periodic_demo(800))  # 100 periods: under the bound
    assert library.frequencies[0] == 100
    assert library.occurrences_complete
    assert library.occurrences[0] == tuple((0, 8 * i) for i in range(100))


def test_sqil_finds_every_occurrence_again_when_the_library_kept_only_the_first(monkeypatch):
    demo = periodic_demo(800)
    monkeypatch.setattr(library_module, "MAX_KEPT_OCCURRENCES", 10)
    library = SequiturMiner(num_routines=1).mine(demo)
    assert library.frequencies == (100,) and len(library.occurrences[0]) == 10
    assert not library.occurrences_complete
    occurrences = _decision_occurrences(library, demo, decision_steps(demo))
    assert occurrences[0] == tuple((0, 8 * i) for i in range(100))  # every one, not 10
    assert RoutineLibrary.from_dict(library.to_dict()).occurrences == library.occurrences


def test_alignment_with_a_long_demo_uses_its_first_decisions_only():
    # Against [0,1,2,3] cut to 2: [0,1] vs [0,1] → 1; uncut: [0,1,3,-1] → 1 − 2/4.
    assert alignment_score([0, 1, 2, 3], [0, 1, 3], max_length=2) == 1.0
    assert alignment_score([0, 1, 2, 3], [0, 1, 3]) == 0.5
    with pytest.raises(ValueError, match="max_length"):
        alignment_score([0, 1], [0], max_length=0)


def test_evaluation_against_a_long_demo_is_bounded_and_says_so():
    demo = periodic_demo(1_500_000, env_id="MiniQbert-v0")
    start = time.perf_counter()
    summary = evaluate_policy("MiniQbert-v0", lambda obs: 0, 2, seed=0, demo=demo,
                              max_steps=200)
    seconds = time.perf_counter() - start
    assert summary["demo_length"] == 1_500_000
    assert summary["aligned_length"] == ALIGNMENT_MAX_LENGTH
    # Uncut, two episodes took ~100 s; cut, ~0.2 s (the bound is loose for a loaded machine).
    assert seconds < 20, seconds
