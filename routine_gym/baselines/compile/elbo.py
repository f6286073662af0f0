"""CompILE's ELBO as pure functions, each with a hand-worked example.

    −ELBO = Σ_m Σ_t P(t ∈ segment m) · −log π(a_t | s_t, z_m)        (`reconstruction_nll`)
            + β_z Σ_m KL(q(z_m) ‖ Uniform(Z))                         (`kl_latent_uniform`)
            + β_b Σ_{m<M-1} KL(q(b_m) ‖ Poisson length prior)          (`kl_boundary`)

`segment_probabilities` turns the (relaxed) boundaries into the soft segment masks of the first
term, `boundary_mask` masks the positions a boundary may no longer take (those up to the
previous boundary), and `poisson_length_log_prior` is the prior on a segment's length. The
choices behind them are in the package docstring (`routine_gym.baselines.compile`); the model
that puts them together is `model.py`.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

__all__ = [
    "EPS",
    "NEG_INF",
    "boundary_mask",
    "kl_boundary",
    "kl_latent_uniform",
    "poisson_length_log_prior",
    "reconstruction_nll",
    "segment_probabilities",
]

#: Added inside logarithms of probabilities that may be 0 (the reference code's value).
EPS = 1e-17
#: The logit of a position a boundary may not take (the reference code's value).
NEG_INF = -1e30


def segment_probabilities(boundaries: torch.Tensor) -> torch.Tensor:
    """Soft segment masks: the probability that step `t` belongs to segment `m`.

    Boundary `b_m` is the position where segment `m + 1` starts (segment `m` is the steps
    `b_{m-1} ≤ t < b_m`, with `b_{-1} = 0`); the last boundary is the window's end `L`. Then
    `P(t ∈ m) = Π_{j<m} P(b_j ≤ t) · P(b_m > t)`, the product over the previous boundaries
    being the reference code's soft version of "past the previous boundary".

    Args:
        boundaries: `[M, B, L+1]` (relaxed) one-hot boundary positions `0 … L`.

    Returns:
        `[M, B, L]` the masks of the steps `0 … L-1`; with hard boundaries they are 0/1 and
        each step is in exactly one segment.

    Example:
        >>> b = torch.tensor([[[0., 0., 1., 0.]], [[0., 0., 0., 1.]]])  # b_0 = 2, b_1 = L = 3
        >>> segment_probabilities(b)[:, 0].tolist()
        [[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    reached = torch.cumsum(boundaries, dim=-1)[..., :-1]  # P(b_m ≤ t), t = 0 … L-1
    # Π_{j<m} P(b_j ≤ t): an exclusive cumulative product over the segments.
    started = torch.cat([torch.ones_like(reached[:1]), torch.cumprod(reached, dim=0)[:-1]])
    return started * (1.0 - reached)


def boundary_mask(previous: torch.Tensor) -> torch.Tensor:
    """Where the next boundary may go: `Π_j P(b_j < t)` over the previous boundaries `j`.

    A segment has at least one step, so boundary `m` lies after boundary `m - 1` (and the first
    after position 0); the window's end `L` is always allowed, so the segments after the one that
    reaches it are empty. The log of this mask is added to the boundary logits: the paper's
    masking of earlier positions, exact for hard boundaries and soft for relaxed ones.

    Args:
        previous: `[m, B, L+1]` the boundaries placed so far, *including* the one-hot at 0 that
            stands for the window's start.

    Returns:
        `[B, L+1]` the mask, in [0, 1].

    Example:
        >>> start = torch.tensor([[[1., 0., 0., 0., 0.]]])  # the window starts at 0
        >>> boundary_mask(start).tolist()
        [[0.0, 1.0, 1.0, 1.0, 1.0]]
        >>> b0 = torch.tensor([[[0., 0., 1., 0., 0.]]])  # b_0 = 2: b_1 ∈ {3, 4}
        >>> boundary_mask(torch.cat([start, b0])).tolist()
        [[0.0, 0.0, 0.0, 1.0, 1.0]]
    """
    before = torch.cumsum(previous, dim=-1) - previous  # P(b_j < t)
    mask = torch.prod(before, dim=0)
    return torch.cat([mask[..., :-1], torch.ones_like(mask[..., -1:])], dim=-1)


def reconstruction_nll(
    action_log_probs: torch.Tensor, actions: torch.Tensor, segment_probs: torch.Tensor
) -> torch.Tensor:
    """`Σ_m Σ_t P(t ∈ m) · −log π(a_t | s_t, z_m)`, averaged over the batch.

    Args:
        action_log_probs: `[M, B, L, A]` the decoder's log-probabilities of every action at
            every step under every segment's latent.
        actions: `[B, L]` the demo's actions.
        segment_probs: `[M, B, L]` the soft segment masks (`segment_probabilities`).

    Example:
        >>> log_p = torch.log(torch.tensor([[[[0.5, 0.5], [0.25, 0.75]]]]))  # M = B = 1, L = 2
        >>> round(float(reconstruction_nll(log_p, torch.tensor([[0, 1]]),
        ...                                torch.tensor([[[1.0, 0.5]]]))), 4)  # log 2 + ½ log 4/3
        0.837
    """
    index = actions.unsqueeze(0).expand(action_log_probs.shape[0], -1, -1).unsqueeze(-1)
    taken = action_log_probs.gather(-1, index).squeeze(-1)  # [M, B, L]
    return -(segment_probs * taken).sum(dim=(0, 2)).mean()


def kl_latent_uniform(logits: torch.Tensor) -> torch.Tensor:
    """`KL(q ‖ Uniform(Z)) = Σ_z q_z (log q_z + log Z)` of the concrete latent's categorical.

    The reference code leaves out the constant `log Z`; with it the term is a true KL (0 for
    a uniform posterior, `log Z` for a certain one).

    Args:
        logits: `[..., Z]` the latent head's logits.

    Returns:
        `[...]` the KL of each.

    Example:
        >>> kl_latent_uniform(torch.tensor([[0.0, 0.0], [100.0, 0.0]])).tolist()  # 0 and log 2
        [0.0, 0.6931471824645996]
    """
    log_q = F.log_softmax(logits, dim=-1)
    return (log_q.exp() * (log_q + np.log(logits.shape[-1]))).sum(dim=-1)


def poisson_length_log_prior(num_positions: int, start: torch.Tensor, rate: float) -> torch.Tensor:
    """Log prior of a boundary's position: Poisson(λ) on the length of the segment it ends.

    A segment starting at `start` ends at position `t` with length `t − start ≥ 1`;
    `p(t) ∝ λ^ℓ e^{−λ} / ℓ!` over the positions `start < t ≤ L`, normalised over them (the
    window is finite). A segment that starts at the window's end `L` is empty: `p(L) = 1`.
    Positions not allowed get `−inf`.

    Args:
        num_positions: `L + 1`, the positions `0 … L`.
        start: `[B]` each segment's start (long).
        rate: λ, the mean segment length.

    Returns:
        `[B, L+1]` log-probabilities.

    Example:
        >>> # λ = 2, start 0, L = 3: lengths 1, 2, 3 ∝ 2, 2, 4/3, i.e. 3/8, 3/8, 1/4.
        >>> poisson_length_log_prior(4, torch.tensor([0]), 2.0).exp().round(decimals=6).tolist()
        [[0.0, 0.375, 0.375, 0.25]]
    """
    positions = torch.arange(num_positions, device=start.device, dtype=torch.float32)
    lengths = positions.unsqueeze(0) - start.unsqueeze(1).float()  # [B, L+1]
    unnormalised = lengths * np.log(rate) - rate - torch.lgamma(lengths.clamp(min=0) + 1)
    last = num_positions - 1
    allowed = (lengths >= 1) | ((start.unsqueeze(1) == last) & (positions == last))
    return F.log_softmax(unnormalised.masked_fill(~allowed, -np.inf), dim=-1)


def _allowed_log_prior(log_prior: torch.Tensor) -> torch.Tensor:
    """The prior with its ruled-out positions at probability `EPS` instead of 0: finite, so
    mass a relaxed boundary puts there is charged (`log q − log EPS`, about 39 nats a unit)
    rather than ignored or infinite."""
    return torch.where(torch.isfinite(log_prior), log_prior,
                       torch.full_like(log_prior, np.log(EPS)))


def kl_boundary(logits: torch.Tensor, start: torch.Tensor, rate: float) -> torch.Tensor:
    """`KL(q(b) ‖ p(b | start))` of one boundary under the Poisson length prior.

    Args:
        logits: `[B, L+1]` the boundary's (masked) logits; `q = softmax(logits)`.
        start: `[B]` the start of the segment the boundary ends (the previous boundary's
            position, 0 for the first).
        rate: λ of `poisson_length_log_prior`.

    Returns:
        `[B]` the KL of each. The prior's ruled-out positions count as probability `EPS`, so
        a boundary cannot escape the prior by putting its mass where the mask of
        `boundary_mask` (soft in training) leaves a little.

    Example:
        >>> # Certain of length 1 under the 3/8, 3/8, 1/4 prior above: KL = log 8/3.
        >>> logits = torch.tensor([[-100.0, 100.0, -100.0, -100.0]])
        >>> round(float(kl_boundary(logits, torch.tensor([0]), 2.0)[0]), 4)
        0.9808
    """
    log_q = F.log_softmax(logits, dim=-1)
    log_p = _allowed_log_prior(poisson_length_log_prior(logits.shape[-1], start, rate))
    return (log_q.exp() * (log_q - log_p)).sum(dim=-1)
