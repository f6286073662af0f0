"""Collecting demos: a trained agent's best episode (`record_agent_demo`), or a person playing
with the keyboard (`record_human_demo`).
"""

from __future__ import annotations

import inspect
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym

from routine_gym.demo.format import Demo
from routine_gym.demo.recorder import DemoRecorder, _agent_stack, _as_action
from routine_gym.envs import make_env


def _policy_caller(policy: Callable[..., Any]) -> Callable[[Any, gym.Env], Any]:
    """Call as `policy(obs, env)` with two required positional parameters, else `policy(obs)`."""
    if not callable(policy):
        raise TypeError(f"policy must be callable, got {policy!r}")
    try:
        params = inspect.signature(policy).parameters.values()
    except (TypeError, ValueError):  # builtins and some C callables have no signature
        return lambda obs, env: policy(obs)
    positional = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    required = [p for p in params if p.kind in positional and p.default is p.empty]
    if len(required) >= 2:
        return lambda obs, env: policy(obs, env)
    return lambda obs, env: policy(obs)


def record_agent_demo(
    env_id: str,
    policy: Callable[..., Any],
    num_episodes: int = 10,
    seed: int = 0,
    env_kwargs: dict[str, Any] | None = None,
    keep: str = "best",
    max_steps: int | None = None,
    record_observations: bool = False,
    progress: bool = True,
    wrap_env: Callable[[gym.Env], gym.Env] | None = None,
    meta: dict[str, Any] | None = None,
    routines: Sequence[Sequence[int]] | None = None,
    stop_rule: Any = None,
) -> Demo:
    """Run a policy for `num_episodes` episodes and keep the best one (as the paper did).

    The stack is `RoutineActionWrapper(DecisionMarker(wrap_env(DemoRecorder(gym.make(...)))))`
    (the routine wrapper only with `routines`): the demo records every primitive step of the raw
    env and marks as decisions the steps the policy chose, each primitive of a chosen routine
    included, and as injected those the preprocessing took.

    Args:
        env_id: the env, made with `gym.make(env_id, **env_kwargs)`.
        policy: `policy(obs) -> action`, or `policy(obs, env) -> action` when it has two
            required positional parameters (`env` is the env the policy acts in, `wrap_env`
            applied). The action may be an int, a NumPy integer or a one-element array, e.g.
            `lambda obs: model.predict(obs, deterministic=True)[0]` for Stable-Baselines3.
        num_episodes: episodes to run, reset with seeds `seed, seed + 1, ...`.
        seed: the first reset seed.
        env_kwargs: keyword arguments of `gym.make`.
        keep: `"best"`: the highest-scoring episode (the first one on ties), with every
            candidate's seed, score and length in `meta["candidates"]`; `"all"`: every episode.
        max_steps: cap on the primitive steps of an episode, applied as
            `gym.make(..., max_episode_steps=max_steps)` so the cut is part of the recorded env
            and replays.
        record_observations: keep the observations in the demo.
        progress: print a line per episode on stderr.
        wrap_env: wrappers the policy was trained behind (`lambda env:
            FrameStackObservation(AtariPreprocessing(env), 4)`), applied over the recorder so
            the demo still records primitive steps of the raw env. Scores are the raw env's.
            Routines go in `routines`, not in `wrap_env`.
        meta: extra provenance for `meta` (which policy, trained how long, ...).
        routines: routines the policy may choose (a `RoutineLibrary` or action sequences),
            added as a `RoutineActionWrapper` over the decision marker.
        stop_rule: the rule that may stop a routine before an inner step
            (`routine_gym.interruption.StopRule`, the rule a policy trained with `--interrupt`
            acts under); needs `routines`. None: every routine runs to its end.
    """
    if isinstance(num_episodes, bool) or not isinstance(num_episodes, int) or num_episodes < 1:
        raise ValueError(f"num_episodes needs to be ≥ 1, actual value: {num_episodes!r}")
    if keep not in ("best", "all"):
        raise ValueError(f'keep must be "best" or "all", actual value: {keep!r}')
    kwargs = dict(env_kwargs or {})
    if max_steps is not None:
        if max_steps < 1:
            raise ValueError(f"max_steps needs to be ≥ 1, actual value: {max_steps}")
        if "max_episode_steps" in kwargs:
            raise ValueError("give max_steps or env_kwargs['max_episode_steps'], not both")
        kwargs["max_episode_steps"] = max_steps
    act = _policy_caller(policy)
    recorder = DemoRecorder(
        make_env(env_id, **kwargs), record_observations=record_observations, source="agent"
    )
    env = _agent_stack(recorder, wrap_env, routines, stop_rule)
    try:
        for k in range(num_episodes):
            obs, _ = env.reset(seed=seed + k)
            while True:
                obs, _, terminated, truncated, _ = env.step(_as_action(act(obs, env)))
                if terminated or truncated:
                    break
            # A wrapper may end its episode before the raw env does (e.g. on a life lost).
            recorder._keep_unfinished()
            if progress and recorder._episodes:
                last = recorder._episodes[-1]
                print(
                    f"[record_agent_demo] {env_id} episode {k + 1}/{num_episodes} "
                    f"seed {seed + k}: score {last.score:g}, {len(last.actions)} steps",
                    file=sys.stderr,
                )
    finally:
        env.close()
    demo = recorder.demo(meta=meta)
    if keep == "all":
        return demo
    candidates = {
        "seeds": list(demo.seeds),
        "scores": demo.scores.tolist(),
        "lengths": demo.episode_lengths.tolist(),
    }
    best = demo.best()
    best.meta["candidates"] = candidates
    return best


