"""Networks of SPEC §5, shared by the training scripts.

Nature CNN on Atari (Mnih et al. 2015), IMPALA CNN on Procgen (Espeholt et al. 2018, as in the
Procgen paper), MinAtar's network on MinAtar (Young & Tian 2019), a 64-64 tanh MLP for flat
observations and a small CNN for other images.
`make_torso(env_id, obs_shape)` builds the one the env's profile names (`EnvProfile.network`);
`ObservationEncoder` adds the scaling and the channel order, so a script's agent is a torso
plus its heads.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn

from routine_gym.envs import profile_for

__all__ = ["ObservationEncoder", "categorical_policy", "image_layout", "layer_init",
           "make_torso", "sample_categorical"]


# ---------------------------------------------------------------------------------------------


def layer_init(layer: nn.Module, std: float = np.sqrt(2), bias_const: float = 0.0) -> nn.Module:
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class ResidualBlock(nn.Module):
    def __init__(self, channels: int) -> None:
        super().__init__()
        self.conv0 = nn.Conv2d(channels, channels, 3, padding=1)
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv1(torch.relu(self.conv0(torch.relu(x))))


class ImpalaStage(nn.Module):
    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_channels, out_channels, 3, padding=1)
        self.pool = nn.MaxPool2d(3, stride=2, padding=1)
        self.res0 = ResidualBlock(out_channels)
        self.res1 = ResidualBlock(out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.res1(self.res0(self.pool(self.conv(x))))


def image_layout(shape: tuple[int, ...]) -> tuple[int, int, int, bool]:
    """(channels, height, width, channels_last) of an image observation."""
    if len(shape) == 2:
        return 1, shape[0], shape[1], False
    if shape[-1] in (1, 3, 4) and shape[0] not in (1, 3, 4):
        return shape[2], shape[0], shape[1], True
    return shape[0], shape[1], shape[2], False


def make_torso(env_id: str, obs_shape: tuple[int, ...]) -> tuple[nn.Module, int]:
    """The feature extractor for `env_id`'s observations and its output size."""
    network = profile_for(env_id).network
    if network == "minatar":
        # MinAtar's network (Young & Tian 2019): one 3×3 convolution of 16 channels, stride 1,
        # then a 128-unit layer, on the (C, 10, 10) observation.
        c, h, w = obs_shape
        return nn.Sequential(
            layer_init(nn.Conv2d(c, 16, 3, stride=1)), nn.ReLU(), nn.Flatten(),
            layer_init(nn.Linear(16 * (h - 2) * (w - 2), 128)), nn.ReLU(),
        ), 128
    if len(obs_shape) == 1:
        return nn.Sequential(
            layer_init(nn.Linear(obs_shape[0], 64)), nn.Tanh(),
            layer_init(nn.Linear(64, 64)), nn.Tanh(),
        ), 64
    c, h, w, _ = image_layout(obs_shape)
    if network == "nature_cnn":  # Nature CNN (Mnih et al. 2015)
        return nn.Sequential(
            layer_init(nn.Conv2d(c, 32, 8, stride=4)), nn.ReLU(),
            layer_init(nn.Conv2d(32, 64, 4, stride=2)), nn.ReLU(),
            layer_init(nn.Conv2d(64, 64, 3, stride=1)), nn.ReLU(),
            nn.Flatten(),
            layer_init(nn.Linear(64 * 7 * 7, 512)), nn.ReLU(),
        ), 512
    if network == "impala_cnn":  # IMPALA CNN (Espeholt et al. 2018), as in the Procgen paper
        stages, channels = [], c
        for out in (16, 32, 32):
            stages.append(ImpalaStage(channels, out))
            channels = out
        with torch.no_grad():
            n = nn.Sequential(*stages)(torch.zeros(1, c, h, w)).numel()
        return nn.Sequential(
            *stages, nn.Flatten(), nn.ReLU(), layer_init(nn.Linear(n, 256)), nn.ReLU()
        ), 256
    conv = nn.Sequential(
        layer_init(nn.Conv2d(c, 16, 3, stride=2)), nn.ReLU(),
        layer_init(nn.Conv2d(16, 32, 3, stride=2)), nn.ReLU(),
        nn.Flatten(),
    )
    with torch.no_grad():
        n = conv(torch.zeros(1, c, h, w)).numel()
    return nn.Sequential(conv, layer_init(nn.Linear(n, 256)), nn.ReLU()), 256


