"""The profile of any discrete env routine-gym has no family for (CartPole, a user's env).

It is `EnvProfile` as it is: the env `gym.make` builds, no preprocessing, no frame stack, an
MLP for flat `Box` observations and a small CNN for images.
"""

from __future__ import annotations

from routine_gym.envs.profile import EnvProfile

__all__ = ["PROFILE", "GenericProfile"]


class GenericProfile(EnvProfile):
    """Any other discrete env, used as `gym.make` builds it."""

    family = "generic"


PROFILE = GenericProfile()
