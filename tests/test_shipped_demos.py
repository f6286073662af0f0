"""Every demo shipped in demos/ loads, replays to its recorded score and length, and mines."""

from __future__ import annotations

import glob
import os
import warnings

import pytest

import routine_gym  # noqa: F401  (registers the envs)
from routine_gym.demo import (
    DEMO_SUITE,
    DEMOS_DIR,
    Demo,
    demo_filename,
    replay,
    shipped_demo_path,
)
from routine_gym.imitation import load_demo
from routine_gym.mining import SequiturMiner

SHIPPED = sorted(glob.glob(os.path.join(DEMOS_DIR, "*.npz")))


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
    assert len(demo.meta["candidates"]["seeds"]) == 10  # the best of 10 episodes
    with open(os.path.join(DEMOS_DIR, "README.md")) as f:
        assert f"`{demo_filename(env_id)}`" in f.read()
    # rapl_sqil.py, bc.py and gail.py load their default demo through load_demo.
    loaded, loaded_path = load_demo(env_id)
    assert loaded_path == path and loaded.score == demo.score


@pytest.mark.parametrize("path", SHIPPED, ids=os.path.basename)
def test_shipped_demo_replays_exactly(path):
    demo = Demo.load(path)
    assert os.path.basename(path) == demo_filename(demo.env_id)
    assert os.path.getsize(path) < 5 * 2**20, "shipped demos stay small"
    result = replay(demo)  # raises DemoReplayError on any divergence
    assert list(result.scores) == list(demo.scores)
    assert list(result.lengths) == [int(n) for n in demo.episode_lengths]


@pytest.mark.parametrize("path", SHIPPED, ids=os.path.basename)
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
