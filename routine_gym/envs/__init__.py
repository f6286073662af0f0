"""Environments routine-gym registers with Gymnasium, and the one way to build a training env.

Importing `routine_gym` registers:
- `MiniQbert-v0`: the small pyramid game of the paper's Figure 1 (`routine_gym.envs.miniqbert`);
- `procgen/CoinRun-v0`: Procgen CoinRun as a Gymnasium env (`routine_gym.envs.procgen`);
- `MinAtar/{Asterix,Breakout,Freeway,Seaquest,SpaceInvaders}-v1`: MinAtar's games
  (`routine_gym.envs.minatar`);
and `register_envs()` (called by everything in routine-gym that looks up or makes an env) adds
the ALE Atari envs (`ALE/Qbert-v5`, ...) by importing `ale_py`.

Each env family has a profile (`profile_for(env_id)`, an `EnvProfile` from
`routine_gym.envs.profile`): `atari.py`, `procgen.py`, `miniqbert.py`, `minatar.py`,
`generic.py`. It holds
what differs between families; `factory.py` builds envs from it.
"""

from __future__ import annotations

import importlib
import sys

import gymnasium as gym
from gymnasium.envs.registration import EnvSpec

__all__ = [
    "PROFILES",
    "canonical_env_id",
    "env_family",
    "env_spec",
    "make_env",
    "profile_for",
    "register_envs",
    "register_own_envs",
    "same_env",
]


def env_spec(env_id: str) -> EnvSpec | None:
    """The registered spec of `env_id`, or None for an id Gymnasium does not know.

    Ids of Gymnasium's `module:EnvId` form import `module` first, as `gym.make` does, so
    `routine_gym.envs.miniqbert:MiniQbert-v0` is the spec of `MiniQbert-v0`.
    """
    register_envs()
    module, sep, name = env_id.rpartition(":")
    if sep:
        importlib.import_module(module)
    try:
        return gym.spec(name if sep else env_id)
    except gym.error.Error:
        return None


def make_env(env_id: str, **kwargs):
    """`gym.make(env_id, **kwargs)` once every env routine-gym knows is registered (ALE's
    too): the one way routine-gym makes an env from an id a user gave."""
    register_envs()
    return gym.make(env_id, **kwargs)


def canonical_env_id(env_id: str) -> str:
    """The registered id of `env_id` (`module:EnvId` → `EnvId`); an unknown id as given."""
    spec = env_spec(env_id)
    return spec.id if spec is not None else env_id


def same_env(a: str | None, b: str | None) -> bool:
    """Whether two env ids name the same registered env (None matches anything)."""
    return a is None or b is None or canonical_env_id(a) == canonical_env_id(b)


#: The env families and their profiles: (entry-point module prefix, "module:PROFILE"). A
#: family is one module of `routine_gym/envs/` with an `EnvProfile` named `PROFILE`, and a line
#: here; the module is imported only when an env of its family is asked for (so importing
#: routine-gym never imports ALE or Procgen).
PROFILES: list[tuple[str, str]] = [
    ("ale_py", "routine_gym.envs.atari:PROFILE"),
    ("routine_gym.envs.procgen", "routine_gym.envs.procgen:PROFILE"),
    ("routine_gym.envs.miniqbert", "routine_gym.envs.miniqbert:PROFILE"),
    ("routine_gym.envs.minatar", "routine_gym.envs.minatar:PROFILE"),
]
_GENERIC = "routine_gym.envs.generic:PROFILE"


def _entry_point(spec: EnvSpec) -> str:
    entry = spec.entry_point
    if isinstance(entry, str):
        return entry
    return f"{getattr(entry, '__module__', '')}:{getattr(entry, '__qualname__', '')}"


def _profile_path(env_id: str) -> str:
    spec = env_spec(env_id)
    if spec is None:
        # Not registered (yet): ALE's names are known, so a family can be told before ALE
        # registers its envs; anything else is generic.
        name = env_id.rpartition(":")[2]
        atari = name.startswith("ALE/") or name.endswith("NoFrameskip-v4")
        return PROFILES[0][1] if atari else _GENERIC
    entry = _entry_point(spec)
    for prefix, path in PROFILES:
        if entry == prefix or entry.startswith((prefix + ".", prefix + ":")):
            return path
    return _GENERIC


def profile_for(env_id: str):
    """The `EnvProfile` of `env_id`'s family, found through Gymnasium's registry.

    The family is the one whose module holds the env's registered entry point, so
    `module:EnvId` ids and envs a user registers resolve like any other (an unregistered id
    gets the generic profile, or Atari's for an ALE name).

    Example:
        >>> import routine_gym
        >>> profile_for("MiniQbert-v0").family, profile_for("CartPole-v1").family
        ('miniqbert', 'generic')
        >>> profile_for("ale_py:ALE/Qbert-v5").frame_stack
        4
    """
    module, _, name = _profile_path(env_id).partition(":")
    return getattr(importlib.import_module(module), name)


def env_family(env_id: str) -> str:
    """`"atari"`, `"procgen"`, `"miniqbert"`, `"generic"`, ...: `profile_for(env_id).family`."""
    return profile_for(env_id).family


def register_own_envs() -> None:
    """Register `MiniQbert-v0`, `procgen/CoinRun-v0` and MinAtar's five games (lazy entry
    points: nothing heavy is imported); `import routine_gym` calls it. Calling it twice is
    harmless."""
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
    from routine_gym.envs import minatar

    minatar.register()


_ale_registered = False
_ale_quiet = False


def quiet_ale() -> None:
    """Keep ALE's banner (`A.L.E: Arcade Learning Environment ...`, `[Powered by Stella]`) off
    stderr, from now on or from when `ale_py` is loaded: ALE's warnings and errors still print.
    The scripts and `routine-gym` call it, so that a run's log and a mistake's one-line error
    are not preceded by the emulator's greeting; a library user's ALE logging is left as it is.
    """
    global _ale_quiet
    _ale_quiet = True
    ale_py = sys.modules.get("ale_py")
    if ale_py is not None:
        _warnings_only(ale_py)


def _warnings_only(ale_py) -> None:
    """ALE's log level for the scripts and `routine-gym`: warnings and errors, no banner."""
    ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Warning)


def register_envs() -> None:
    """Register routine-gym's envs and ALE's (`ALE/Qbert-v5`, ...) with Gymnasium.

    ALE's are registered by importing `ale_py` (Gymnasium 1.x loads no plugins), which loads
    the emulator; routine-gym does it the first time it looks up or makes an env, and the
    scripts at start, so that importing `routine_gym` (or `routine_gym.metrics`) stays light.
    Call it before `gym.make("ALE/...")` in code of your own (or `gym.register_envs(ale_py)`).
    Calling it twice is harmless.
    """
    global _ale_registered
    register_own_envs()
    if _ale_registered:
        return
    try:
        import ale_py
    except ImportError:  # ale-py is a dependency; a broken install should not hide the rest
        return
    gym.register_envs(ale_py)
    if _ale_quiet:
        _warnings_only(ale_py)
    _ale_registered = True