class _EnoughEpisodes(Exception):
    """Raised from the `play` callback to stop playing once the episodes are in."""


def _default_play_fps(env: gym.Env) -> int | None:
    """The env's profile's playing speed (Atari: real time), or None for `render_fps`."""
    from routine_gym.envs import profile_for

    return profile_for(env.spec.id).play_fps(env) if env.spec is not None else None


def record_human_demo(
    env_id: str,
    keys_to_action: dict[Any, int] | None = None,
    seed: int = 0,
    fps: int | None = None,
    zoom: float | None = None,
    env_kwargs: dict[str, Any] | None = None,
    num_episodes: int = 1,
    noop: int = 0,
    record_observations: bool = False,
    meta: dict[str, Any] | None = None,
) -> Demo:
    """Play `env_id` with the keyboard (`gymnasium.utils.play.play`) and return the demo.

    Needs a display and pygame. Episode `k` is reset with seed `seed + k`. Playing stops after
    `num_episodes` episodes have ended, or earlier when the window is closed or Escape is
    pressed; an episode cut short that way is kept as played (its last step has neither flag).

    Args:
        env_id: the env, made with `gym.make(env_id, render_mode="rgb_array", **env_kwargs)`.
        keys_to_action: `play`'s mapping from keys to actions (`{"w": 2, "d": 3, ("w", "d"):
            6}`); by default the env's `get_keys_to_action()` (ALE has one: W/A/S/D to move,
            space to fire).
        seed: the reset seed of the first episode.
        fps: steps per second; by default 60 / frameskip for ALE (real-time Atari), else the
            env's `render_fps`.
        zoom: scale of the window.
        env_kwargs: keyword arguments of `gym.make`.
        num_episodes: episodes to play.
        noop: the action taken while no mapped key is pressed.
        record_observations: keep the observations in the demo.
        meta: extra provenance for `meta` (who played, ...).
    """
    with warnings.catch_warnings():  # its "matplotlib is not installed" is about PlayPlot only
        warnings.simplefilter("ignore")
        from gymnasium.utils.play import play  # imports pygame: only when a human plays

    if isinstance(num_episodes, bool) or not isinstance(num_episodes, int) or num_episodes < 1:
        raise ValueError(f"num_episodes needs to be ≥ 1, actual value: {num_episodes!r}")
    kwargs = dict(env_kwargs or {})
    if kwargs.get("render_mode", "rgb_array") != "rgb_array":
        raise ValueError(
            f"play renders rgb_array frames, got render_mode={kwargs['render_mode']!r}"
        )
    kwargs["render_mode"] = "rgb_array"
    env = make_env(env_id, **kwargs)
    if keys_to_action is None and not env.has_wrapper_attr("get_keys_to_action"):
        env.close()
        raise ValueError(
            f"{env_id} has no default keyboard mapping; pass keys_to_action, "
            "e.g. {'a': 0, 'd': 1}"
        )
    recorder = DemoRecorder(env, record_observations=record_observations, seed=seed, source="human")

    def on_step(obs_t, obs_tp1, action, reward, terminated, truncated, info) -> None:
        if terminated or truncated:
            done = recorder.num_episodes
            print(
                f"[record_human_demo] {env_id} episode {done}/{num_episodes}: "
                f"score {recorder.episode_scores[-1]:g}",
                file=sys.stderr,
            )
            if done >= num_episodes:
                raise _EnoughEpisodes

    try:
        # seed=None: the recorder seeds each reset with seed + k, where play would reuse one seed
        play(
            recorder,
            fps=fps if fps is not None else _default_play_fps(env),
            zoom=zoom,
            callback=on_step,
            keys_to_action=keys_to_action,
            seed=None,
            noop=noop,
        )
    except _EnoughEpisodes:
        import pygame

        pygame.quit()  # play's own pygame.quit() is skipped when its loop is left by raising
    finally:
        recorder.close()
    recorder._keep_unfinished()
    if recorder.num_episodes == 0:
        raise RuntimeError("no step was played, so there is no demo to return")
    return recorder.demo(meta=meta)
