"""`sample_categorical` and `categorical_policy` are `torch.distributions.Categorical` without
the object: the same draws from torch's generator, the same log-probabilities and entropies, and
the same gradients bit for bit (so a training script's scalars do not move when it switches)."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch.distributions import Categorical

from routine_gym.networks import categorical_policy, sample_categorical


def _loss_and_grad(logits_source: torch.Tensor, fn) -> tuple[list[torch.Tensor], torch.Tensor]:
    """Run `fn(logits)` → (outputs, loss) from a leaf copy of `logits_source`; its gradient."""
    logits = logits_source.clone().requires_grad_(True)
    outputs, loss = fn(logits)
    loss.backward()
    return outputs, logits.grad


@settings(max_examples=40, deadline=None)
@given(batch=st.integers(1, 40), n=st.integers(2, 9), seed=st.integers(0, 2**16),
       scale=st.sampled_from([0.01, 1.0, 30.0]), sampled=st.booleans())
def test_the_policy_is_the_distribution_bit_for_bit(batch, n, seed, scale, sampled):
    gen = torch.Generator().manual_seed(seed)
    raw = torch.randn(batch, n, generator=gen) * scale
    given_actions = None if sampled else torch.randint(0, n, (batch,), generator=gen)

    def with_distribution(logits):
        dist = Categorical(logits=logits)
        actions = dist.sample() if given_actions is None else given_actions
        log_prob, entropy = dist.log_prob(actions), dist.entropy()
        return [actions, log_prob, entropy], (log_prob * 0.7).mean() - 0.01 * entropy.mean()

    def without(logits):
        actions, log_prob, entropy = categorical_policy(logits, given_actions)
        return [actions, log_prob, entropy], (log_prob * 0.7).mean() - 0.01 * entropy.mean()

    torch.manual_seed(seed)
    ref, ref_grad = _loss_and_grad(raw, with_distribution)
    torch.manual_seed(seed)
    ours, our_grad = _loss_and_grad(raw, without)
    for a, b in zip(ref, ours, strict=True):
        assert torch.equal(a, b)
    assert torch.equal(ref_grad, our_grad)


def test_sampling_draws_what_the_distribution_draws_and_moves_the_generator_alike():
    logits = torch.tensor([[0.0, 0.0, 10.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    torch.manual_seed(3)
    ref = [Categorical(logits=logits).sample() for _ in range(20)]
    after_ref = torch.rand(1)
    torch.manual_seed(3)
    ours = [sample_categorical(logits) for _ in range(20)]
    assert torch.equal(torch.stack(ours), torch.stack(ref))
    assert torch.equal(torch.rand(1), after_ref)
    # A nearly certain action is drawn (e^10 / (e^10 + 2) > 0.9999): a real draw, not argmax.
    assert all(int(draw[0]) == 2 for draw in ours)
    assert ours[0].shape == (3,) and ours[0].dtype == torch.int64


def test_a_known_distribution_has_its_hand_worked_numbers():
    # logits log 1, log 3 → probabilities 1/4, 3/4; entropy −(¼ ln ¼ + ¾ ln ¾) = 0.5623351
    logits = torch.log(torch.tensor([[1.0, 3.0]], dtype=torch.float64))
    _, log_prob, entropy = categorical_policy(logits, torch.tensor([1]))
    assert log_prob.item() == pytest.approx(math.log(0.75), abs=1e-12)
    assert entropy.item() == pytest.approx(0.5623351446188083, abs=1e-12)
