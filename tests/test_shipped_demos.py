"""Every demo shipped in demos/ loads, replays to its recorded score and length, and mines."""

from __future__ import annotations

import glob
import os
import warnings

import gymnasium as gym
import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers the envs)
from routine_gym.demo import (
    DEMO_SUITE,
    DEMOS_DIR,
    Demo,
    demo_file_version,
    demo_filename,
    replay,
    shipped_demo_path,
)
from routine_gym.envs import env_family
from routine_gym.mining import SequiturMiner
from routine_gym.plumbing.loading import load_demo

SHIPPED = sorted(glob.glob(os.path.join(DEMOS_DIR, "*.npz"))
                 + glob.glob(os.path.join(DEMOS_DIR, "*", "*.npz")))
#: The best mean evaluation return any learner reached on each MinAtar game in the first
#: protocol's `long` sweep (10^7 steps, issue 47): the current demos score at least this.
LONG_SWEEP_BEST = {"MinAtar/Asterix-v1": 25.3, "MinAtar/Breakout-v1": 17.2,
                   "MinAtar/Freeway-v1": 59.8, "MinAtar/Seaquest-v1": 77.3,
                   "MinAtar/SpaceInvaders-v1": 177.1}


def _ids(path: str) -> str:
    return os.path.relpath(path, DEMOS_DIR)


def test_demos_are_shipped():
    assert shipped_demo_path("MiniQbert-v0") is not None
    assert shipped_demo_path("NoSuchEnv-v0") is None


@pytest.mark.parametrize("env_id", DEMO_SUITE)
def test_every_suite_env_has_a_demo_with_provenance_that_the_scripts_default_to(env_id):
    path = shipped_demo_path(env_id)
    assert path is not None, f"no shipped demo for {env_id}"
    demo = Demo.load(path)
    assert demo.env_id == env_id
    # Trained agents' demos say how long the agent trained; demos/README.md has the rest.
    assert demo.meta["trained_steps"] >= 300_000
    assert len(demo.meta["candidates"]["seeds"]) >= 10  # the best of 10 (MinAtar: 30) episodes
    with open(os.path.join(DEMOS_DIR, "README.md")) as f:
        assert f"`{demo_filename(env_id)}`" in f.read()
    # rapl_sqil.py, bc.py and gail.py load their default demo through load_demo.
    loaded, loaded_path = load_demo(env_id)
    assert loaded_path == path and loaded.score == demo.score


@pytest.mark.parametrize("env_id", sorted(LONG_SWEEP_BEST))
def test_the_current_minatar_demos_score_at_least_the_best_learner_of_the_long_sweep(env_id):
    current = Demo.load(shipped_demo_path(env_id))
    assert current.score >= LONG_SWEEP_BEST[env_id]
    assert current.meta["trained_steps"] >= 5_000_000  # Seaquest, SpaceInvaders: 10^7
    first = Demo.load(shipped_demo_path(env_id, "first"))  # the first protocol's, kept
    assert first.meta["trained_steps"] == 5_000_000 and first.env_id == env_id
    assert shipped_demo_path(env_id, "first").endswith(f"first/{demo_filename(env_id)}")


@pytest.mark.parametrize("path", SHIPPED, ids=_ids)
def test_shipped_demo_replays_exactly(path):
    demo = Demo.load(path)
    assert os.path.basename(path) == demo_filename(demo.env_id)
    assert os.path.getsize(path) < 5 * 2**20, "shipped demos stay small"
    result = replay(demo)  # raises DemoReplayError on any divergence
    assert list(result.scores) == list(demo.scores)
    assert list(result.lengths) == [int(n) for n in demo.episode_lengths]


@pytest.mark.parametrize("path", SHIPPED, ids=_ids)
def test_shipped_demo_mines_routines(path):
    demo = Demo.load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # MiniQbert's short demo yields fewer than K
        library = SequiturMiner().mine(demo)
    if demo.env_id in DEMO_SUITE:  # a trained agent's long demo gives all K = 3
        assert len(library) == 3
    else:
        assert 1 <= len(library) <= 3
    assert all(len(r) >= 3 for r in library.routines)
    assert library.source["env_id"] == demo.env_id


