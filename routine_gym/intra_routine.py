"""What a routine teaches the primitive policy: two mechanisms beyond the paper (issue 49).

In RAPL as published a routine call is one decision: the policy learns that choosing routine
k at s_{t_i} paid, and nothing about the ℓ − 1 primitive actions the routine took at the
states it passed through. Two ways to pass that on, each behind a flag of `rapl_a2c.py` and
`rapl_ppo.py`, off by default:

**Intra-routine policy learning** (`--intra-coef λ_intra`). Every state s_{i,j} inside a
routine (step j ≥ 1 of decision i, the states A_prim already trains the critic at) also
trains the policy toward the primitive action a_{i,j} the routine took there, as an
off-policy actor-critic term (intra-option learning, Sutton, Precup & Singh 1999: every
option consistent with the action taken learns from it; AG-RL's "hindsight action replay",
Christodoulou et al. 2019, relabels a macro's steps as primitive transitions, most of its
+77 % on Qbert):

    L_intra = − (1/M) Σ_{i,j} ρ̄_{i,j} Â_{i,j} log π(a_{i,j} | s_{i,j})
    ρ̄_{i,j} = min(c̄, π(a_{i,j} | s_{i,j}) / μ(a_{i,j} | s_{i,j})),  μ = 1 inside a routine

μ is the behaviour's probability of a_{i,j} at s_{i,j}: inside a routine its next action is
certain, so the truncated importance weight (Retrace's, Munos et al. 2016, with c̄ = 1) is
the policy's own probability of that action, held constant. Â_{i,j} = G_prim(s_{i,j}) −
V(s_{i,j}) is the step's primitive advantage, the critic's A_prim target minus its value,
held constant. A routine step the policy would have taken anyway (ρ̄ near 1) teaches it
fully; one it would not (ρ̄ near 0) barely moves it. PPO's form of the same term is the
clipped surrogate on r = π_θ/π_old with the advantage ρ̄_old · Â (`intra_routine_ppo_loss`).

**A routine's logit starts where its first primitive's is** (`--routine-logit first-action`).
The actor's output z over |A| + K actions is read as

    z'_a = z_a  (a < |A|),    z'_{|A|+k} = z_{f_k} + z_{|A|+k}

with f_k routine k's first primitive: routine k's logit is its first primitive's plus a
learned, state-dependent offset (the head's own output, ≈ 0 at its initialisation). A routine
whose first action the policy learns to avoid is avoided with it, and one that starts with a
good action is chosen about as often as that action, not ignored; AG-RL initialises a new
macro's value from its first primitive's (+16 % on Qbert in its ablation).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from routine_gym.macro_info import PAD_ACTION

__all__ = [
    "RoutineLogits",
    "first_action_logits",
    "inner_actions",
    "intra_routine_loss",
    "intra_routine_ppo_loss",
    "routine_table",
]


def routine_table(routines: Sequence[Sequence[int]]) -> np.ndarray:
    """The routines as one `[K, L]` int64 array, padded with `PAD_ACTION` (L: the longest).

    Example:
        >>> routine_table([(2, 2, 0), (1, 0)]).tolist()
        [[2, 2, 0], [1, 0, -1]]
    """
    width = max(len(r) for r in routines)
    table = np.full((len(routines), width), PAD_ACTION, dtype=np.int64)
    for k, routine in enumerate(routines):
        table[k, : len(routine)] = routine
    return table


def inner_actions(actions: np.ndarray, lengths: np.ndarray, table: np.ndarray,
                  num_primitives: int) -> np.ndarray:
    """The primitive action each routine took at each state inside it, in the order of
    `routine_gym.returns.inner_states_and_targets` (decision, then step j ≥ 1, then env).

    Step j of decision i, a call of routine k = a_i − |A| executed for ℓ_i steps, is
    `table[k, j]` for 1 ≤ j < ℓ_i; a primitive decision (ℓ = 1) has no inner step.

    Args:
        actions: `[N, E]` the decisions (primitives `< num_primitives`, then routines).
        lengths: `[N, E]` their executed lengths ℓ (≤ the routine's length: a routine stops
            early at an episode's end).
        table: `[K, L]` the routines (`routine_table`).
        num_primitives: |A|.

    Example:
        >>> table = routine_table([(2, 2, 0), (1, 0)])
        >>> acts = np.array([[3, 4], [0, 3]])  # [N=2, E=2]: routine 0, routine 1; a primitive
        >>> lens = np.array([[3, 2], [1, 2]])  # the last call cut after 2 of its 3 steps
        >>> inner_actions(acts, lens, table, num_primitives=3).tolist()
        [2, 0, 0, 2]
    """
    actions, lengths = np.asarray(actions), np.asarray(lengths)
    width = table.shape[1]
    k = np.clip(actions - num_primitives, 0, len(table) - 1)
    steps = np.swapaxes(table[k], 1, 2)  # [N, L, E]: the routine's action j
    inside = np.arange(1, width)[None, :, None] < lengths[:, None, :]  # [N, L-1, E]
    return steps[:, 1:][inside]


def intra_routine_loss(logprobs: torch.Tensor, advantages: torch.Tensor,
                       clip: float = 1.0) -> torch.Tensor:
    """L_intra = − mean(ρ̄ Â log π(a|s)), ρ̄ = min(c̄, π(a|s)) (μ = 1 inside a routine).

    `logprobs` are log π(a_{i,j} | s_{i,j}) with their graph; ρ̄ and the primitive advantages
    `advantages` (G_prim − V) enter as constants. An empty batch gives 0.

    Example (a routine of length 3: two inner states; π(a) = 0.5 and 0.25, Â = 2 and −4):
        >>> logp = torch.log(torch.tensor([0.5, 0.25], requires_grad=True))
        >>> loss = intra_routine_loss(logp, torch.tensor([2.0, -4.0]))
        >>> round(loss.item(), 4)  # −(1·ln 0.5 − 1·ln 0.25) / 2 = −(−0.6931 + 1.3863) / 2
        -0.3466
    """
    if logprobs.numel() == 0:
        return logprobs.sum()
    weight = torch.clamp(logprobs.detach().exp(), max=clip)
    return -(weight * advantages.detach() * logprobs).mean()


def intra_routine_ppo_loss(new_logprobs: torch.Tensor, old_logprobs: torch.Tensor,
                           advantages: torch.Tensor, clip_coef: float,
                           clip: float = 1.0) -> torch.Tensor:
    """PPO's form of `intra_routine_loss`: the clipped surrogate on r = π_θ(a|s)/π_old(a|s)
    with the advantage Â' = min(c̄, π_old(a|s)) · Â,

        L_intra = − mean(min(r Â', clip(r, 1 − ε, 1 + ε) Â')),

    whose gradient at θ = θ_old is `intra_routine_loss`'s.

    Example (r = 1.5 and 0.5, π_old = 0.5 and 0.25, Â = 2 and −4, ε = 0.2):
        >>> old = torch.log(torch.tensor([0.5, 0.25]))
        >>> new = torch.log(torch.tensor([0.75, 0.125]))
        >>> round(intra_routine_ppo_loss(new, old, torch.tensor([2.0, -4.0]), 0.2).item(), 4)
        -0.2
    """
    if new_logprobs.numel() == 0:
        return new_logprobs.sum()
    weighted = torch.clamp(old_logprobs.detach().exp(), max=clip) * advantages.detach()
    ratio = (new_logprobs - old_logprobs.detach()).exp()
    clipped = torch.clamp(ratio, 1 - clip_coef, 1 + clip_coef)
    return -torch.min(ratio * weighted, clipped * weighted).mean()


def first_action_logits(logits: torch.Tensor, first_actions: torch.Tensor,
                        num_primitives: int) -> torch.Tensor:
    """z'_{|A|+k} = z_{f_k} + z_{|A|+k}; the primitives' logits unchanged.

    Example (|A| = 3, routines starting with actions 2 and 0):
        >>> z = torch.tensor([[1.0, 2.0, 3.0, 0.5, -1.0]])
        >>> first_action_logits(z, torch.tensor([2, 0]), 3).tolist()
        [[1.0, 2.0, 3.0, 3.5, 0.0]]
    """
    primitive = logits[..., :num_primitives]
    return torch.cat([primitive, logits[..., num_primitives:] + primitive[..., first_actions]],
                     dim=-1)


class RoutineLogits(torch.nn.Module):
    """`--routine-logit`'s reading of an actor's output over |A| + K actions: unchanged
    (`first_actions` None, the paper) or `first_action_logits` with routine k's first
    primitive `first_actions[k]`. No parameters and no saved state, so an agent's checkpoint
    is the same with it.
    """

    def __init__(self, num_actions: int, first_actions: Sequence[int] | None = None) -> None:
        super().__init__()
        if first_actions is None:
            self.first_actions = None
        else:
            self.register_buffer("first_actions", torch.as_tensor(first_actions),
                                 persistent=False)
        self._num_primitives = num_actions - len(first_actions or ())

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        if self.first_actions is None:
            return z
        return first_action_logits(z, self.first_actions, self._num_primitives)
