"""CompILE (Kipf et al. 2019) on one demo, and its latent codes as options.

CompILE ("Compositional Imitation Learning and Execution") segments a demonstration into `M`
segments with one latent code each by maximising an ELBO: a recognition model places the
boundaries `b_0 < b_1 < … < b_{M-1}` (Gumbel-softmax / concrete relaxations of a categorical
over positions) and reads a latent `z_m` out of each segment; a decoder `π(a | s, z)`
reconstructs every segment's actions from its states and its latent:

    −ELBO = Σ_m Σ_t P(t ∈ segment m) · −log π(a_t | s_t, z_m)        (`reconstruction_nll`)
            + β_z Σ_m KL(q(z_m) ‖ Uniform(Z))                         (`kl_latent_uniform`)
            + β_b Σ_{m<M-1} KL(q(b_m) ‖ Poisson length prior)          (`kl_boundary`)

`segment_probabilities` turns the (relaxed) boundaries into the soft segment masks of the first
term, `boundary_mask` masks the positions a boundary may no longer take (those up to the
previous boundary), and `poisson_length_log_prior` is the prior on a segment's length. Each is
a pure function with hand-worked tests (`tests/test_compile.py`).

The reference code (github.com/tkipf/compile) is a toy on symbol sequences; the choices made
here for RL demos, and why:

- **Data.** The demo's decisions (`decision_steps`: the steps the demonstrator chose, the
  injected no-ops and FIREs left out) and the states the agent saw at them
  (`agent_view_states`: replayed from the demo's seeds through the agent's observation
  pipeline). One demo is one long sequence, so training samples `batch_size` windows of
  `window` = 32 consecutive decisions inside an episode at random offsets; each window is
  segmented into `num_segments` = M = 10 segments. Windows are short enough for a recurrent
  recognition model and long enough for several skills: 32 / λ = 8 segments of the prior's
  mean length, and M leaves room for the partial segments at the window's two cuts (the
  segments after the one that reaches the window's end are empty and cost nothing).
- **Networks.** One state encoder φ, the env family's torso (`ObservationEncoder`: Nature CNN
  on Atari, IMPALA CNN on Procgen, MinAtar's network, an MLP for flat observations), shared by
  recognition, decoder and termination head. Recognition: `x_t = ReLU(W φ(s_t) + E a_t)` with a
  learned end-of-window vector appended, a GRU (128 units) re-run once per segment with its
  state multiplied by the soft mask of positions past the previous boundaries (the reference's
  masked LSTM: it starts afresh at each boundary), a boundary head (logit per position) and a
  latent head (read out at the segment's last step). Decoder and termination head: MLPs on
  `[φ(s), z]` (128 units).
- **Latent: concrete (Gumbel-softmax) over `num_latents` = 8 codes**, uniform prior. A discrete
  code makes "K latents become options" direct: each code *is* an option, `z_k` its one-hot,
  with no clustering of continuous latents (the reference's other choice, Gaussian); the K most
  used codes of the demo's segmentation become the options, as RAPL keeps its K most frequent
  routines.
- **Prior on lengths: Poisson(λ = 4)**, normalised over the lengths a boundary can still take
  in the window (the routines of RAPL's demos are 3–8 actions long). Unlike the reference code,
  which scores only the first segment's boundary (times M, and one position off), each
  boundary's KL is taken against the prior on its own segment's length, counted from the
  previous boundary (its hard position); positions the prior rules out count as probability
  `EPS`, so a relaxed boundary cannot park its mass there for free. Both KLs are weighted
  β_b = β_z = 0.1 and both temperatures are 1, as in the reference code.
- **Budget** (`train_compile`): 1000 Adam steps (lr 1e-3, gradient norm clipped at 10) of 16
  windows, then (`fit_options`) 500 steps of 256 decisions. φ runs once per distinct state of
  a batch, so a step costs at most `batch_size · window` encoder passes.
- **Options.** After the ELBO, `segment` cuts the whole demo into hard segments (argmax
  boundaries and codes, window by window), and `fit_options` trains the decoder and a
  termination head `β(s', z)` by supervised learning on them: `β` is 1 on the state after a
  segment's last step, 0 on the states after its other steps (segment ends made by the end of
  the episode are left out: the episode, not the skill, ended them).

`CompILEOptions` holds the K codes with the decoder and the termination head on the CPU, and
`OptionActionWrapper` adds them to an env as `Discrete(n + K)`: option `k` runs the decoder's
greedy action `argmax_a π(a | s, z_k)` one primitive step at a time until the termination head
fires on the state reached (`β(s', z_k) > 0.5`), `max_length` steps have run, or the episode
ends. Greedy, because the options then need no random state of their own (nothing to seed or
checkpoint) and do what the demo did; the env's own randomness (sticky actions) remains.

A decoder that sees the state reconstructs a short, deterministic demo nearly without the
latent (posterior collapse): on MiniQbert's 39 decisions the latents' KL stays about 0.02
nats, so the codes say little and the boundaries mostly follow the prior. The options are then
the decoder's imitation of the demo, run for about λ steps (there: segments of 2–5 decisions,
the decoder 100 % accurate on them). That is CompILE's own behaviour with a strong decoder,
kept as it is for the baseline.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import os
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from gymnasium import spaces

from routine_gym.atomic import atomic_write_bytes
from routine_gym.imitation.agent_view import state_offsets
from routine_gym.library import routine_name
from routine_gym.networks import ObservationEncoder, layer_init

__all__ = [
    "CompILE",
    "CompILEConfig",
    "CompILEOptions",
    "OptionActionWrapper",
    "OptionSummary",
    "Segmentation",
    "boundary_mask",
    "boundary_scores",
    "compile_from_state",
    "compile_state",
    "describe_options",
    "fit_options",
    "kl_boundary",
    "kl_latent_uniform",
    "load_compile",
    "most_used_codes",
    "option_primitive_policy",
    "option_summary",
    "poisson_length_log_prior",
    "reconstruction_nll",
    "save_compile",
    "segment",
    "segment_probabilities",
    "train_compile",
]

#: Added inside logarithms of probabilities that may be 0 (the reference code's value).
EPS = 1e-17
#: The logit of a position a boundary may not take (the reference code's value).
NEG_INF = -1e30


# -- the loss terms (pure functions) ------------------------------------------------------------


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


def _gumbel_softmax(logits: torch.Tensor, temperature: float,
                    generator: torch.Generator | None) -> torch.Tensor:
    """A concrete / Gumbel-softmax sample, its noise drawn from `generator`."""
    uniform = torch.rand(logits.shape, generator=generator, device=logits.device)
    gumbel = -torch.log(EPS - torch.log(uniform + EPS))
    return F.softmax((logits + gumbel) / temperature, dim=-1)


def _one_hot(logits: torch.Tensor) -> torch.Tensor:
    return F.one_hot(logits.argmax(dim=-1), logits.shape[-1]).to(logits.dtype)


# -- the model -----------------------------------------------------------------------------------


@dataclass
class CompILEConfig:
    """The architecture and ELBO settings of a `CompILE` model (saved with it as JSON)."""

    env_id: str
    """the env whose torso encodes the states"""
    obs_shape: tuple[int, ...]
    """the agent's observation shape"""
    obs_dtype: str
    """the agent's observation dtype (`uint8` images are scaled to [0, 1])"""
    num_actions: int
    """the primitive actions"""
    num_latents: int = 8
    """Z, the codes of the concrete latent"""
    num_segments: int = 10
    """M, the segments of a window"""
    window: int = 32
    """decisions per training window"""
    prior_rate: float = 4.0
    """λ of the Poisson prior on segment lengths"""
    hidden_dim: int = 128
    """units of the GRU and the heads"""
    temp_b: float = 1.0
    """Gumbel-softmax temperature of the boundaries"""
    temp_z: float = 1.0
    """Gumbel-softmax temperature of the latents"""
    beta_b: float = 0.1
    """weight of the boundaries' KL"""
    beta_z: float = 0.1
    """weight of the latents' KL"""

    def __post_init__(self) -> None:
        self.obs_shape = tuple(int(d) for d in self.obs_shape)
        self.obs_dtype = str(np.dtype(self.obs_dtype))
        for name in ("num_actions", "num_latents", "num_segments", "window", "hidden_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} needs to be ≥ 1, actual value: {getattr(self, name)}")
        for name in ("prior_rate", "temp_b", "temp_z"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} needs to be > 0, actual value: {getattr(self, name)}")


