"""Returns and advantages over routine decisions and their primitive steps (SPEC §5).

Pure numpy functions, shared by `algos/rapl_a2c.py` and `algos/rapl_sqil.py` and tested with
hand-computed numbers. Arrays are time-major: `[decision, env]` for decisions and
`[decision, step inside the routine, env]` for the primitive steps of each decision.

A decision `i` starts at primitive time `t_i`, runs a routine of executed length `ℓ_i` and
collects rewards `r_{t_i}, …, r_{t_i+ℓ_i-1}`. RAPL turns it into one transition with

    R_i = Σ_{τ=t_i}^{t_i+ℓ_i-1} γ^{τ-t_i} r_τ        (routine reward)
    Γ_i = γ^{ℓ_i}                                      (routine discount)

so that the decision-level return `G_i = R_i + Γ_i G_{i+1}` is exactly the primitive-level
discounted return from `t_i`. The MacroAction baseline instead uses the plain sum of rewards
and one γ per decision. An episode that ends inside a routine ends the routine: on
termination the return stops there; on truncation it is bootstrapped from the value of the
final observation.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "decision_returns",
    "macro_reward_and_discount",
    "primitive_returns",
    "routine_reward_and_discount",
]


def _step_mask(lengths: np.ndarray, max_len: int) -> np.ndarray:
    """`mask[..., j, ...]` is True for the executed steps `j < length` (step axis = -2)."""
    steps = np.arange(max_len).reshape((1,) * (lengths.ndim - 1) + (max_len, 1))
    return steps < np.expand_dims(lengths, -2)


def routine_reward_and_discount(
    rewards: np.ndarray, lengths: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """RAPL's `R = Σ_j γ^j r_j` and `Γ = γ^ℓ` for each decision.

    Args:
        rewards: `[..., L, E]` per-step rewards, zero-padded past each routine's length.
        lengths: `[..., E]` executed lengths ℓ (≥ 1).
        gamma: the per-primitive-step discount γ.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    lengths = np.asarray(lengths)
    max_len = rewards.shape[-2]
    powers = gamma ** np.arange(max_len, dtype=np.float64).reshape(max_len, 1)
    mask = _step_mask(lengths, max_len)
    routine_reward = (rewards * powers * mask).sum(axis=-2)
    return routine_reward, gamma ** lengths.astype(np.float64)


def macro_reward_and_discount(
    rewards: np.ndarray, lengths: np.ndarray, gamma: float
) -> tuple[np.ndarray, np.ndarray]:
    """The MacroAction baseline's plain sum `Σ_j r_j` and one `γ` per decision."""
    rewards = np.asarray(rewards, dtype=np.float64)
    lengths = np.asarray(lengths)
    mask = _step_mask(lengths, rewards.shape[-2])
    return (rewards * mask).sum(axis=-2), np.full(lengths.shape, gamma, dtype=np.float64)


def decision_returns(
    rewards: np.ndarray,
    discounts: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    final_values: np.ndarray,
    bootstrap_value: np.ndarray,
) -> np.ndarray:
    """`G_i = R_i + Γ_i · next`, where next is `G_{i+1}`, 0 or `V(final obs)`.

    Args:
        rewards: `[N, E]` decision rewards `R_i`.
        discounts: `[N, E]` decision discounts `Γ_i`.
        terminated: `[N, E]` the episode terminated during decision `i`: nothing follows.
        truncated: `[N, E]` the episode was cut during decision `i`: bootstrap from
            `final_values[i]`, the value of the observation it was cut at.
        final_values: `[N, E]` values of final observations (read only where truncated).
        bootstrap_value: `[E]` value of the observation after the last decision.

    Returns:
        `[N, E]` returns `G_i`; the advantage is `G_i − V(s_{t_i})`.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    returns = np.zeros_like(rewards)
    next_return = np.asarray(bootstrap_value, dtype=np.float64)
    for i in reversed(range(rewards.shape[0])):
        following = np.where(truncated[i], final_values[i], next_return)
        following = np.where(terminated[i], 0.0, following)
        next_return = rewards[i] + discounts[i] * following
        returns[i] = next_return
    return returns


def primitive_returns(
    rewards: np.ndarray,
    lengths: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    final_values: np.ndarray,
    bootstrap_value: np.ndarray,
    gamma: float,
) -> np.ndarray:
    """The discounted return from every primitive step of a rollout of routine decisions.

    The primitive steps of all decisions are one trajectory per env; the return of step `j` of
    decision `i` is `r + γ·(return of the next primitive step)`, cut at termination,
    bootstrapped from the final observation's value at truncation and from `bootstrap_value`
    after the last decision. These are the critic's `A_prim` targets.

    Args:
        rewards: `[N, L, E]` per-step rewards, zero-padded past each routine's length.
        lengths: `[N, E]` executed lengths.
        terminated, truncated, final_values: `[N, E]` as in `decision_returns`; an episode
            can only end on the last executed step of a routine.
        bootstrap_value: `[E]` value of the observation after the last decision.
        gamma: the per-step discount.

    Returns:
        `[N, L, E]` returns, zero where `j ≥ ℓ_i`. `returns[:, 0]` equals
        `decision_returns` with RAPL's routine rewards and discounts.
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    lengths = np.asarray(lengths)
    n, max_len, _ = rewards.shape
    returns = np.zeros_like(rewards)
    next_return = np.asarray(bootstrap_value, dtype=np.float64)
    for i in reversed(range(n)):
        last = lengths[i] - 1
        for j in reversed(range(max_len)):
            executed = j <= last
            at_end = j == last
            following = next_return
            following = np.where(at_end & truncated[i], final_values[i], following)
            following = np.where(at_end & terminated[i], 0.0, following)
            value = rewards[i, j] + gamma * following
            next_return = np.where(executed, value, next_return)
            returns[i, j] = np.where(executed, value, 0.0)
    return returns