class ObservationEncoder(nn.Module):
    """Observations (uint8 images or flat vectors, batched) to features, via `make_torso`."""

    def __init__(self, env_id: str, obs_shape: tuple[int, ...], obs_dtype=np.uint8) -> None:
        super().__init__()
        self.obs_shape = tuple(obs_shape)
        self.is_image = len(self.obs_shape) >= 2
        self.channels_last = self.is_image and image_layout(self.obs_shape)[3]
        # uint8 images are scaled to [0, 1]; flat observations go in as they are.
        self.scale = 255.0 if np.dtype(obs_dtype) == np.uint8 else 1.0
        self.torso, self.num_features = make_torso(env_id, self.obs_shape)
        # The Nature CNN's convolutions run a quarter to a third faster on a CPU with the
        # channels last in memory (measured on 84×84×4 batches of 16 and 80; MinAtar's small
        # convolution is slower so). The weights are the same numbers, only laid out otherwise.
        self.memory_format = (torch.channels_last if profile_for(env_id).network == "nature_cnn"
                              and self.is_image else torch.contiguous_format)
        if self.memory_format is torch.channels_last:
            self.torso.to(memory_format=torch.channels_last)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = obs.float()
        if self.scale != 1.0:  # float observations (MinAtar, flat vectors) go in as they are
            x = x / self.scale
        if self.is_image:
            if x.dim() == 3:  # (B, H, W) grey images
                x = x.unsqueeze(1)
            elif self.channels_last:
                x = x.permute(0, 3, 1, 2)
            if self.memory_format is torch.channels_last:
                x = x.contiguous(memory_format=torch.channels_last)
        return self.torso(x)


# ---------------------------------------------------------------------------------------------
# The categorical policy's three uses, as `torch.distributions.Categorical(logits=...)` computes
# them (the same operations in the same order, so the same numbers and the same draws from
# torch's generator) without building the distribution: the object, its lazy properties and
# shape bookkeeping cost ~20 µs a call even with argument checks off, a seventh of MinAtar's
# acting pass on 16 observations.


def sample_categorical(logits: torch.Tensor) -> torch.Tensor:
    """One action per row of `logits` `[..., n]`: `Categorical(logits=logits).sample()`.

    Example:
        >>> from torch.distributions import Categorical
        >>> logits = torch.randn(5, 3)
        >>> _ = torch.manual_seed(0); ours = sample_categorical(logits)
        >>> _ = torch.manual_seed(0); torch.equal(ours, Categorical(logits=logits).sample())
        True
    """
    return _draw(torch.softmax(logits - logits.logsumexp(dim=-1, keepdim=True), dim=-1))


def _draw(probs: torch.Tensor) -> torch.Tensor:
    """One draw per row of `probs` `[..., n]`, as `Categorical.sample()` makes it."""
    n = probs.shape[-1]
    return torch.multinomial(probs.reshape(-1, n), 1, True).T.reshape(probs.shape[:-1])


def categorical_policy(
    logits: torch.Tensor, actions: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`Categorical(logits=logits)` over rows `[B, n]`: actions (sampled when `actions` is None),
    `log_prob(actions)` and `entropy()`, the tensors made in the order the distribution makes
    them (the probabilities before the log-probabilities when sampling, after otherwise), so
    that their gradients, too, are summed in the same order, bit for bit.

    Example:
        >>> from torch.distributions import Categorical
        >>> logits, actions = torch.randn(4, 3), torch.tensor([0, 2, 1, 1])
        >>> _, log_prob, entropy = categorical_policy(logits, actions)
        >>> dist = Categorical(logits=logits)
        >>> torch.equal(log_prob, dist.log_prob(actions)), torch.equal(entropy, dist.entropy())
        (True, True)
    """
    logits = logits - logits.logsumexp(dim=-1, keepdim=True)
    probs = None
    if actions is None:
        probs = torch.softmax(logits, dim=-1)
        actions = _draw(probs)
    log_prob = logits.gather(-1, actions.long().unsqueeze(-1)).squeeze(-1)
    clamped = torch.clamp(logits, min=torch.finfo(logits.dtype).min)
    if probs is None:
        probs = torch.softmax(logits, dim=-1)
    return actions, log_prob, -(clamped * probs).sum(-1)
