"""`EnvProfile`: everything routine-gym does differently for one family of environments.

A family (Atari, Procgen, MiniQbert, MinAtar, any other discrete env) differs in its default
`gym.make` keyword arguments, the training and evaluation wrapper stacks, the observation view
the agent gets, the network torso, the frame stack, its train/eval level settings and the key
of its human-normalised score. Scripts and library code ask `profile_for(env_id)` (in
`routine_gym.envs`) and never test an env id themselves; adding a family is one new module in
`routine_gym/envs/` with an `EnvProfile` subclass, plus one line in `routine_gym.envs.PROFILES`.

The base class is the generic profile: the env as `gym.make` builds it, no preprocessing, an
MLP for flat observations and a small CNN for images (`routine_gym.networks`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym

__all__ = ["EnvProfile"]


class EnvProfile:
    """The generic profile; each family overrides what it does differently.

    Attributes:
        family: the family's name (`"atari"`, `"procgen"`, `"miniqbert"`, `"generic"`, ...).
        frame_stack: frames per observation of the agent's view (Atari: 4; others: 1).
        network: the torso `routine_gym.networks.make_torso` builds: `"nature_cnn"`,
            `"impala_cnn"`, `"minatar"` or `"default"` (MLP for flat observations, a small CNN
            for images). A name, not a module: the networks depend on the profiles, never the
            reverse, so `routine_gym.envs` imports no torch.
        has_levels: the env is trained on some levels and evaluated on others (Procgen).
        reward_scale: what the scripts multiply the rewards they learn from by when
            `--reward-scale` is not given (MiniQbert: 0.01, its 25- and 100-point rewards
            swamp the value loss at 1); the logged and evaluated returns stay the game's.
    """

    family: str = "generic"
    frame_stack: int = 1
    network: str = "default"
    has_levels: bool = False
    reward_scale: float = 1.0

    def __repr__(self) -> str:
        return f"{type(self).__name__}(family={self.family!r})"

    def default_kwargs(self, env_id: str) -> dict[str, Any]:
        """The `gym.make` keyword arguments routine-gym uses unless told otherwise."""
        return {}

    def level_kwargs(self, num_levels: int, start_level: int, distribution_mode: str,
                     eval_distribution_mode: str, *, training: bool) -> dict[str, Any]:
        """`gym.make` keyword arguments of the training levels, or of the unseen evaluation
        levels with `training=False` (only families with `has_levels`)."""
        return {}

    def preprocess(self, env: gym.Env, env_id: str, *, training: bool = True,
                   serve_lives: bool = True) -> gym.Env:
        """The agent's view on top of a primitive env: reset-side wrappers, reward handling
        (training only) and the observation view. `serve_lives=False` is Atari's evaluation
        stack of routine-gym 0.1 (see `routine_gym.envs.atari`)."""
        return self.observation_view(env, env_id)

    def observation_view(self, env: gym.Env, env_id: str) -> gym.Env:
        """The observation side of `preprocess` alone (what turns recorded frames into the
        agent's states)."""
        return env

    def vector_env(self, env_id: str, num_envs: int, *, routines: Any = None,
                   record_observations: bool = False, env_kwargs: dict[str, Any] | None = None,
                   training: bool = True) -> gym.vector.VectorEnv | None:
        """A vector env of the family's own that steps `num_envs` envs of the agent's view in
        one call (same-step autoreset, the `make_env` stack's observations, rewards and info),
        or None: the generic `SyncVectorEnv` of `make_env` thunks (`make_vector_env`)."""
        return None

    def recording_stacks(self, env_id: str) -> dict[str, Callable[[gym.Env], gym.Env]]:
        """The stacks a demo may have been recorded under, newest first (`routine-gym
        upgrade`): `agent`, the evaluation view `rapl_a2c.py --record-demo` records under, and
        `raw`, no preprocessing (the CLI's `record` and `play`)."""
        return {
            "agent": lambda env: self.preprocess(env, env_id, training=False),
            "raw": lambda env: env,
        }

    def score_key(self, env_id: str) -> str | None:
        """The game's key in the human-normalised score table, or None (no such score)."""
        return None

    def scripted_expert(self, env: gym.Env, noise: float,
                        rng: Any) -> Callable[[Any], int] | None:
        """A scripted expert policy for `env` (`routine-gym record --policy expert`), or None."""
        return None

    def play_fps(self, env: gym.Env) -> int | None:
        """Steps per second for a human playing `env` (None: the env's `render_fps`)."""
        return None
