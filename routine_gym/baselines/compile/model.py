"""The CompILE model: its configuration, its networks, and its file.

`CompILE` holds the recognition model (a GRU restarted at each boundary, with boundary and
latent heads), the decoder `π(a | s, z)` and the termination head `β(s, z)`, all on one state
encoder φ; `negative_elbo` puts the terms of `elbo.py` together. `compile_state` and
`save_compile`/`load_compile` keep a model with its options' description, loadable without
unpickling. The choices behind the architecture are in the package docstring
(`routine_gym.baselines.compile`).
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from routine_gym.atomic import atomic_write_bytes
from routine_gym.baselines.compile.elbo import (
    EPS,
    NEG_INF,
    boundary_mask,
    kl_boundary,
    kl_latent_uniform,
    reconstruction_nll,
    segment_probabilities,
)
from routine_gym.baselines.compile.masked_gru import masked_gru
from routine_gym.networks import ObservationEncoder, layer_init

__all__ = [
    "CompILE",
    "CompILEConfig",
    "Recognition",
    "compile_from_state",
    "compile_state",
    "load_compile",
    "save_compile",
]


def _gumbel_softmax(logits: torch.Tensor, temperature: float,
                    generator: torch.Generator | None) -> torch.Tensor:
    """A concrete / Gumbel-softmax sample, its noise drawn from `generator`."""
    uniform = torch.rand(logits.shape, generator=generator, device=logits.device)
    gumbel = -torch.log(EPS - torch.log(uniform + EPS))
    return F.softmax((logits + gumbel) / temperature, dim=-1)


def _one_hot(logits: torch.Tensor) -> torch.Tensor:
    """The argmax of `logits` as a one-hot of their dtype (a hard sample)."""
    return F.one_hot(logits.argmax(dim=-1), logits.shape[-1]).to(logits.dtype)


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

    def _masked_gru(self, gates: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The GRU over `[B, T, 3H]` input gates (`W_ih x + b_ih`), its state multiplied by
        `mask[:, t]` after each step (`masked_gru`: `self.gru`'s cell in a loop, made fast)."""
        return masked_gru(gates, mask, self.gru.weight_hh, self.gru.bias_hh)

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
        gates = F.linear(x, self.gru.weight_ih, self.gru.bias_ih)  # the GRU's input side, once
        start = F.one_hot(torch.zeros(b, dtype=torch.long, device=x.device),
                          length + 1).to(x.dtype)
        placed = [start]
        boundaries, logits_b, latent_logits, latents, starts = [], [], [], [], []
        for m in range(c.num_segments):
            starts.append(placed[-1].argmax(dim=-1))
            # The GRU starts afresh at the previous boundary: its state is masked before it.
            started = torch.prod(torch.cumsum(torch.stack(placed[1:]), dim=-1), dim=0) \
                if m > 0 else torch.ones_like(start)
            encodings = self._masked_gru(gates, started)
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

    def _segment_policy_logits(self, features: torch.Tensor,
                               latents: torch.Tensor) -> torch.Tensor:
        """`policy_logits` of every step under every segment's latent, `[M, B, L, A]` from
        features `[B, L, F]` and latents `[M, B, Z]`, without repeating the work: the decoder's
        first layer is `W_s s + W_z z + b`, so `W_s s` is computed once per step and `W_z z + b`
        once per segment (not M·L times each)."""
        first, activation, last = self.decoder
        width = features.shape[-1]
        per_step = F.linear(features, first.weight[:, :width])  # [B, L, H]
        per_segment = F.linear(latents, first.weight[:, width:], first.bias)  # [M, B, H]
        return last(activation(per_step.unsqueeze(0) + per_segment.unsqueeze(2)))

    def termination_logits(self, features: torch.Tensor, latents: torch.Tensor) -> torch.Tensor:
        """The termination head's logit of `β(s, z)`: `[..., F]`, `[..., Z]` to `[...]`."""
        return self.termination(torch.cat([features, latents], dim=-1)).squeeze(-1)

    def negative_elbo(self, features: torch.Tensor, actions: torch.Tensor,
                      recognition: Recognition) -> dict[str, torch.Tensor]:
        """The loss of the module docstring and its terms (`loss`, `nll`, `kl_z`, `kl_b`)."""
        c = self.config
        log_probs = F.log_softmax(self._segment_policy_logits(features, recognition.latents),
                                  dim=-1)
        nll = reconstruction_nll(log_probs, actions,
                                 segment_probabilities(recognition.boundaries))
        kl_z = kl_latent_uniform(recognition.latent_logits).sum(dim=0).mean()
        kl_b = sum((kl_boundary(logits, recognition.starts[j], c.prior_rate).mean()
                    for j, logits in enumerate(recognition.boundary_logits)),
                   torch.zeros((), device=actions.device))
        return {"loss": nll + c.beta_z * kl_z + c.beta_b * kl_b, "nll": nll, "kl_z": kl_z,
                "kl_b": kl_b}


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
