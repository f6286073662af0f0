"""PPO's pieces over routine decisions (SPEC §5): SMDP GAE, the primitive-level critic targets
and the clipped losses of `algos/rapl_ppo.py`.

Pure functions, tested with hand-computed numbers (`tests/test_rapl_ppo.py`). The returns and
advantages are numpy, time-major like `routine_gym.returns` (`[decision, env]` and `[decision,
step inside the routine, env]`); the losses take torch tensors (they use tensor methods only,
so importing this module does not import torch).

A decision `i` runs a routine of executed length `ℓ_i` from the state `s_{t_i}`. With RAPL's
routine reward `R_i = Σ_j γ^j r_{t_i+j}` and discount `Γ_i = γ^{ℓ_i}` (`routine_gym.returns`),
generalised advantage estimation over decisions is

    δ_i = R_i + Γ_i V(s_{t_{i+1}}) − V(s_{t_i})
    A_i = δ_i + Γ_i Λ_i A_{i+1},        Λ_i = λ^{ℓ_i}                 (trace decay)

so the trace decays by `(γλ)^{ℓ_i}` across a routine: λ counts primitive steps, as γ does.
This is the primitive-level λ-return in which every n-step return that would bootstrap from a
state inside a routine (where no decision is made, so PPO has no value of its own there) is
carried on to the routine's end: the λ-weights `(1 − λ) λ^{n−1}`, n = 1 … ℓ_i, of the steps
inside the routine add up to `1 − λ^{ℓ_i}`, the weight the recursion above puts on
`V(s_{t_{i+1}})`. The bias-variance trade-off then spans the same stretch of game time
(about `1/(1 − γλ)` primitive steps) however long the routines the agent picks; with
`Λ_i = λ` instead (one λ per decision) an agent using routines of mean length d̄ would get
nearly Monte-Carlo advantages over d̄ times as many steps. With every `ℓ_i = 1`, `Γ_i = γ` and
`Λ_i = λ`: CleanRL's GAE exactly (`ppo_atari.py`'s loop with `nextnonterminal`). The
MacroAction baseline treats a routine as one step: `Γ_i = γ`, `Λ_i = λ`, summed reward.

An episode that ends inside decision `i` ends the trace there; the next value is 0 on
termination and `V(final observation)` on truncation (CleanRL uses 0 for both; the two agree
where no episode is truncated).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

__all__ = [
    "clipped_policy_loss",
    "clipped_value_loss",
    "inner_lambda_returns",
    "inner_state_shares",
    "normalize_advantages",
    "routine_trace_decay",
    "smdp_gae",
]


def routine_trace_decay(lengths: np.ndarray, gae_lambda: float) -> np.ndarray:
    """RAPL's trace decay `Λ_i = λ^{ℓ_i}` of each decision (one λ per primitive step).

    Example:
        >>> import numpy as np
        >>> routine_trace_decay(np.array([[1, 3]]), 0.5)
        array([[0.5  , 0.125]])
    """
    return float(gae_lambda) ** np.asarray(lengths, dtype=np.float64)


def _following(next_values: np.ndarray, terminated: np.ndarray, truncated: np.ndarray,
               final_values: np.ndarray) -> np.ndarray:
    """What follows a decision: 0 after termination, the final observation's value after
    truncation, else `next_values`."""
    following = np.where(truncated, final_values, next_values)
    return np.where(terminated, 0.0, following)


def smdp_gae(
    rewards: np.ndarray,
    discounts: np.ndarray,
    traces: np.ndarray,
    values: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    final_values: np.ndarray,
    bootstrap_value: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation over decisions: `A_i = δ_i + Γ_i Λ_i A_{i+1}`.

    Args:
        rewards: `[N, E]` decision rewards `R_i`.
        discounts: `[N, E]` decision discounts `Γ_i` (γ^ℓ for RAPL, γ per decision otherwise).
        traces: `[N, E]` trace decays `Λ_i` (`routine_trace_decay`, or λ per decision).
        values: `[N, E]` values `V(s_{t_i})` of the decision states.
        terminated: `[N, E]` the episode terminated during decision `i`: nothing follows.
        truncated: `[N, E]` it was cut during decision `i`: `final_values[i]` follows.
        final_values: `[N, E]` values of the final observations (read only where truncated).
        bootstrap_value: `[E]` value of the state after the last decision.

    Returns:
        `(advantages, returns)`, each `[N, E]` float64; `returns = advantages + values`, the
        λ-returns the critic is trained on.

    Example:
        >>> import numpy as np
        >>> no = np.zeros((3, 1), dtype=bool)
        >>> R, V = np.array([[1.0], [2.0], [4.0]]), np.array([[1.0], [2.0], [3.0]])
        >>> adv, ret = smdp_gae(R, np.full((3, 1), 0.5), np.full((3, 1), 0.5), V, no, no,
        ...                     np.zeros((3, 1)), np.array([4.0]))
        >>> adv.ravel().tolist()  # δ = 3, 1.5, 1; A = 3, 1.5 + .25·3, 1 + .25·2.25
        [1.5625, 2.25, 3.0]
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    discounts = np.asarray(discounts, dtype=np.float64)
    traces = np.asarray(traces, dtype=np.float64)
    advantages = np.zeros_like(rewards)
    next_value = np.asarray(bootstrap_value, dtype=np.float64)
    next_advantage = np.zeros_like(next_value)
    for i in reversed(range(rewards.shape[0])):
        following = _following(next_value, terminated[i], truncated[i], final_values[i])
        delta = rewards[i] + discounts[i] * following - values[i]
        goes_on = ~(np.asarray(terminated[i]) | np.asarray(truncated[i]))
        next_advantage = delta + discounts[i] * traces[i] * goes_on * next_advantage
        advantages[i] = next_advantage
        next_value = values[i]
    return advantages, advantages + values


def inner_lambda_returns(
    rewards: np.ndarray,
    lengths: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    final_values: np.ndarray,
    values: np.ndarray,
    returns: np.ndarray,
    bootstrap_value: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> np.ndarray:
    """The λ-return from every primitive step of every decision: RAPL's `A_prim` targets.

    Step `j` of decision `i` has `k = ℓ_i − j` steps left in its routine. Its return is the
    discounted rest of the routine's rewards, then, at the routine's end, the same mixture of
    the next decision's value and λ-return that `smdp_gae` uses (the λ-weights of the steps
    still inside the routine carried on to its end):

        G_{i,j} = Σ_{m=j}^{ℓ_i−1} γ^{m−j} r_m + γ^k [(1 − λ^k) V(s_{t_{i+1}}) + λ^k G_{i+1}]

    where `G_{i+1}` is the next decision's λ-return (`smdp_gae`'s `returns`), `bootstrap_value`
    after the last decision, both 0 after termination and `V(final obs)` after truncation.
    Step 0 gives the decision's own λ-return back. With λ = 1 these are
    `routine_gym.returns.primitive_returns`, RAPL-A2C's `A_prim` targets (the return to the
    rollout's end); `routine_gym.returns.inner_states_and_targets` pairs steps `j ≥ 1` with
    the states they start from.

    Args:
        rewards: `[N, L, E]` per-step rewards, zero-padded past each routine's length.
        lengths: `[N, E]` executed lengths ℓ (≥ 1).
        terminated, truncated, final_values: `[N, E]` as in `smdp_gae`.
        values: `[N, E]` values of the decision states.
        returns: `[N, E]` the decisions' λ-returns (`smdp_gae`'s second output).
        bootstrap_value: `[E]` value of the state after the last decision.
        gamma: the per-step discount γ.
        gae_lambda: λ.

    Returns:
        `[N, L, E]` λ-returns, zero where `j ≥ ℓ_i`.

    Example:
        >>> import numpy as np
        >>> rewards = np.array([[[1.0], [2.0]]])  # one decision of ℓ = 2: rewards 1, 2
        >>> no = np.zeros((1, 1), dtype=bool)
        >>> G = inner_lambda_returns(rewards, np.array([[2]]), no, no, np.zeros((1, 1)),
        ...                          np.array([[0.0]]), np.array([[4.0]]), np.array([8.0]),
        ...                          0.5, 0.5)
        >>> G[0, :, 0].tolist()  # 1 + .5·2 + .25·8 and 2 + .5·8 (V = G after the rollout)
        [4.0, 6.0]
    """
    rewards = np.asarray(rewards, dtype=np.float64)
    lengths = np.asarray(lengths)
    n, max_len, _ = rewards.shape
    values = np.asarray(values, dtype=np.float64)
    returns = np.asarray(returns, dtype=np.float64)
    bootstrap = np.asarray(bootstrap_value, dtype=np.float64)[None]
    next_values = np.concatenate([values[1:], bootstrap])
    next_returns = np.concatenate([returns[1:], bootstrap])
    value_after = _following(next_values, terminated, truncated, final_values)
    return_after = _following(next_returns, terminated, truncated, final_values)

    steps = np.arange(max_len)[None, :, None]
    executed = steps < lengths[:, None, :]
    left = np.maximum(lengths[:, None, :] - steps, 0).astype(np.float64)  # k = ℓ − j
    tail = np.zeros_like(rewards)  # Σ_{m ≥ j} γ^{m−j} r_m within the routine
    after = np.zeros_like(rewards[:, 0])
    for j in reversed(range(max_len)):
        after = np.where(executed[:, j], rewards[:, j] + gamma * after, 0.0)
        tail[:, j] = after
    decay = float(gae_lambda) ** left
    end = (1.0 - decay) * value_after[:, None, :] + decay * return_after[:, None, :]
    return np.where(executed, tail + gamma**left * end, 0.0)


def inner_state_shares(num_inner: int, epochs: int, passes: int,
                       permutation: Callable[[int], np.ndarray] = np.random.permutation
                       ) -> Iterator[np.ndarray]:
    """The states inside routines each of an update's `epochs` trains: in all, every one of
    the `num_inner` states `passes` times (1 ≤ passes ≤ epochs).

    The states are dealt from shuffled decks (`permutation(num_inner)`, a new deck drawn when
    the last runs out, only then, so a lazy consumer draws as the update goes), in shares of
    `passes · num_inner / epochs` (sizes as `np.array_split`'s). With `passes == epochs` each
    epoch takes a fresh deck whole: every state in every epoch, as PPO trains its decisions.
    With `passes == 1` (`rapl_ppo.py`'s default) the epochs split one deck: each state is
    trained once per rollout, as RAPL-A2C trains it. An epoch splits its share among its
    minibatches (`np.array_split`).

    Example:
        >>> backwards = lambda n: np.arange(n)[::-1]
        >>> [s.tolist() for s in inner_state_shares(6, 4, 1, backwards)]  # 6 split 2, 2, 1, 1
        [[5, 4], [3, 2], [1], [0]]
        >>> [s.tolist() for s in inner_state_shares(3, 2, 2, backwards)]  # a deck each epoch
        [[2, 1, 0], [2, 1, 0]]
    """
    if not 1 <= passes <= epochs:
        raise ValueError(f"passes must be in [1, epochs={epochs}], actual value: {passes}")
    deck = np.empty(0, dtype=np.int64)
    whole, extra = divmod(passes * num_inner, epochs)
    for size in [whole + 1] * extra + [whole] * (epochs - extra):
        while len(deck) < size:
            deck = np.concatenate([deck, permutation(num_inner)])
        share, deck = deck[:size], deck[size:]
        yield share


def normalize_advantages(advantages: Any) -> Any:
    """`(A − mean A) / (std A + 1e-8)` over a minibatch (torch's unbiased std, as CleanRL).

    Example:
        >>> import torch
        >>> normalize_advantages(torch.tensor([1.0, 3.0])).tolist()  # mean 2, std √2
        [-0.7071067690849304, 0.7071067690849304]
    """
    return (advantages - advantages.mean()) / (advantages.std() + 1e-8)


def clipped_policy_loss(advantages: Any, new_logprob: Any, old_logprob: Any,
                        clip_coef: float) -> Any:
    """PPO's clipped surrogate, to minimise: `mean(max(−A·ρ, −A·clip(ρ, 1 − ε, 1 + ε)))` with
    the probability ratio `ρ = exp(log π_new − log π_old)` (torch tensors).

    Example:
        >>> import math, torch
        >>> old = torch.zeros(2, dtype=torch.float64)
        >>> new = torch.tensor([math.log(1.5), math.log(0.5)], dtype=torch.float64)
        >>> loss = clipped_policy_loss(torch.tensor([1.0, -1.0], dtype=torch.float64), new,
        ...                            old, 0.2)
        >>> round(loss.item(), 12)  # max(−1.5, −1.2) and max(0.5, 0.8): mean of −1.2 and 0.8
        -0.2
    """
    ratio = (new_logprob - old_logprob).exp()
    unclipped = -advantages * ratio
    clipped = -advantages * ratio.clamp(1.0 - clip_coef, 1.0 + clip_coef)
    return unclipped.maximum(clipped).mean()


def clipped_value_loss(new_values: Any, old_values: Any, returns: Any, clip_coef: float,
                       clip: bool = True) -> Any:
    """PPO's value loss: `0.5·mean(max((V − G)², (V_old + clip(V − V_old, ±ε) − G)²))`, or
    `0.5·mean((V − G)²)` with `clip=False` (torch tensors).

    Example:
        >>> import torch
        >>> new, old = torch.tensor([2.0, 0.0]), torch.tensor([1.0, 0.5])
        >>> G = torch.tensor([3.0, 0.0])
        >>> # 0.5·mean(max(1, 3.24), max(0, 0.09))
        >>> round(clipped_value_loss(new, old, G, 0.2).item(), 6)
        0.8325
        >>> clipped_value_loss(new, old, G, 0.2, clip=False).item()  # .5·mean(1, 0)
        0.25
    """
    unclipped = (new_values - returns).pow(2)
    if not clip:
        return 0.5 * unclipped.mean()
    moved = old_values + (new_values - old_values).clamp(-clip_coef, clip_coef)
    return 0.5 * unclipped.maximum((moved - returns).pow(2)).mean()