@dataclass
class Recognition:
    """What the recognition model gives for a batch of windows (see `CompILE.recognise`)."""

    boundaries: torch.Tensor
    """`[M, B, L+1]` the (relaxed or hard) one-hot boundary of each segment"""
    boundary_logits: list[torch.Tensor]
    """the masked logits of the `M − 1` boundaries that are not fixed at the window's end"""
    starts: torch.Tensor
    """`[M, B]` each segment's start, the previous boundary's (hard) position"""
    latent_logits: torch.Tensor
    """`[M, B, Z]` the latent head's logits"""
    latents: torch.Tensor
    """`[M, B, Z]` the (relaxed or hard) one-hot latent of each segment"""


class CompILE(nn.Module):
    """Recognition model, decoder `π(a | s, z)` and termination head `β(s, z)` of CompILE."""

    def __init__(self, config: CompILEConfig) -> None:
        super().__init__()
        self.config = config
        h = config.hidden_dim
        self.encoder = ObservationEncoder(config.env_id, config.obs_shape, config.obs_dtype)
        features = self.encoder.num_features
        self.state_in = layer_init(nn.Linear(features, h))
        self.action_in = nn.Embedding(config.num_actions, h)
        self.end_of_window = nn.Parameter(torch.zeros(h))
        self.gru = nn.GRUCell(h, h)
        self.boundary_head = nn.Sequential(layer_init(nn.Linear(h, h)), nn.ReLU(),
                                           layer_init(nn.Linear(h, 1), std=0.01))
        self.latent_head = nn.Sequential(layer_init(nn.Linear(h, h)), nn.ReLU(),
                                         layer_init(nn.Linear(h, config.num_latents)))
        self.decoder = nn.Sequential(
            layer_init(nn.Linear(features + config.num_latents, h)), nn.ReLU(),
            layer_init(nn.Linear(h, config.num_actions), std=0.01))
        self.termination = nn.Sequential(
            layer_init(nn.Linear(features + config.num_latents, h)), nn.ReLU(),
            layer_init(nn.Linear(h, 1), std=0.01))

    def features(self, states: torch.Tensor) -> torch.Tensor:
        """φ(s): `[N, *obs_shape]` to `[N, F]`."""
        return self.encoder(states)

    def _masked_gru(self, inputs: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """GRU over `[B, T, H]`, its state multiplied by `mask[:, t]` after each step."""
        hidden = inputs.new_zeros(inputs.shape[0], inputs.shape[2])
        outputs = []
        for t in range(inputs.shape[1]):
            hidden = self.gru(inputs[:, t], hidden) * mask[:, t, None]
            outputs.append(hidden)
        return torch.stack(outputs, dim=1)

    def recognise(self, features: torch.Tensor, actions: torch.Tensor, *, hard: bool = False,
                  generator: torch.Generator | None = None) -> Recognition:
        """Segment a batch of windows: boundaries and latents of its `M` segments.

        Args:
            features: `[B, L, F]` φ of the state before each decision.
            actions: `[B, L]` the decisions.
            hard: argmax boundaries and latents (segmenting) instead of Gumbel-softmax samples
                (training).
            generator: the Gumbel noise's generator.
        """
        c = self.config
        b, length = actions.shape
        x = torch.relu(self.state_in(features) + self.action_in(actions))
        x = torch.cat([x, self.end_of_window.expand(b, 1, -1)], dim=1)  # [B, L+1, H]
        start = F.one_hot(torch.zeros(b, dtype=torch.long, device=x.device),
                          length + 1).to(x.dtype)
        placed = [start]
        boundaries, logits_b, latent_logits, latents, starts = [], [], [], [], []
        for m in range(c.num_segments):
            starts.append(placed[-1].argmax(dim=-1))
            # The GRU starts afresh at the previous boundary: its state is masked before it.
            started = torch.prod(torch.cumsum(torch.stack(placed[1:]), dim=-1), dim=0) \
                if m > 0 else torch.ones_like(start)
            encodings = self._masked_gru(x, started)
            if m < c.num_segments - 1:
                raw = self.boundary_head(encodings).squeeze(-1)
                mask = boundary_mask(torch.stack(placed))
                # Soft where the previous boundaries are soft; where the mask is exactly 0 (the
                # window's start, and everything up to a hard boundary) no logit can get in.
                logits = (raw + torch.log(mask.clamp(min=EPS))).masked_fill(mask <= 0, NEG_INF)
                sample = _one_hot(logits) if hard else _gumbel_softmax(logits, c.temp_b,
                                                                       generator)
                logits_b.append(logits)
            else:  # the last segment ends at the window's end
                sample = F.one_hot(torch.full((b,), length, device=x.device),
                                   length + 1).to(x.dtype)
            # The latent is read out at the segment's last step, the position before b_m.
            readout = (encodings[:, :-1] * sample[:, 1:, None]).sum(dim=1)
            z_logits = self.latent_head(readout)
            z = _one_hot(z_logits) if hard else _gumbel_softmax(z_logits, c.temp_z, generator)
            placed.append(sample)
            boundaries.append(sample)
            latent_logits.append(z_logits)
            latents.append(z)
        return Recognition(boundaries=torch.stack(boundaries), boundary_logits=logits_b,
                           starts=torch.stack(starts), latent_logits=torch.stack(latent_logits),
                           latents=torch.stack(latents))

    def policy_logits(self, features: torch.Tensor, latents: torch.Tensor) -> torch.Tensor:
        """The decoder's action logits `π(· | s, z)`: `[..., F]`, `[..., Z]` to `[..., A]`."""
        return self.decoder(torch.cat([features, latents], dim=-1))

    def termination_logits(self, features: torch.Tensor, latents: torch.Tensor) -> torch.Tensor:
        """The termination head's logit of `β(s, z)`: `[..., F]`, `[..., Z]` to `[...]`."""
        return self.termination(torch.cat([features, latents], dim=-1)).squeeze(-1)

    def negative_elbo(self, features: torch.Tensor, actions: torch.Tensor,
                      recognition: Recognition) -> dict[str, torch.Tensor]:
        """The loss of the module docstring and its terms (`loss`, `nll`, `kl_z`, `kl_b`)."""
        c = self.config
        m, _, length = recognition.boundaries.shape[0], *actions.shape
        z = recognition.latents.unsqueeze(2).expand(-1, -1, length, -1)  # [M, B, L, Z]
        log_probs = F.log_softmax(
            self.policy_logits(features.unsqueeze(0).expand(m, -1, -1, -1), z), dim=-1)
        nll = reconstruction_nll(log_probs, actions,
                                 segment_probabilities(recognition.boundaries))
        kl_z = kl_latent_uniform(recognition.latent_logits).sum(dim=0).mean()
        kl_b = sum((kl_boundary(logits, recognition.starts[j], c.prior_rate).mean()
                    for j, logits in enumerate(recognition.boundary_logits)),
                   torch.zeros((), device=actions.device))
        return {"loss": nll + c.beta_z * kl_z + c.beta_b * kl_b, "nll": nll, "kl_z": kl_z,
                "kl_b": kl_b}


# -- training on a demo --------------------------------------------------------------------------


def _episode_layout(episode_lengths: Sequence[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each episode's decisions and states start in the concatenated arrays."""
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64), state_offsets(lengths)


def _check_demo_arrays(states: np.ndarray, actions: np.ndarray,
                       episode_lengths: np.ndarray) -> None:
    if int(episode_lengths.sum()) != len(actions):
        raise ValueError(f"the episode lengths add up to {int(episode_lengths.sum())} decisions, "
                         f"but there are {len(actions)} actions")
    if len(states) != len(actions) + len(episode_lengths):
        raise ValueError(
            f"{len(actions)} decisions in {len(episode_lengths)} episode(s) need "
            f"{len(actions) + len(episode_lengths)} states (one before each decision and each "
            f"episode's last), got {len(states)}")
    if episode_lengths.max(initial=0) < 1:
        raise ValueError("the demo has no decision to learn from")


def train_compile(
    states: np.ndarray,
    actions: np.ndarray,
    episode_lengths: Sequence[int] | np.ndarray,
    config: CompILEConfig,
    *,
    iterations: int = 1000,
    batch_size: int = 16,
    learning_rate: float = 1e-3,
    seed: int = 0,
    device: torch.device | str = "cpu",
    log_every: int = 100,
    progress: Callable[[dict[str, float]], None] | None = None,
) -> tuple[CompILE, list[dict[str, float]]]:
    """Fit CompILE's ELBO on random windows of a demo (Adam; see the module docstring).

    Args:
        states: `[Σ_e (D_e + 1), *obs_shape]` the agent's states (`agent_view_states`).
        actions: `[Σ_e D_e]` the decisions (`decision_steps(demo).actions`).
        episode_lengths: `D_e`, the decisions of each episode.
        config: the model; its `window` is cut to the longest episode when that is shorter.
        iterations: gradient steps, one batch of windows each.
        batch_size: windows per batch.
        learning_rate: Adam's.
        seed: initialisation, windows and Gumbel noise (the caller's RNGs are left alone).
        device: where to train.
        log_every: iterations between the log's entries.
        progress: called with each log entry.

    Returns:
        The model (in eval mode) and the log: `iteration`, `loss`, `nll`, `kl_z`, `kl_b`.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    actions = np.asarray(actions, dtype=np.int64)
    _check_demo_arrays(states, actions, lengths)
    config = CompILEConfig(**{**asdict(config), "window": min(config.window, int(lengths.max()))})
    w = config.window
    decision_start, state_start = _episode_layout(lengths)
    # A window lies inside one episode; every start position of every long-enough episode is as
    # likely as any other.
    eligible = np.flatnonzero(lengths >= w)
    starts_per_episode = lengths[eligible] - w + 1
    device = torch.device(device)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = CompILE(config).to(device)
    generator = torch.Generator(device=device).manual_seed(seed)
    rng = np.random.default_rng(seed)
    states_t = torch.as_tensor(states, device=device)
    actions_t = torch.as_tensor(actions, device=device)
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    log: list[dict[str, float]] = []
    model.train()
    for iteration in range(1, iterations + 1):
        pick = rng.choice(len(eligible), size=batch_size, p=starts_per_episode
                          / starts_per_episode.sum())
        episode = eligible[pick]
        offset = rng.integers(0, starts_per_episode[pick])
        steps = offset[:, None] + np.arange(w)[None]  # [B, W] within the episode
        state_index = state_start[episode][:, None] + steps
        # φ once per distinct state of the batch, then gathered into the windows.
        unique, inverse = np.unique(state_index, return_inverse=True)
        features = model.features(states_t[torch.as_tensor(unique, device=device)])
        features = features[torch.as_tensor(inverse.reshape(state_index.shape), device=device)]
        window_actions = actions_t[torch.as_tensor(decision_start[episode][:, None] + steps,
                                                   device=device)]
        recognition = model.recognise(features, window_actions, generator=generator)
        terms = model.negative_elbo(features, window_actions, recognition)
        optimizer.zero_grad()
        terms["loss"].backward()
        nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        optimizer.step()
        if iteration % log_every == 0 or iteration == iterations:
            entry = {"iteration": iteration, **{k: v.item() for k, v in terms.items()}}
            log.append(entry)
            if progress is not None:
                progress(entry)
    return model.eval(), log


@dataclass(frozen=True)
class Segmentation:
    """A demo cut into hard segments, each with its latent code (see `segment`).

    Attributes:
        episodes: `(S,)` the episode of each segment.
        starts: `(S,)` its first decision, as an index into the concatenated decisions.
        lengths: `(S,)` its decisions.
        codes: `(S,)` its latent code.
    """

    episodes: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    codes: np.ndarray

    def __len__(self) -> int:
        return len(self.starts)

    def boundaries(self) -> np.ndarray:
        """Where segments start inside an episode: every start but each episode's first."""
        first = np.concatenate([[True], self.episodes[1:] != self.episodes[:-1]])
        return self.starts[~first]


@torch.no_grad()
def segment(model: CompILE, states: np.ndarray, actions: np.ndarray,
            episode_lengths: Sequence[int] | np.ndarray) -> Segmentation:
    """Cut a whole demo into hard segments: argmax boundaries and codes, window by window.

    Each episode is read in windows of `config.window` decisions: the recognition model's
    segments of a window are kept but the last (its end is the window's cut, not a boundary),
    and the next window starts where that one did; a window that reaches the episode's end
    keeps all its segments, one with no boundary inside is one segment.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    actions = np.asarray(actions, dtype=np.int64)
    _check_demo_arrays(states, actions, lengths)
    device = next(model.parameters()).device
    was_training = model.training
    model.eval()
    decision_start, state_start = _episode_layout(lengths)
    w = model.config.window
    out: dict[str, list[int]] = {"episodes": [], "starts": [], "lengths": [], "codes": []}
    for e, d in enumerate(lengths):
        position = 0
        features = model.features(torch.as_tensor(
            states[state_start[e]: state_start[e] + d], device=device))
        episode_actions = torch.as_tensor(actions[decision_start[e]: decision_start[e] + d],
                                          device=device)
        while position < d:
            end = min(position + w, int(d))
            rec = model.recognise(features[None, position:end],
                                  episode_actions[None, position:end], hard=True)
            cuts = [0] + rec.boundaries[:, 0].argmax(dim=-1).tolist()
            codes = rec.latents[:, 0].argmax(dim=-1).tolist()
            pieces = [(cuts[m], cuts[m + 1], codes[m]) for m in range(len(codes))
                      if cuts[m + 1] > cuts[m]]
            if end < d and len(pieces) > 1:
                pieces = pieces[:-1]
            for a, b, code in pieces:
                out["episodes"].append(e)
                out["starts"].append(int(decision_start[e]) + position + a)
                out["lengths"].append(b - a)
                out["codes"].append(code)
            position += pieces[-1][1]
    model.train(was_training)
    return Segmentation(**{k: np.asarray(v, dtype=np.int64) for k, v in out.items()})


def _segment_steps(segmentation: Segmentation,
                   episode_lengths: np.ndarray) -> dict[str, np.ndarray]:
    """Per decision of the segmented demo: its state, next state, code and termination target."""
    decision_start, state_start = _episode_layout(episode_lengths)
    rows: dict[str, list] = {"state": [], "next_state": [], "decision": [], "code": [],
                             "ends": [], "valid": []}
    for e, start, length, code in zip(segmentation.episodes, segmentation.starts,
                                      segmentation.lengths, segmentation.codes, strict=True):
        local = start - decision_start[e]
        for j in range(length):
            t = local + j
            rows["state"].append(state_start[e] + t)
            rows["next_state"].append(state_start[e] + t + 1)
            rows["decision"].append(start + j)
            rows["code"].append(code)
            last = j == length - 1
            rows["ends"].append(last)
            # A segment that the episode's end cut says nothing about when the skill ends.
            rows["valid"].append(not (last and t + 1 == episode_lengths[e]))
    return {k: np.asarray(v) for k, v in rows.items()}


def fit_options(
    model: CompILE,
    states: np.ndarray,
    actions: np.ndarray,
    episode_lengths: Sequence[int] | np.ndarray,
    segmentation: Segmentation,
    *,
    steps: int = 500,
    batch_size: int = 256,
    learning_rate: float = 1e-3,
    seed: int = 0,
) -> list[dict[str, float]]:
    """Train the decoder and the termination head on the hard segments (supervised).

    For step `t` of a segment with code `c`: cross-entropy of `π(· | s_t, z_c)` against the
    demo's action, and binary cross-entropy of `β(s_{t+1}, z_c)` against "t is the segment's
    last step" (left out where the episode's end cut the segment). Trains the model in place;
    returns a log of `step`, `policy_loss`, `termination_loss`.
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    data = _segment_steps(segmentation, lengths)
    device = next(model.parameters()).device
    rng = np.random.default_rng(seed)
    states_t = torch.as_tensor(states, device=device)
    actions_t = torch.as_tensor(np.asarray(actions, dtype=np.int64), device=device)
    eye = torch.eye(model.config.num_latents, device=device)
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    log = []
    model.train()
    for step in range(1, steps + 1):
        pick = rng.choice(len(data["state"]), size=min(batch_size, len(data["state"])),
                          replace=False)
        z = eye[torch.as_tensor(data["code"][pick], device=device)]
        both = model.features(states_t[torch.as_tensor(
            np.concatenate([data["state"][pick], data["next_state"][pick]]), device=device)])
        here, after = both[: len(pick)], both[len(pick):]
        policy_loss = F.cross_entropy(
            model.policy_logits(here, z),
            actions_t[torch.as_tensor(data["decision"][pick], device=device)])
        valid = torch.as_tensor(data["valid"][pick], device=device, dtype=torch.float32)
        bce = F.binary_cross_entropy_with_logits(
            model.termination_logits(after, z),
            torch.as_tensor(data["ends"][pick], device=device, dtype=torch.float32),
            reduction="none")
        termination_loss = (bce * valid).sum() / valid.sum().clamp(min=1.0)
        loss = policy_loss + termination_loss
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        optimizer.step()
        if step % 100 == 0 or step == steps:
            log.append({"step": step, "policy_loss": policy_loss.item(),
                        "termination_loss": termination_loss.item()})
    model.eval()
    return log


def most_used_codes(segmentation: Segmentation, k: int) -> list[int]:
    """The `k` codes with the most segments (ties: more decisions, then the lower code).

    Fewer when fewer codes are used.

    Example:
        >>> s = Segmentation(episodes=np.zeros(5, int), starts=np.arange(5),
        ...                  lengths=np.array([1, 3, 2, 2, 1]), codes=np.array([4, 1, 4, 2, 1]))
        >>> most_used_codes(s, 2)  # codes 4 and 1 have 2 segments each; 1 has 4 decisions
        [1, 4]
    """
    counts = Counter(segmentation.codes.tolist())
    steps = Counter()
    for code, length in zip(segmentation.codes.tolist(), segmentation.lengths.tolist(),
                            strict=True):
        steps[code] += length
    return sorted(counts, key=lambda c: (-counts[c], -steps[c], c))[:k]


def boundary_scores(predicted: Sequence[int] | np.ndarray, true: Sequence[int] | np.ndarray,
                    tolerance: int = 0) -> tuple[float, float]:
    """Boundary precision and recall, a predicted boundary matching a true one within
    `tolerance` steps (each true boundary matched at most once, nearest first).

    Example:
        >>> boundary_scores([3, 7, 9], [3, 6, 12], tolerance=1)  # 3 and 7 match 3 and 6
        (0.6666666666666666, 0.6666666666666666)
        >>> boundary_scores([3, 7, 9], [3, 6, 12])
        (0.3333333333333333, 0.3333333333333333)
    """
    predicted, true = np.asarray(predicted), np.asarray(true)
    if len(predicted) == 0 or len(true) == 0:
        return 0.0, 0.0
    distance = np.abs(predicted[:, None] - true[None, :])
    matched_true: set[int] = set()
    matches = 0
    for i in np.argsort(distance.min(axis=1), kind="stable"):
        for j in np.argsort(distance[i], kind="stable"):
            if distance[i, j] > tolerance:
                break
            if j not in matched_true:
                matched_true.add(int(j))
                matches += 1
                break
    return matches / len(predicted), matches / len(true)


# -- saving ---------------------------------------------------------------------------------------


def compile_state(model: CompILE, meta: dict[str, Any]) -> dict[str, Any]:
    """A model and its options' description as tensors and JSON strings (`weights_only` loads
    it): `state_dict`, `config`, `meta`."""
    return {"state_dict": model.state_dict(), "config": json.dumps(asdict(model.config)),
            "meta": json.dumps(meta)}


def compile_from_state(state: dict[str, Any]) -> tuple[CompILE, dict[str, Any]]:
    """The model and meta of `compile_state` (on the CPU, in eval mode)."""
    model = CompILE(CompILEConfig(**json.loads(state["config"])))
    model.load_state_dict(state["state_dict"])
    return model.eval(), json.loads(state["meta"])


def save_compile(path: str | os.PathLike, model: CompILE, meta: dict[str, Any]) -> None:
    """Write `compile_state(model, meta)` to `path` atomically."""
    buffer = io.BytesIO()
    torch.save(compile_state(model, meta), buffer)
    atomic_write_bytes(path, buffer.getvalue())


def load_compile(path: str | os.PathLike) -> tuple[CompILE, dict[str, Any]]:
    """Read a file of `save_compile` without unpickling (`torch.load(weights_only=True)`)."""
    return compile_from_state(torch.load(path, weights_only=True, map_location="cpu"))


# -- options ----------------------------------------------------------------------------------


@contextlib.contextmanager
def _one_thread() -> Iterator[None]:
    """A batch of one is fastest on one thread, and leaves the other cores to the learner."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class CompILEOptions:
    """K latent codes of a trained CompILE model as options, evaluated on the CPU.

    `evaluate(obs, k)` gives option `k`'s greedy action `argmax_a π(a | obs, z_k)` and its
    termination probability `β(obs, z_k)` in one forward pass of one observation, without
    gradients and on one thread.

    Args:
        model: the trained model (copied to the CPU; the original is left as it is).
        codes: the codes that become options, option `k` being `codes[k]`.
    """

    def __init__(self, model: CompILE, codes: Sequence[int]) -> None:
        z = model.config.num_latents
        bad = [c for c in codes if not 0 <= int(c) < z]
        if bad:
            raise ValueError(f"code {bad[0]} is not one of the model's {z} latent codes")
        if len(codes) == 0:
            raise ValueError("options need at least one code")
        self.model = copy.deepcopy(model).cpu().eval()
        self.codes = tuple(int(c) for c in codes)
        self._latents = torch.eye(z)[list(self.codes)]

    def __len__(self) -> int:
        return len(self.codes)

    def evaluate(self, obs: Any, k: int) -> tuple[int, float]:
        """Option `k`'s greedy action at `obs` and its termination probability there."""
        with torch.no_grad(), _one_thread():
            features = self.model.features(torch.as_tensor(np.asarray(obs)[None]))
            z = self._latents[k: k + 1]
            action = int(self.model.policy_logits(features, z).argmax(dim=-1)[0])
            beta = float(torch.sigmoid(self.model.termination_logits(features, z))[0])
        return action, beta


def _option_action(options: Any, k: int, obs: Any, executed: int, max_length: int) -> int | None:
    """The next primitive action of option `k` after `executed` steps, or None when it ends at
    `obs` (the termination head fires there, or it has run `max_length` steps). The first step
    always runs."""
    if executed >= max_length:
        return None
    action, beta = options.evaluate(obs, k)
    if executed > 0 and beta > 0.5:
        return None
    return action


class OptionActionWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Extends a `Discrete(n)` env with `K` CompILE options to `Discrete(n + K)`.

    Action `a < n` is the primitive `a`; action `n + k` runs option `k`: its greedy decoder
    action at the current observation, one inner `env.step` each, until the termination head
    fires on the observation reached (`β > 0.5`; never after zero steps), `max_length` steps
    have run, or the episode terminates or is truncated. Like `RoutineActionWrapper` (whose
    `info` keys it shares, so the MacroAction learner of `algos/rapl_a2c.py` and
    `algos/compile_a2c.py` reads either), the reward is the plain sum of the executed steps'
    rewards and `info` is the last inner info extended with:

    - ``routine_index`` (int): `k` for option `k`, `-1` for a primitive action.
    - ``routine_length`` (int): the primitive steps executed, `1 ≤ L ≤ max_length`.
    - ``routine_actions`` (np.int64 array): the executed actions, then `-1` padding.
    - ``routine_rewards`` (np.float64 array): each executed step's reward, then `0.0`.
    - ``routine_terminated``, ``routine_truncated`` (bool arrays): each step's flags.

    Every array has length `max_length`, so `SyncVectorEnv`/`AsyncVectorEnv` stack them. Unlike
    a routine, an option's actions depend on the observations, so the wrapper keeps the last
    observation (from `reset` and `step`) to act on.

    Example:
        >>> import gymnasium as gym
        >>> class PushRightTwice:  # option 0: action 1, ends on the state after two steps
        ...     def __init__(self): self.steps = 0
        ...     def __len__(self): return 1
        ...     def evaluate(self, obs, k):
        ...         self.steps += 1
        ...         return 1, float(self.steps == 3)
        >>> env = OptionActionWrapper(gym.make("CartPole-v1"), PushRightTwice(), max_length=5)
        >>> env.action_space
        Discrete(3)
        >>> _ = env.reset(seed=0)
        >>> _, reward, _, _, info = env.step(2)
        >>> reward, info["routine_length"], info["routine_actions"].tolist()
        (2.0, 2, [1, 1, -1, -1, -1])

    Args:
        env: an env with a `Discrete(n)` action space starting at 0.
        options: the options, e.g. `CompILEOptions`: `len(options)` is K and
            `options.evaluate(obs, k)` gives option `k`'s action at `obs` and its termination
            probability there.
        max_length: the most primitive steps an option runs (CompILE: twice the longest
            segment of its codes).

    Raises:
        TypeError: the action space is not `Discrete`.
        ValueError: it does not start at 0, there are no options, or `max_length < 1`.
    """

    def __init__(self, env: gym.Env, options: Any, max_length: int) -> None:
        space = env.action_space
        if not isinstance(space, spaces.Discrete):
            raise TypeError("OptionActionWrapper needs an env with a Discrete action space, "
                            f"actual action space: {space!r}")
        if int(space.start) != 0:
            raise ValueError("OptionActionWrapper needs a Discrete action space starting at 0, "
                             f"actual action space: {space!r}")
        if len(options) < 1:
            raise ValueError("OptionActionWrapper needs at least one option, actual: 0")
        if int(max_length) < 1:
            raise ValueError(f"max_length needs to be ≥ 1, actual value: {max_length}")
        gym.utils.RecordConstructorArgs.__init__(self, options=options,
                                                 max_length=int(max_length))
        gym.Wrapper.__init__(self, env)
        self.options = options
        self.num_primitive_actions = int(space.n)
        self.max_length = int(max_length)
        self.action_space = spaces.Discrete(self.num_primitive_actions + len(options))
        self._obs: Any = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        return obs, info

    def step(self, action: int) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Run the primitive or option `action`; see the class docstring."""
        a = int(action)
        if not self.action_space.contains(a):
            raise ValueError(f"action {action!r} is outside the action space {self.action_space}")
        n, length = self.num_primitive_actions, self.max_length
        actions = np.full(length, -1, dtype=np.int64)
        rewards = np.zeros(length, dtype=np.float64)
        terminated_steps = np.zeros(length, dtype=np.bool_)
        truncated_steps = np.zeros(length, dtype=np.bool_)
        executed, total = 0, 0.0
        primitive: int | None = a if a < n else _option_action(self.options, a - n, self._obs,
                                                               0, length)
        while primitive is not None:
            obs, reward, terminated, truncated, info = self.env.step(primitive)
            self._obs = obs
            actions[executed], rewards[executed] = primitive, float(reward)
            terminated_steps[executed], truncated_steps[executed] = terminated, truncated
            total += float(reward)
            executed += 1
            if a < n or terminated or truncated:
                break
            primitive = _option_action(self.options, a - n, obs, executed, length)
        info["routine_index"] = a - n if a >= n else -1
        info["routine_length"] = executed
        info["routine_actions"] = actions
        info["routine_rewards"] = rewards
        info["routine_terminated"] = terminated_steps
        info["routine_truncated"] = truncated_steps
        return obs, total, terminated, truncated, info

    def get_action_meanings(self) -> list[str]:
        """The inner env's action names (or ids), then `"O{k}"` (`"O{k}:z{code}"` for CompILE)."""
        n = self.num_primitive_actions
        inner = getattr(self.env.unwrapped, "get_action_meanings", None)
        meanings = [str(m) for m in inner()] if callable(inner) else None
        if meanings is None or len(meanings) != n:
            meanings = [str(i) for i in range(n)]
        codes = getattr(self.options, "codes", None)
        return meanings + [f"O{k}" + (f":z{codes[k]}" if codes is not None else "")
                           for k in range(len(self.options))]


def option_primitive_policy(
    controller: Callable[[np.ndarray], int], options: Any, max_length: int, num_actions: int
) -> Callable[[np.ndarray, gym.Env], int]:
    """A policy of primitive actions that runs a controller's options itself, one step a call.

    For `routine_gym.evaluation.evaluate_policy` (and `record_agent_demo`), which take a
    policy of the env's own actions: when `controller(obs)` picks `num_actions + k`, the
    returned policy plays option `k`'s steps on the following calls exactly as
    `OptionActionWrapper` would, and asks the controller again when the option ends. The
    policy is called as `policy(obs, env)`; a new episode (the env's `RecordEpisodeStatistics`
    counts them, as `algos/option_critic.py` reads) ends the running option.
    """
    state = {"option": None, "executed": 0, "episode": None}

    def policy(obs: np.ndarray, env: gym.Env) -> int:
        episode = env.get_wrapper_attr("episode_count")
        if episode != state["episode"]:
            state.update(option=None, episode=episode)
        if state["option"] is not None:
            action = _option_action(options, state["option"], obs, state["executed"],
                                    max_length)
            if action is not None:
                state["executed"] += 1
                return action
            state["option"] = None
        choice = int(controller(obs))
        if choice < num_actions:
            return choice
        state.update(option=choice - num_actions, executed=1)
        return _option_action(options, choice - num_actions, obs, 0, max_length)

    return policy


# -- describing the options --------------------------------------------------------------------


@dataclass
class OptionSummary:
    """What one option did in the demo's segmentation (`option_summary`)."""

    code: int
    segments: int
    min_length: int
    mean_length: float
    max_length: int
    demo_actions: list[tuple[str, int]] = field(default_factory=list)
    """the most frequent action sequences of its segments in the demo, with their counts"""
    decoded_actions: list[tuple[str, int]] = field(default_factory=list)
    """the most frequent greedy decodings `argmax π(a | s_t, z)` of its segments' states"""
    decoder_accuracy: float = 0.0
    """how often the greedy decoding is the demo's action on its segments"""


@torch.no_grad()
def option_summary(model: CompILE, states: np.ndarray, actions: np.ndarray,
                   segmentation: Segmentation, episode_lengths: Sequence[int] | np.ndarray,
                   codes: Sequence[int], meanings: Sequence[str] | None = None,
                   top: int = 3) -> list[OptionSummary]:
    """How long each code's segments were and which actions they hold and decode to."""
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    _, state_start = _episode_layout(lengths)
    decision_start, _ = _episode_layout(lengths)
    device = next(model.parameters()).device
    eye = torch.eye(model.config.num_latents, device=device)
    out = []
    for code in codes:
        chosen = np.flatnonzero(segmentation.codes == code)
        demo_strings, decoded_strings, correct, total = Counter(), Counter(), 0, 0
        for s in chosen:
            e, start, length = (segmentation.episodes[s], segmentation.starts[s],
                                segmentation.lengths[s])
            first_state = state_start[e] + start - decision_start[e]
            features = model.features(torch.as_tensor(
                states[first_state: first_state + length], device=device))
            decoded = model.policy_logits(features, eye[code].expand(length, -1)) \
                .argmax(dim=-1).cpu().numpy()
            demo = actions[start: start + length]
            demo_strings[routine_name(demo.tolist(), meanings)] += 1
            decoded_strings[routine_name(decoded.tolist(), meanings)] += 1
            correct += int((decoded == demo).sum())
            total += int(length)
        seg_lengths = segmentation.lengths[chosen]
        out.append(OptionSummary(
            code=int(code), segments=len(chosen),
            min_length=int(seg_lengths.min()) if len(chosen) else 0,
            mean_length=float(seg_lengths.mean()) if len(chosen) else 0.0,
            max_length=int(seg_lengths.max()) if len(chosen) else 0,
            demo_actions=demo_strings.most_common(top),
            decoded_actions=decoded_strings.most_common(top),
            decoder_accuracy=correct / max(total, 1)))
    return out


def describe_options(summaries: Sequence[OptionSummary], max_length: int) -> str:
    """A readable table of `option_summary`."""
    lines = [f"{len(summaries)} CompILE option(s), each runs at most {max_length} steps:"]
    for k, s in enumerate(summaries):
        lines.append(
            f"  O{k} = z{s.code}: {s.segments} segments of {s.min_length}–{s.max_length} "
            f"(mean {s.mean_length:.1f}) decisions; decoder accuracy {s.decoder_accuracy:.0%}")
        lines.append("      demo:    " + ", ".join(f"{a} ×{c}" for a, c in s.demo_actions))
        lines.append("      decoded: " + ", ".join(f"{a} ×{c}" for a, c in s.decoded_actions))
    return "\n".join(lines)