# -- format version 2: the demonstrator's decisions ------------------------------------------


def _runs(mask):
    """(start, end) of each run of True in a boolean array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


@pytest.mark.parametrize("path", SHIPPED, ids=_ids)
def test_shipped_demo_is_version_2_with_its_injected_steps_marked(path):
    demo = Demo.load(path)
    assert demo_file_version(path) == 2
    if env_family(demo.env_id) != "atari":  # CoinRun and MiniQbert have no injecting wrapper
        assert demo.num_injected == 0
        return
    meanings = demo.action_meanings
    injected = _runs(~demo.decisions)
    # The episode opens with the no-op start (1–30 NOOPs) and, where the game has FIRE, the
    # fire reset's FIRE: all injected, and nothing else before the first decision.
    start, end = injected[0]
    opening = [meanings[a] for a in demo.actions[start:end]]
    assert start == 0 and demo.decisions[end]
    fire = "FIRE" in meanings
    assert opening[-1] == ("FIRE" if fire else "NOOP")
    assert set(opening[: -1 if fire else None]) == {"NOOP"}
    assert 1 <= len(opening) - fire <= 30
    # Every later injected run is a served life: NOOP then FIRE (FireOnLifeLoss), which the
    # Qbert demo (recorded under routine-gym 0.1's stack) does not have.
    served = [[meanings[a] for a in demo.actions[a:b]] for a, b in injected[1:]]
    if demo.meta["recorded_under_stack"] == "agent-0.1":
        assert served == []
    else:
        assert fire == bool(served)
        assert all(run == ["NOOP", "FIRE"] for run in served)
    assert demo.num_injected == sum(b - a for a, b in injected)


@pytest.mark.parametrize("path", SHIPPED, ids=_ids)
def test_mining_a_shipped_demo_is_mining_its_decision_segments(path):
    demo = Demo.load(path)
    segments, starts = demo.decision_segments()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from_demo = SequiturMiner().mine(demo)
        from_segments = SequiturMiner().mine(segments)
    assert from_demo.routines == from_segments.routines
    assert from_demo.frequencies == from_segments.frequencies
    assert from_demo.scores == from_segments.scores
    # Occurrences are the segments' own, mapped back to the demo's steps: every one is the
    # routine's actions, on decided steps only, so no routine overlaps an injected step.
    offsets = demo.episode_offsets
    for routine, occ, seg_occ in zip(from_demo.routines, from_demo.occurrences,
                                     from_segments.occurrences, strict=True):
        assert len(occ) == len(seg_occ) == from_demo.frequencies[from_demo.routines.index(routine)]
        for (e, t), (s, u) in zip(occ, seg_occ, strict=True):
            assert (e, t) == (starts[s][0], starts[s][1] + u)
            first = int(offsets[e]) + t
            assert tuple(demo.actions[first : first + len(routine)]) == routine
            assert demo.decisions[first : first + len(routine)].all()


MINATAR = [env_id for env_id in DEMO_SUITE if env_family(env_id) == "minatar"]


@pytest.mark.parametrize("env_id", MINATAR)
def test_minatar_demos_come_from_5m_step_experts_far_above_random(env_id):
    # MinAtar's own budget is 5M steps; the demo scores at least 5× the random policy's mean
    # and at least 5 points above it (the random policy over 30 episodes, seeds 0–29).
    demo = Demo.load(shipped_demo_path(env_id))
    assert demo.meta["trained_steps"] >= 5_000_000
    assert demo.meta["mode"] == "a2c" and demo.decisions.all()
    env = gym.make(env_id)
    env.action_space.seed(0)
    scores = []
    for episode in range(30):
        env.reset(seed=episode)
        score, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            score += reward
            done = terminated or truncated
        scores.append(score)
    random_mean = float(np.mean(scores))
    assert demo.score >= 5 * random_mean and demo.score >= random_mean + 5
