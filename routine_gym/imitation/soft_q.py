"""SQIL's soft Q target (SPEC §5): `y = R_sq + Γ·α·log Σ_a' exp(Q(s', a')/α)`.

`R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} r` and `Γ = γ^ℓ` for a transition of ℓ primitive steps
(`sqil_reward_and_discount`), with SQIL's reward `r = 1` on every primitive step of a demo
transition and `r = 0` on the agent's; no bootstrap after termination.

SQIL reward convention for a routine. A demo transition gets `r = 1` for *every primitive step*
it spans, so a routine occurrence of length ℓ gets `R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} = (1 − γ^ℓ)/(1 − γ)`
and discount `Γ = γ^ℓ`: exactly the discounted SQIL reward of the ℓ primitive demo transitions
it replaces, so a routine is worth what the chain of demo steps it stands for is worth (one
decision with `r = 1` per routine would instead make long routines look worse per step, and a
plain sum would make them look better than their chain). Agent transitions get `r = 0`, so
`R_sq = 0` and `Γ = γ^ℓ` with ℓ the executed length.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from routine_gym.returns import routine_reward_and_discount

__all__ = ["soft_value", "sqil_reward_and_discount", "sqil_target"]


def sqil_reward_and_discount(
    lengths: np.ndarray | Sequence[int], gamma: float, reward: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """SQIL's `R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} r` and `Γ = γ^ℓ` for transitions of ℓ primitive steps.

    `r` is the SQIL reward of every primitive step: 1 for the demo, 0 for the agent. This is
    RAPL-A2C's routine reward (`returns.routine_reward_and_discount`) of a constant reward.

    Example:
        >>> r, d = sqil_reward_and_discount([1, 3], gamma=0.5)
        >>> r.tolist(), d.tolist()  # 1; 1 + 0.5 + 0.25
        ([1.0, 1.75], [0.5, 0.125])
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    if lengths.size and lengths.min() < 1:
        raise ValueError(f"lengths need to be ≥ 1, got {int(lengths.min())}")
    max_len = int(lengths.max()) if lengths.size else 1
    rewards = np.full((max_len, lengths.size), float(reward))
    return routine_reward_and_discount(rewards, lengths, gamma)


def soft_value(q: torch.Tensor, temperature: float) -> torch.Tensor:
    """`V(s) = α·log Σ_a exp(Q(s, a)/α)`, the soft value of soft Q-learning (last axis)."""
    if temperature <= 0:
        raise ValueError(f"the temperature α needs to be > 0, actual value: {temperature}")
    return temperature * torch.logsumexp(q / temperature, dim=-1)


def sqil_target(
    rewards: torch.Tensor,
    discounts: torch.Tensor,
    terminated: torch.Tensor,
    next_q: torch.Tensor,
    temperature: float,
) -> torch.Tensor:
    """SQIL's target `R_sq + Γ·α·logsumexp(Q(s', ·)/α)`, with no bootstrap after termination.

    Args:
        rewards: `(B,)` `R_sq` of each transition (see `sqil_reward_and_discount`).
        discounts: `(B,)` `Γ = γ^ℓ`.
        terminated: `(B,)` bool; a terminated transition's target is its reward alone.
        next_q: `(B, A)` Q-values of the next state (the target network's).
        temperature: α.
    """
    bootstrap = soft_value(next_q, temperature) * (~terminated.bool()).to(next_q.dtype)
    return rewards + discounts * bootstrap
