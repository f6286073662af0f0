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
    "critic_loss",
    "decision_returns",
    "first_steps",
    "inner_states_and_targets",
    "macro_reward_and_discount",
    "primitive_returns",
    "routine_discount_minus_one",
    "routine_reward_and_discount",
    "window_returns",
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
    """The MacroAction baseline's plain sum `R = Σ_j r_j` and one `Γ = γ` per decision.

    The baseline treats a routine as a black-box action: the rewards of its steps are summed
    undiscounted and the next decision is one γ away whatever the routine's length. Plain A2C is
    the same with every length 1, where this agrees with `routine_reward_and_discount`.

    Args:
        rewards: `[..., L, E]` per-step rewards, zero-padded past each routine's length.
        lengths: `[..., E]` executed lengths ℓ (≥ 1); the padding past them is not summed.
        gamma: the discount γ, used once per decision.

    Returns:
        `(R, Γ)`, each `[..., E]` float64.

    Example:
        >>> import numpy as np
        >>> from routine_gym.returns import macro_reward_and_discount, routine_reward_and_discount
        >>> rewards = np.array([[[1.0], [2.0], [4.0]]])  # [N=1, L=3, E=1]: 2 executed, 1 pad
        >>> macro_reward_and_discount(rewards, np.array([[2]]), 0.5)  # 1 + 2, γ
        (array([[3.]]), array([[0.5]]))
        >>> routine_reward_and_discount(rewards, np.array([[2]]), 0.5)  # 1 + 0.5·2, γ²
        (array([[2.]]), array([[0.25]]))
    """
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
    returns = np.empty_like(rewards)
    # What follows a decision whose episode ended: nothing (terminated), or the value of the
    # observation it was cut at (truncated).
    ended = np.logical_or(terminated, truncated)
    stops = np.where(terminated, 0.0, final_values)
    following = np.array(bootstrap_value, dtype=np.float64)  # G_{i+1}, updated in place
    for i in reversed(range(rewards.shape[0])):
        np.copyto(following, stops[i], where=ended[i])
        np.multiply(discounts[i], following, out=following)
        np.add(rewards[i], following, out=following)
        returns[i] = following
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


