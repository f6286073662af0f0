"""The one way routine-gym builds an env, for demos, training scripts and evaluation.

Two layers, so that a demonstration is always of *primitive* actions and replays from
`gym.make(env_id, **env_kwargs)` alone:

1. `make_primitive_env(env_id, **kwargs)`: the env whose actions are the primitive actions the
   routines are made of. For Atari that is ALE with its own frame skip of 4 (the last frame
   observed) and grey observations; `*NoFrameskip-v4` ids get `frameskip=4` too, so an agent
   step is 4 frames everywhere. This is the env a `DemoRecorder` records.
2. `preprocess(env, env_id, training=...)`: the agent's view on top. Atari: no-op starts,
   (training only) a life loss ends the episode, FIRE on reset, reward sign-clipping, 84×84,
   4-frame stack. Procgen and other envs are used as they are.

`make_env(...)` returns a thunk for vector envs, CleanRL style, with
`RecordEpisodeStatistics` directly on the primitive env (so the logged return is the real,
unclipped, full-game score) and a `RoutineActionWrapper` on top when routines are given.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
from gymnasium.wrappers import (
    FrameStackObservation,
    RecordEpisodeStatistics,
    ResizeObservation,
    TransformReward,
)

from routine_gym.envs import env_family
from routine_gym.envs.atari import (
    EpisodicLife,
    FireOnLifeLoss,
    FireReset,
    NoopReset,
    is_atari,
    sign_reward,
)

__all__ = [
    "default_env_kwargs",
    "is_atari",
    "is_miniqbert",
    "is_procgen",
    "make_env",
    "make_primitive_env",
    "preprocess",
    "preprocess_observation",
    "recording_stacks",
]

COINRUN_ID = "procgen/CoinRun-v0"


def is_miniqbert(env_id: str) -> bool:
    """`MiniQbert-v0`, by its registered entry point (`module:EnvId` ids too)."""
    return env_family(env_id) == "miniqbert"


def is_procgen(env_id: str) -> bool:
    """`procgen/CoinRun-v0`, by its registered entry point."""
    return env_family(env_id) == "procgen"


def default_env_kwargs(env_id: str) -> dict[str, Any]:
    """The `gym.make` keyword arguments routine-gym uses for `env_id` unless told otherwise."""
    if is_atari(env_id):
        return {"frameskip": 4, "obs_type": "grayscale"}
    return {}


def make_primitive_env(env_id: str, render_mode: str | None = None, **kwargs: Any) -> gym.Env:
    """The env of primitive actions (what demos record), with routine-gym's defaults."""
    kwargs = {**default_env_kwargs(env_id), **kwargs}
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    return gym.make(env_id, **kwargs)


def preprocess(
    env: gym.Env, env_id: str, *, training: bool = True, serve_lives: bool = True
) -> gym.Env:
    """Add the agent's standard preprocessing on top of a primitive env.

    Atari: no-op starts, FIRE, 84×84 grey 4-stacks; in training a life loss also ends the
    episode and rewards are sign-clipped. MiniQbert, a Qbert in miniature, is trained as Qbert
    is: a life loss ends the training episode (otherwise falling off is a free teleport back to
    the top, and agents learn to spend lives on it until the last one runs out).

    `serve_lives=False` leaves `FireOnLifeLoss` out of the evaluation stack: the stack of
    routine-gym 0.1, which the first shipped Qbert demo was recorded under.
    """
    if is_miniqbert(env_id):
        return EpisodicLife(env) if training else env
    if not is_atari(env_id):
        return env
    env = NoopReset(env, noop_max=30)
    if training:
        env = EpisodicLife(env)
    if "FIRE" in env.unwrapped.get_action_meanings():
        if not training and serve_lives:  # each life starts as in training (EpisodicLife +
            # FireReset fire there)
            env = FireOnLifeLoss(env)
        env = FireReset(env)
    if training:
        env = TransformReward(env, sign_reward)
    return preprocess_observation(env, env_id)


def recording_stacks(env_id: str) -> dict[str, Callable[[gym.Env], gym.Env]]:
    """The preprocessing stacks a demo of `env_id` may have been recorded under, newest first.

    `routine-gym upgrade` replays a version-1 demo through each in turn to find which steps
    the preprocessing injected. `agent` is today's evaluation view (`preprocess(...,
    training=False)`, what `rapl_a2c.py --record-demo` records under); `agent-0.1` the same
    without `FireOnLifeLoss` (routine-gym 0.1), only where it differs; `raw` no preprocessing
    (the CLI's `record` and `play`), where every step is a decision.
    """
    stacks: dict[str, Callable[[gym.Env], gym.Env]] = {
        "agent": lambda env: preprocess(env, env_id, training=False),
    }
    if is_atari(env_id):
        stacks["agent-0.1"] = lambda env: preprocess(env, env_id, training=False,
                                                     serve_lives=False)
    stacks["raw"] = lambda env: env
    return stacks


def preprocess_observation(env: gym.Env, env_id: str) -> gym.Env:
    """The observation side of `preprocess` alone: Atari frames to 84×84 grey, stacked by 4."""
    if not is_atari(env_id):
        return env
    if len(env.observation_space.shape) == 3:  # an RGB primitive env
        env = gym.wrappers.GrayscaleObservation(env)
    env = ResizeObservation(env, (84, 84))
    return FrameStackObservation(env, 4)


def make_env(
    env_id: str,
    seed: int = 0,
    idx: int = 0,
    *,
    routines: Sequence[Sequence[int]] | None = None,
    training: bool = True,
    record_observations: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    capture_video: bool = False,
    run_name: str = "",
) -> Callable[[], gym.Env]:
    """A thunk that builds env number `idx`: primitive env, statistics, preprocessing, routines.

    Args:
        env_id: any registered discrete env (`ALE/Qbert-v5`, `procgen/CoinRun-v0`, ...).
        seed: the vector env's seed; each thunk seeds its action space with `seed + idx`.
        idx: the env's index in the vector env (video is captured for env 0).
        routines: the routines to add as actions (a `RoutineLibrary` or action sequences).
        training: training-only wrappers (Atari and MiniQbert: a life loss ends the episode;
            Atari: reward clipping).
        record_observations: let the routine wrapper return the intermediate observations.
        env_kwargs: extra `gym.make` keyword arguments (e.g. `num_levels` for CoinRun).
        capture_video: record videos of env 0 into `videos/{run_name}`.
    """

    def thunk() -> gym.Env:
        render_mode = "rgb_array" if capture_video and idx == 0 else None
        env = make_primitive_env(env_id, render_mode=render_mode, **(env_kwargs or {}))
        if capture_video and idx == 0:
            env = gym.wrappers.RecordVideo(env, f"videos/{run_name}")
        env = RecordEpisodeStatistics(env)
        env = preprocess(env, env_id, training=training)
        if routines is not None and len(routines) > 0:
            from routine_gym.wrapper import RoutineActionWrapper

            env = RoutineActionWrapper(env, routines, record_observations=record_observations)
        env.action_space.seed(seed + idx)
        return env

    return thunk
