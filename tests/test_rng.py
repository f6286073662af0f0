"""Checkpointed RNG state restores every generator a script draws from."""

from __future__ import annotations

import io
import random

import numpy as np
import pytest
import torch

from routine_gym.plumbing.rng import rng_state, set_rng_state


def draw(generator: np.random.Generator) -> tuple:
    return (random.random(), np.random.rand(), torch.rand(1).item(),  # noqa: NPY002
            int(generator.integers(2**62)))


def test_restored_state_repeats_every_draw_after_a_weights_only_round_trip():
    generator = np.random.default_rng(123)
    draw(generator)  # move every generator away from its seed
    buffer = io.BytesIO()
    torch.save(rng_state(generator), buffer)
    expected = [draw(generator) for _ in range(3)]

    draw(generator)  # and further still, so a no-op restore would fail
    buffer.seek(0)
    set_rng_state(torch.load(buffer, weights_only=True), generator)
    assert [draw(generator) for _ in range(3)] == expected


def test_a_state_without_generator_cannot_restore_one():
    state = rng_state()
    assert "generator" not in state
    with pytest.raises(ValueError, match="no generator state"):
        set_rng_state(state, np.random.default_rng(0))
