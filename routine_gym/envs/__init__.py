"""Environments routine-gym registers with Gymnasium, and the one way to build a training env.

Importing `routine_gym` registers:
- `MiniQbert-v0`: the small pyramid game of the paper's Figure 1 (`routine_gym.envs.miniqbert`);
- `procgen/CoinRun-v0`: Procgen CoinRun as a Gymnasium env (`routine_gym.envs.procgen`);
- the ALE Atari envs (`ALE/Qbert-v5`, ...), through `ale_py`.
"""

from __future__ import annotations

import importlib

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec

__all__ = ["canonical_env_id", "env_family", "env_spec", "register_envs", "same_env"]


def env_spec(env_id: str) -> EnvSpec | None:
    """The registered spec of `env_id`, or None for an id Gymnasium does not know.

    Ids of Gymnasium's `module:EnvId` form import `module` first, as `gym.make` does, so
    `routine_gym.envs.miniqbert:MiniQbert-v0` is the spec of `MiniQbert-v0`.
    """
    module, sep, name = env_id.rpartition(":")
    if sep:
        importlib.import_module(module)
    try:
        return gym.spec(name if sep else env_id)
    except gym.error.Error:
        return None


def canonical_env_id(env_id: str) -> str:
    """The registered id of `env_id` (`module:EnvId` → `EnvId`); an unknown id as given."""
    spec = env_spec(env_id)
    return spec.id if spec is not None else env_id


def same_env(a: str | None, b: str | None) -> bool:
    """Whether two env ids name the same registered env (None matches anything)."""
    return a is None or b is None or canonical_env_id(a) == canonical_env_id(b)


#: The env families routine-gym treats differently, by the module their entry point is in.
_FAMILY_ENTRY_POINTS = (
    ("ale_py", "atari"),
    ("routine_gym.envs.procgen", "procgen"),
    ("routine_gym.envs.miniqbert", "miniqbert"),
)


def env_family(env_id: str) -> str:
    """`"atari"`, `"procgen"`, `"miniqbert"` or `"generic"`, from the env's registered entry
    point (so `ale_py:ALE/Qbert-v5` is Atari and a user-registered env is generic).

    An id Gymnasium does not know falls back to its name (`ALE/...` and `...NoFrameskip-v4`
    are Atari), so that a family can be told before ALE registers its envs.
    """
    spec = env_spec(env_id)
    if spec is None:
        name = env_id.rpartition(":")[2]
        return "atari" if name.startswith("ALE/") or name.endswith("NoFrameskip-v4") else "generic"
    entry = spec.entry_point if isinstance(spec.entry_point, str) else (
        getattr(spec.entry_point, "__module__", "") or "")
    for prefix, family in _FAMILY_ENTRY_POINTS:
        if entry == prefix or entry.startswith((prefix + ".", prefix + ":")):
            return family
    return "generic"


def register_envs() -> None:
    """Register routine-gym's envs and ALE's with Gymnasium; calling it twice is harmless."""
    registry = gym.envs.registration.registry
    if "MiniQbert-v0" not in registry:
        gym.register(
            id="MiniQbert-v0",
            entry_point="routine_gym.envs.miniqbert:MiniQbertEnv",
            max_episode_steps=500,
        )
    if "procgen/CoinRun-v0" not in registry:
        gym.register(
            id="procgen/CoinRun-v0",
            entry_point="routine_gym.envs.procgen:ProcgenEnv",
            kwargs={"env_name": "coinrun"},
        )
    try:
        import ale_py
    except ImportError:  # ale-py is a dependency; a broken install should not hide the rest
        return
    gym.register_envs(ale_py)
