"""Every demo shipped in demos/ loads, replays to its recorded score and length, and mines."""

from __future__ import annotations

import glob
import os
import warnings

import pytest

import routine_gym  # noqa: F401  (registers the envs)
from routine_gym.demo import DEMOS_DIR, Demo, demo_filename, replay, shipped_demo_path
from routine_gym.mining import SequiturMiner

SHIPPED = sorted(glob.glob(os.path.join(DEMOS_DIR, "*.npz")))


def test_demos_are_shipped():
    assert shipped_demo_path("MiniQbert-v0") is not None
    assert shipped_demo_path("NoSuchEnv-v0") is None


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
    assert 1 <= len(library) <= 3
    assert all(len(r) >= 3 for r in library.routines)
    assert library.source["env_id"] == demo.env_id
