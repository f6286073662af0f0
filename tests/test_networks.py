"""`ObservationEncoder`: the Nature CNN laid out channels-last computes what the plain layout
computes, from the same initial weights; the other torsos keep the plain layout."""

from __future__ import annotations

import numpy as np
import torch

import routine_gym
from routine_gym.networks import ObservationEncoder


def test_the_nature_cnn_runs_channels_last_with_the_same_numbers():
    routine_gym.register_envs()
    torch.manual_seed(0)
    encoder = ObservationEncoder("ALE/Qbert-v5", (4, 84, 84), np.uint8)
    torch.manual_seed(0)
    plain = ObservationEncoder("ALE/Qbert-v5", (4, 84, 84), np.uint8)
    plain.torso.to(memory_format=torch.contiguous_format)
    assert encoder.memory_format is torch.channels_last
    conv = encoder.torso[0].weight
    assert conv.is_contiguous(memory_format=torch.channels_last) and not conv.is_contiguous()
    # Same initial numbers (orthogonal init before the layout change).
    for a, b in zip(encoder.state_dict().values(), plain.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    obs = torch.randint(0, 256, (16, 4, 84, 84), dtype=torch.uint8)
    out, ref = encoder(obs), plain(obs)
    assert out.shape == (16, 512)
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)
    out.sum().backward()
    ref.sum().backward()
    torch.testing.assert_close(encoder.torso[0].weight.grad, plain.torso[0].weight.grad,
                               rtol=1e-4, atol=1e-4)


def test_the_other_torsos_keep_the_plain_layout():
    encoder = ObservationEncoder("MinAtar/Breakout-v1", (4, 10, 10), np.float32)
    assert encoder.memory_format is torch.contiguous_format
    assert encoder.torso[0].weight.is_contiguous()