def inner_states_and_targets(
    inner_obs: np.ndarray, prim_returns: np.ndarray, lengths: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The critic's `A_prim` pairs: each primitive state visited inside a routine, and its return.

    Step `j ≥ 1` of decision `i` starts from the observation after step `j-1`, which the routine
    wrapper records as `inner_obs[i, j-1]`; its target is `prim_returns[i, j]`, the return from
    that step. Step 0 is left out: its state is the decision's own, whose target
    (`prim_returns[i, 0]`, the decision return `G_i`) `A_routine` already trains; so are the
    padded steps `j ≥ ℓ_i`, and with them the routine's last observation, which is the next
    decision's state.

    Args:
        inner_obs: `[N, ≥ L-1, E, *obs_shape]` the observation after each step of each decision
            (``routine_observations``, time-major); entries from step axis index `L-1` on are
            ignored.
        prim_returns: `[N, L, E]` the returns of every primitive step, as `primitive_returns`
            gives them.
        lengths: `[N, E]` executed lengths ℓ (≥ 1).

    Returns:
        `(states, targets)`: `[M, *obs_shape]` observations and `[M]` returns, where
        `M = Σ (ℓ_i − 1)`, ordered by decision, then step, then env.

    Example:
        >>> import numpy as np
        >>> from routine_gym.returns import inner_states_and_targets
        >>> inner_obs = np.array([[[[0.1]], [[0.2]]]])  # [N=1, L-1=2, E=1, 1]: after steps 0, 1
        >>> prim = np.array([[[5.0], [8.0], [12.0]]])   # [N=1, L=3, E=1]: returns of steps 0-2
        >>> states, targets = inner_states_and_targets(inner_obs, prim, np.array([[3]]))
        >>> states.tolist(), targets.tolist()
        ([[0.1], [0.2]], [8.0, 12.0])
        >>> states, targets = inner_states_and_targets(inner_obs, prim, np.array([[2]]))
        >>> states.tolist(), targets.tolist()  # a routine cut after 2 steps: one inner state
        ([[0.1]], [8.0])
    """
    lengths = np.asarray(lengths)
    max_len = prim_returns.shape[1]
    inside = np.arange(1, max_len)[None, :, None] < lengths[:, None, :]  # [N, L-1, E]
    return inner_obs[:, : max_len - 1][inside], prim_returns[:, 1:][inside]


# -- the authors' variant (SPEC §5b): each difference from the paper as its own function -----


def routine_discount_minus_one(lengths: np.ndarray, is_routine: np.ndarray,
                               gamma: float) -> np.ndarray:
    """The authors' code's decision discount: `γ^(ℓ−1)` after a routine, `γ` after a primitive
    (`routine_wrapper.py:29-30` keeps `γ^idx` of the routine's last step), where the paper has
    `γ^ℓ` for both.

    Example:
        >>> import numpy as np
        >>> routine_discount_minus_one(np.array([[3, 1]]), np.array([[True, False]]), 0.5)
        array([[0.25, 0.5 ]])
    """
    lengths = np.asarray(lengths).astype(np.float64)
    return np.where(is_routine, gamma ** (lengths - 1.0), gamma)


def critic_loss(value_loss, prim_loss, rule: str, prim_coef: float = 1.0,
                prim_limit: float = 10.0):
    """The critic's loss before `λ_value`: the paper's `L_routine + λ_prim L_prim`, or the
    authors' `0.5·L_routine + 0.5·L_prim` with `L_prim` dropped (0) when above `prim_limit`
    (`algo/a2c.py:7-11,72-75`, `clip_loss` with 10). Works on floats and on torch scalars.

    Example:
        >>> critic_loss(2.0, 4.0, "paper"), critic_loss(2.0, 4.0, "authors")
        (6.0, 3.0)
        >>> critic_loss(2.0, 12.0, "authors")  # L_prim above 10: dropped
        1.0
    """
    if rule == "paper":
        return value_loss + prim_coef * prim_loss
    if rule == "authors":
        size = float(prim_loss.detach()) if hasattr(prim_loss, "detach") else float(prim_loss)
        kept = prim_loss if size <= prim_limit else prim_loss * 0.0
        return 0.5 * value_loss + 0.5 * kept
    raise ValueError(f"unknown critic loss {rule!r} (paper or authors)")


def first_steps(lengths: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Where the first `window` primitive steps of each env's rollout are, and the state after
    them: the authors' `A_prim` states (`storage.py:219-234`).

    Each env's rollout is its decisions' primitive steps in order; step `w` of it is step
    `step[w]` of decision `decision[w]`. Entry `window` is the state the N-step targets
    bootstrap from; `(N, 0)` stands for the state after the rollout's last decision.

    Args:
        lengths: `[N, E]` executed lengths ℓ (≥ 1), so each env has at least N steps.
        window: how many steps (≤ N).

    Returns:
        `(decision, step)`, each `[window + 1, E]` int64.

    Example:
        >>> import numpy as np
        >>> decision, step = first_steps(np.array([[3], [1], [2]]), window=3)
        >>> decision[:, 0].tolist(), step[:, 0].tolist()
        ([0, 0, 0, 1], [0, 1, 2, 0])
        >>> decision, step = first_steps(np.array([[1], [1]]), window=2)
        >>> decision[:, 0].tolist(), step[:, 0].tolist()  # the state after the rollout
        ([0, 1, 2], [0, 0, 0])
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    n, e = lengths.shape
    if not 1 <= window <= n:
        raise ValueError(f"window needs to be in [1, {n}], actual value: {window}")
    decision = np.zeros((window + 1, e), dtype=np.int64)
    step = np.zeros((window + 1, e), dtype=np.int64)
    for env in range(e):
        ells = lengths[:, env]
        owner = np.append(np.repeat(np.arange(n), ells), n)[: window + 1]
        starts = np.append(np.cumsum(ells) - ells, ells.sum())
        decision[:, env] = owner
        step[:, env] = np.arange(window + 1) - starts[owner]
    return decision, step


def window_returns(rewards: np.ndarray, lengths: np.ndarray, terminated: np.ndarray,
                   truncated: np.ndarray, final_values: np.ndarray, decision: np.ndarray,
                   step: np.ndarray, bootstrap_value: np.ndarray, gamma: float) -> np.ndarray:
    """N-step TD targets of the primitive steps `first_steps` picked: `G_w = r_w + γ G_{w+1}`,
    from `bootstrap_value` (the value of the state after them), cut where an episode
    terminates and bootstrapped from the final observation's value where it is truncated
    (an episode ends only on a decision's last executed step).

    Args:
        rewards: `[N, L, E]` per-step rewards; lengths, terminated, truncated, final_values:
            `[N, E]` as in `primitive_returns`.
        decision, step: `[W + 1, E]` from `first_steps` (its last row is not read).
        bootstrap_value: `[E]` the value of the state at `(decision[W], step[W])`.

    Returns:
        `[W, E]` targets.

    Example:
        >>> import numpy as np
        >>> rewards = np.array([[[1.0], [2.0]], [[4.0], [0.0]]])  # decisions of ℓ 2 and 1
        >>> lengths = np.array([[2], [1]])
        >>> no = np.zeros((2, 1), dtype=bool)
        >>> d, s = first_steps(lengths, 2)
        >>> window_returns(rewards, lengths, no, no, np.zeros((2, 1)), d, s,
        ...                np.array([10.0]), 0.5).ravel().tolist()  # 1 + .5(2 + .5·10), 2 + 5
        [4.5, 7.0]
    """
    window = decision.shape[0] - 1
    envs = np.arange(decision.shape[1])
    d, j = decision[:window], step[:window]
    last = j == np.asarray(lengths)[d, envs] - 1
    return decision_returns(
        np.asarray(rewards, dtype=np.float64)[d, j, envs],
        np.full(d.shape, gamma, dtype=np.float64),
        last & np.asarray(terminated)[d, envs],
        last & np.asarray(truncated)[d, envs],
        np.asarray(final_values, dtype=np.float64)[d, envs],
        bootstrap_value,
    )
