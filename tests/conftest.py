"""Shared test setup: a headless SDL, one torch thread, and the repository root."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# pygame (imported by gymnasium.utils.play) must never try to open a window in the tests.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
# Scripts the tests start as subprocesses use torch's default thread count, which follows this.
os.environ.setdefault("OMP_NUM_THREADS", "1")

REPO_ROOT = Path(__file__).resolve().parent.parent


def pytest_configure(config: pytest.Config) -> None:
    # The machine has two cores; torch's default thread pool would fight the envs for them.
    import torch

    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (holds `algos/`, `demos/`, `routine_gym/`)."""
    return REPO_ROOT


# Tests make ALE envs with gym.make directly; routine-gym registers ALE's ids on first use.
import routine_gym  # noqa: E402

routine_gym.register_envs()
