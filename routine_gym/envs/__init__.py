"""Environments routine-gym registers with Gymnasium, and the one way to build a training env.

Importing `routine_gym` registers:
- `MiniQbert-v0`: the small pyramid game of the paper's Figure 1 (`routine_gym.envs.miniqbert`);
- `procgen/CoinRun-v0`: Procgen CoinRun as a Gymnasium env (`routine_gym.envs.procgen`);
- the ALE Atari envs (`ALE/Qbert-v5`, ...), through `ale_py`.
"""

from __future__ import annotations

import gymnasium as gym


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
