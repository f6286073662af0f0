"""The one way routine-gym builds an env, for demos, training scripts and evaluation.

Two layers, so that a demonstration is always of *primitive* actions and replays from
`gym.make(env_id, **env_kwargs)` alone:

1. `make_primitive_env(env_id, **kwargs)`: the env whose actions are the primitive actions the
   routines are made of, with the family's default kwargs (Atari: ALE's own frame skip of 4,
   grey frames). This is the env a `DemoRecorder` records.
2. `preprocess(env, env_id, training=...)`: the agent's view on top, as the env's profile
   (`routine_gym.envs.profile_for`) defines it.

`make_env(...)` returns a thunk for vector envs, CleanRL style, with
`RecordEpisodeStatistics` directly on the primitive env (so the logged return is the real,
unclipped, full-game score) and a `RoutineActionWrapper` on top when routines are given.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
from gymnasium.wrappers import RecordEpisodeStatistics

from routine_gym.envs import profile_for

__all__ = [
    "default_env_kwargs",
    "make_env",
    "make_vector_env",
    "make_primitive_env",
    "preprocess",
    "preprocess_observation",
    "recording_stacks",
]


def default_env_kwargs(env_id: str) -> dict[str, Any]:
    """The `gym.make` keyword arguments routine-gym uses for `env_id` unless told otherwise."""
    return profile_for(env_id).default_kwargs(env_id)


def make_primitive_env(env_id: str, render_mode: str | None = None, **kwargs: Any) -> gym.Env:
    """The env of primitive actions (what demos record), with routine-gym's defaults."""
    kwargs = {**default_env_kwargs(env_id), **kwargs}
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    return gym.make(env_id, **kwargs)


def preprocess(
    env: gym.Env, env_id: str, *, training: bool = True, serve_lives: bool = True
) -> gym.Env:
    """Add the agent's standard preprocessing on top of a primitive env (the profile's).

    Atari: no-op starts, FIRE, 84×84 grey 4-stacks; in training a life loss also ends the
    episode and rewards are sign-clipped; in evaluation each new life is served with FIRE
    (`serve_lives=False` leaves that out: routine-gym 0.1's stack). MiniQbert: a life loss ends
    the training episode. Other families: as they are.
    """
    return profile_for(env_id).preprocess(env, env_id, training=training,
                                          serve_lives=serve_lives)


def recording_stacks(env_id: str) -> dict[str, Callable[[gym.Env], gym.Env]]:
    """The preprocessing stacks a demo of `env_id` may have been recorded under, newest first.

    `routine-gym upgrade` replays a version-1 demo through each in turn to find which steps
    the preprocessing injected. `agent` is today's evaluation view (`preprocess(...,
    training=False)`, what `rapl_a2c.py --record-demo` records under); Atari adds `agent-0.1`,
    the same without `FireOnLifeLoss` (routine-gym 0.1); `raw` is no preprocessing (the CLI's
    `record` and `play`), where every step is a decision.
    """
    return profile_for(env_id).recording_stacks(env_id)


def preprocess_observation(env: gym.Env, env_id: str) -> gym.Env:
    """The observation side of `preprocess` alone: Atari frames to 84×84 grey, stacked by 4."""
    return profile_for(env_id).observation_view(env, env_id)


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
    first_video_episode: int = 0,
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
        capture_video: film env 0's episodes 0, 1, 8, 27, ... (CleanRL's schedule) into
            `videos/{run_name}/train-episode-{k}.gif`, each frame captioned with its primitive
            action (`routine_gym.video`; Gymnasium's `RecordVideo` needs moviepy).
        first_video_episode: the number of env 0's first episode (a resumed run's episodes
            so far, `Run.first_video_episode`), so its films go on where the run left off.
    """

    def thunk() -> gym.Env:
        render_mode = "rgb_array" if capture_video and idx == 0 else None
        env = make_primitive_env(env_id, render_mode=render_mode, **(env_kwargs or {}))
        if capture_video and idx == 0:
            env = _filmed(env, f"videos/{run_name}", first_video_episode)
        env = RecordEpisodeStatistics(env)
        env = preprocess(env, env_id, training=training)
        if routines is not None and len(routines) > 0:
            from routine_gym.wrapper import RoutineActionWrapper

            env = RoutineActionWrapper(env, routines, record_observations=record_observations)
        env.action_space.seed(seed + idx)
        return env

    return thunk


def _filmed(env: gym.Env, folder: str, first_episode: int = 0) -> gym.Env:
    """`env` filming its episodes on the cubic schedule as captioned GIFs in `folder`,
    numbered from `first_episode`; a GIF already there (a killed leg's, filmed after its last
    checkpoint) is kept and the new one named beside it."""
    from routine_gym.video import (
        FrameRecorder,
        cubic_schedule,
        step_captions,
        unused_path,
        write_gif,
    )

    meanings = getattr(env.unwrapped, "get_action_meanings", lambda: None)()
    fps = (env.metadata or {}).get("render_fps") or 15

    def write(episode: int, frames: list, actions: list[int]) -> None:
        captions = step_captions(actions, [True] * len(actions), actions,
                                 num_actions=int(env.action_space.n),
                                 action_meanings=meanings)
        write_gif(frames, [*captions, f"end of training episode {episode}"],
                  unused_path(f"{folder}/train-episode-{episode}.gif"), fps=fps)

    return FrameRecorder(env, record=cubic_schedule, on_episode_end=write,
                         first_episode=first_episode, spool_dir=folder)


def make_vector_env(
    env_id: str,
    num_envs: int,
    seed: int = 0,
    *,
    routines: Sequence[Sequence[int]] | None = None,
    training: bool = True,
    record_observations: bool = False,
    env_kwargs: dict[str, Any] | None = None,
    capture_video: bool = False,
    run_name: str = "",
    first_video_episode: int = 0,
    async_envs: bool = False,
    batched: bool = True,
) -> gym.vector.VectorEnv:
    """The training scripts' vector env of `num_envs` `make_env` envs, same-step autoreset.

    A family with a vector env of its own (`EnvProfile.vector_env`: MinAtar's
    `MinAtarVectorEnv`) steps all envs in one call; it returns what the `SyncVectorEnv` of
    `make_env` thunks returns. The thunks' `SyncVectorEnv` (or `AsyncVectorEnv` with
    `async_envs`, subprocesses) is used for every other family, for video capture, and with
    `batched=False`.
    """
    if batched and not async_envs and not capture_video:
        envs = profile_for(env_id).vector_env(
            env_id, num_envs, routines=routines, record_observations=record_observations,
            env_kwargs=env_kwargs, training=training)
        if envs is not None:
            return envs
    thunks = [make_env(env_id, seed, i, routines=routines, training=training,
                       record_observations=record_observations, env_kwargs=env_kwargs,
                       capture_video=capture_video, run_name=run_name,
                       first_video_episode=first_video_episode)
              for i in range(num_envs)]
    vector_cls = gym.vector.AsyncVectorEnv if async_envs else gym.vector.SyncVectorEnv
    return vector_cls(thunks, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
