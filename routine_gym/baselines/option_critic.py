"""The mathematics of the option-critic baseline (`algos/option_critic.py`), as pure functions.

The synchronous advantage option-critic (A2OC, Harb et al. 2018) of the option-critic
architecture (Bacon, Harb & Precup 2017). With options ω, option values `Q_Ω(s, ω)`,
intra-option policies `π_ω(a | s)` and terminations `β_ω(s)`:

    U(s', ω)   = (1 − β_ω(s')) Q_Ω(s', ω) + β_ω(s') max_ω' Q_Ω(s', ω')      (value upon arrival)
    G_t        = r_t + γ G_{t+1},   G_N = U(s_N, ω_{N−1})                      (n-step target)
    critic     : (G_t − Q_Ω(s_t, ω_t))²
    policy     : −log π_ω(a_t | s_t) · (G_t − Q_Ω(s_t, ω_t))  − λ_entropy H(π_ω(· | s_t))
    termination: β_ω(s_{t+1}) · (Q_Ω(s_{t+1}, ω_t) − V_Ω(s_{t+1}) + ξ),  V_Ω = max_ω Q_Ω

The termination loss pushes β up where the current option is worse than the best one by more
than the deliberation cost ξ, and down elsewhere; no termination is learnt across an episode
end. A new option is chosen ε-greedily on `Q_Ω(s, ·)` when the current one terminates (and at
the start of every episode).
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = [
    "choose_options",
    "option_returns",
    "termination_advantage",
    "value_upon_arrival",
]


def value_upon_arrival(q: torch.Tensor, beta: torch.Tensor, options: torch.Tensor) -> torch.Tensor:
    """`U(s', ω) = (1 − β_ω(s')) Q_Ω(s', ω) + β_ω(s') max Q_Ω(s', ·)` for each row's option.

    Args:
        q: `(B, O)` option values at s'.
        beta: `(B, O)` termination probabilities at s'.
        options: `(B,)` the option ω running when s' was reached.

    Example:
        >>> q = torch.tensor([[1.0, 3.0], [2.0, 0.0]])
        >>> beta = torch.tensor([[0.25, 0.5], [0.5, 1.0]])
        >>> value_upon_arrival(q, beta, torch.tensor([0, 1])).tolist()  # 0.75·1 + 0.25·3; 2
        [1.5, 2.0]
    """
    q_option = q.gather(1, options[:, None]).squeeze(1)
    beta_option = beta.gather(1, options[:, None]).squeeze(1)
    return (1.0 - beta_option) * q_option + beta_option * q.max(dim=1).values


def option_returns(rewards: np.ndarray, dones: np.ndarray, bootstrap: np.ndarray,
                   gamma: float) -> np.ndarray:
    """The n-step targets `G_t = r_t + γ (1 − done_t) G_{t+1}` with `G_N = bootstrap`.

    Args:
        rewards: `(N, E)` rewards of the rollout.
        dones: `(N, E)` the episode ended at step t (terminated, or truncated with its final
            value already added to `rewards`): no bootstrap across it.
        bootstrap: `(E,)` `U(s_N, ω_{N−1})` after the rollout.
        gamma: the discount γ.

    Example:
        >>> option_returns(np.array([[1.0], [2.0]]), np.array([[False], [False]]),
        ...                np.array([4.0]), gamma=0.5).ravel().tolist()  # 1 + .5(2 + .5·4)
        [3.0, 4.0]
        >>> option_returns(np.array([[1.0], [2.0]]), np.array([[True], [False]]),
        ...                np.array([4.0]), gamma=0.5).ravel().tolist()
        [1.0, 4.0]
    """
    returns = np.zeros_like(rewards, dtype=np.float64)
    following = np.asarray(bootstrap, dtype=np.float64)
    for t in reversed(range(len(rewards))):
        following = rewards[t] + gamma * (~dones[t]) * following
        returns[t] = following
    return returns


def termination_advantage(q_next: torch.Tensor, options: torch.Tensor,
                          deliberation_cost: float) -> torch.Tensor:
    """`Q_Ω(s', ω) − V_Ω(s') + ξ` with `V_Ω(s') = max Q_Ω(s', ·)`: what `β_ω(s')` is multiplied
    by in the termination loss (negative: the option is worth keeping less than switching).

    Example:
        >>> q_next = torch.tensor([[1.0, 3.0], [2.0, 0.0]])
        >>> advantage = termination_advantage(q_next, torch.tensor([0, 0]), 0.01)
        >>> [round(x, 2) for x in advantage.tolist()]
        [-1.99, 0.01]
    """
    q_option = q_next.gather(1, options[:, None]).squeeze(1)
    return q_option - q_next.max(dim=1).values + deliberation_cost


def choose_options(q: np.ndarray, current: np.ndarray, terminate: np.ndarray, epsilon: float,
                   rng: np.random.Generator) -> np.ndarray:
    """Each env's option: `current` where it goes on, else ε-greedy on `Q_Ω(s, ·)`.

    Args:
        q: `(E, O)` option values at the current state.
        current: `(E,)` the running options.
        terminate: `(E,)` the running option ended (β fired, or a new episode began).
        epsilon: probability of a uniformly random option at a choice.
        rng: the generator of the random choices (one draw each of an ε test and an option per
            env, whether or not it chooses, so the stream does not depend on the outcome).

    Example:
        >>> q = np.array([[0.0, 5.0, 1.0], [3.0, 0.0, 0.0]])
        >>> choose_options(q, np.array([2, 2]), np.array([True, False]), 0.0,
        ...                np.random.default_rng(0)).tolist()
        [1, 2]
    """
    explore = rng.random(len(current)) < epsilon
    random_options = rng.integers(0, q.shape[1], size=len(current))
    chosen = np.where(explore, random_options, q.argmax(axis=1))
    return np.where(terminate, chosen, current)
