"""Replay: re-run a demo's actions from its seeds and verify that the env reproduces it.

A demo's env is deterministic given the reset seed and the actions, so `replay` re-creates the
raw env from the demo's `meta` and checks every reward, flag and (when stored) observation. A
version-1 demo is upgraded to version 2 the same way: `upgrade_demo` replays it through the
preprocessing it was recorded under to re-derive which steps were injected. `render_frames`
replays a demo with the env rendering, as far as the frames it is asked for (the pictures of
routines, `routine_gym.pictures`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.demo.format import Demo, DemoEpisode, _check_env
from routine_gym.demo.recorder import DemoRecorder, _agent_stack, _Episode
from routine_gym.envs import make_env


class DemoReplayError(ValueError):
    """A replayed demo diverged from its record; `episode` and `step` say where."""

    def __init__(self, message: str, episode: int, step: int | None) -> None:
        super().__init__(message)
        self.episode = episode
        self.step = step


@dataclass(frozen=True)
class ReplayResult:
    """What `replay` observed, one entry per replayed episode.

    Attributes:
        episodes: indices (into the demo) of the replayed episodes.
        scores: undiscounted return of each replayed episode.
        lengths: steps each episode ran (fewer than the demo's if the env ended early).
        divergences: None for an episode that matched its record, else where and how it
            diverged (only with `check=False`; with `check=True` a divergence raises).
        demo: the replayed episodes as recorded again, with observations when
            `record_observations=True` (how to regenerate a shipped demo's observations).
    """

    episodes: tuple[int, ...]
    scores: np.ndarray
    lengths: np.ndarray
    divergences: tuple[str | None, ...]
    demo: Demo

    @property
    def matched(self) -> bool:
        return all(d is None for d in self.divergences)


def _same_obs(a: Any, b: np.ndarray) -> str | None:
    a = np.asarray(a)
    if a.shape != b.shape:
        return f"observation shape {a.shape} in replay, {b.shape} in the demo"
    if a.dtype.kind == "f" or b.dtype.kind == "f":
        if not np.allclose(a, b, rtol=1e-5, atol=1e-6):
            diff = float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64))))
            return f"observation differs (max abs difference {diff:g})"
    elif not np.array_equal(a, b):
        return f"observation differs in {int(np.count_nonzero(a != b))} entries"
    return None


def replay(
    demo: Demo,
    env: gym.Env | None = None,
    episode: int | Sequence[int] | None = None,
    check: bool = True,
    record_observations: bool = False,
) -> ReplayResult:
    """Re-run a demo's actions from its seeds and verify that the env reproduces it.

    Each episode is reset with its recorded seed and its actions are stepped in order; every
    step's reward (to 1e-6 relative), `terminated` and `truncated` flags, and the observations
    when the demo stores them (exact for integers, to 1e-5 relative for floats), must match.

    Args:
        demo: the demo.
        env: the env to replay in: the raw env, without preprocessing wrappers. By default
            `gym.make(demo.env_id, max_episode_steps=..., **demo.env_kwargs)` is made (and
            closed afterwards); a demo recorded on an env without a spec needs `env`.
        episode: an episode index, a list of them, or None for every episode.
        check: raise `DemoReplayError` at the first divergence; with False, divergences are
            reported in the result and the episode goes on while the env lets it.
        record_observations: record the observations of the replay into `result.demo`.

    Raises:
        DemoReplayError: with `check=True`, naming the episode and step that diverged.
        ValueError: the demo has no env id and no `env` was given, an episode has no seed,
            or `env` is not the demo's env.
    """
    indices = demo._indices(episode)
    for i in indices:
        if demo.meta["seeds"][i] is None:
            raise ValueError(f"episode {i} of the demo has no reset seed, so it cannot be replayed")
    own_env = env is None
    if own_env:
        if demo.env_id is None:
            raise ValueError(
                "this demo has no env id (it was recorded on an env not made by gym.make), so "
                "replay cannot re-create its env; pass the env: replay(demo, env=...)"
            )
        kwargs = demo.env_kwargs
        if demo.meta.get("max_episode_steps") is not None:
            kwargs["max_episode_steps"] = demo.meta["max_episode_steps"]
        env = make_env(demo.env_id, **kwargs)
    else:
        _check_env(demo, env=env)
    with warnings.catch_warnings():  # the replay env may legitimately be wrapped or spec-less
        warnings.simplefilter("ignore")
        recorder = DemoRecorder(env, record_observations=record_observations, source="replay")

    scores, lengths, divergences = [], [], []
    try:
        for i in indices:
            ep = demo.episode(i)
            divergence, where = None, None
            obs, _ = recorder.reset(seed=ep.seed)
            if ep.observations is not None:
                divergence = _same_obs(obs, ep.observations[0])
                where = "at reset" if divergence else None
            score, steps = 0.0, 0
            for t, action in enumerate(ep.actions):
                obs, reward, terminated, truncated, _ = recorder.step(int(action))
                score += float(reward)
                steps = t + 1
                if divergence is None:
                    divergence = _compare_step(ep, t, obs, reward, terminated, truncated)
                    where = f"at step {t} (action {int(action)})" if divergence else None
                if divergence is not None and check:
                    raise DemoReplayError(
                        f"replay of episode {i} (seed {ep.seed}) diverged {where}: {divergence}",
                        episode=i,
                        step=None if where == "at reset" else t,
                    )
                if terminated or truncated:
                    break
            recorder._keep_unfinished()
            scores.append(score)
            lengths.append(steps)
            divergences.append(
                None if divergence is None else f"episode {i} diverged {where}: {divergence}"
            )
    finally:
        if own_env:
            env.close()
    replayed = recorder.demo()
    meta = {k: v for k, v in demo.meta.items() if k not in ("scores",)}
    meta["seeds"] = [demo.meta["seeds"][i] for i in indices]
    original = demo.select(indices)
    same_steps = np.array_equal(replayed.episode_lengths, original.episode_lengths)
    replayed = Demo(
        actions=replayed.actions,
        rewards=replayed.rewards,
        terminated=replayed.terminated,
        truncated=replayed.truncated,
        episode_lengths=replayed.episode_lengths,
        observations=replayed.observations,
        final_observations=replayed.final_observations,
        meta=meta,
        # The replay steps the raw env only; which steps were decisions is the demo's record.
        decisions=original.decisions if same_steps else None,
    )
    return ReplayResult(
        episodes=tuple(indices),
        scores=np.array(scores, dtype=np.float64),
        lengths=np.array(lengths, dtype=np.int64),
        divergences=tuple(divergences),
        demo=replayed,
    )


def render_frames(
    demo: Demo, steps: Mapping[int, Iterable[int]]
) -> dict[tuple[int, int], np.ndarray]:
    """The RGB frames the env showed before the given steps, replayed from the demo's seeds.

    Each episode named in `steps` is reset with its seed in the env `replay` makes, with
    `render_mode="rgb_array"`, and stepped only as far as the last step asked for, so a frame
    near the start of a long demo costs a few steps. Every replayed step is checked against
    the record as `replay` checks it.

    Args:
        demo: the demo.
        steps: `{episode: steps within it}`; step `t` asks for the frame before action `t`.

    Returns:
        `{(episode, step): frame}`, each frame `env.render()`: an (H, W, 3) uint8 array.

    Raises:
        ValueError: the demo has no env id, an episode has no seed, a step lies outside its
            episode, or the env cannot render RGB frames (naming the env and the problem).
        DemoReplayError: the replay diverged from the record before the last frame asked for.
    """
    wanted = {demo._index(e): sorted({int(t) for t in ts}) for e, ts in steps.items()}
    wanted = {e: ts for e, ts in wanted.items() if ts}
    for e, ts in wanted.items():
        if ts[0] < 0 or ts[-1] >= int(demo.episode_lengths[e]):
            raise ValueError(f"step {ts[0] if ts[0] < 0 else ts[-1]} is outside episode {e} "
                             f"of the demo ({int(demo.episode_lengths[e])} steps)")
        if demo.meta["seeds"][e] is None:
            raise ValueError(f"episode {e} of the demo has no reset seed, so it cannot be replayed")
    if not wanted:
        return {}
    env = _rendering_env(demo)
    frames: dict[tuple[int, int], np.ndarray] = {}
    try:
        for e, ts in sorted(wanted.items()):
            ep = demo.episode(e)
            pending = set(ts)
            env.reset(seed=ep.seed)
            for t in range(ts[-1] + 1):
                if t in pending:
                    frames[(e, t)] = _rgb_frame(env.render(), demo.env_id)
                if t == ts[-1]:
                    break
                _, reward, terminated, truncated, _ = env.step(int(ep.actions[t]))
                divergence = _compare_step(replace(ep, observations=None), t, None,
                                           reward, terminated, truncated)
                if divergence is not None:
                    raise DemoReplayError(
                        f"replay of episode {e} (seed {ep.seed}) diverged at step {t} (action "
                        f"{int(ep.actions[t])}): {divergence}", episode=e, step=t)
    finally:
        env.close()
    return frames


def _rendering_env(demo: Demo) -> gym.Env:
    """The demo's env as `replay` makes it, rendering RGB frames; a `ValueError` naming the env
    and the problem when it cannot."""
    if demo.env_id is None:
        raise ValueError("this demo has no env id (it was recorded on an env not made by "
                         "gym.make), so its frames cannot be rendered by replaying it")
    kwargs = demo.env_kwargs
    if demo.meta.get("max_episode_steps") is not None:
        kwargs["max_episode_steps"] = demo.meta["max_episode_steps"]
    problem = f"{demo.env_id} cannot render RGB frames (render_mode='rgb_array')"
    # Gymnasium warns, then passes the mode on, when an env does not list it; the warning
    # would be a second line beside the one-line error, so it is caught and the modes read.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            env = make_env(demo.env_id, render_mode="rgb_array", **kwargs)
        except (TypeError, ValueError) as exc:
            message = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
            raise ValueError(f"{problem}: making it so fails: {message}") from None
    modes = list(env.metadata.get("render_modes") or [])
    if "rgb_array" not in modes:
        env.close()
        raise ValueError(f"{problem}: its render modes are {modes}")
    return env


def _rgb_frame(frame: Any, env_id: str | None) -> np.ndarray:
    """`env.render()`'s frame as an (H, W, 3) uint8 array; a `ValueError` for anything else."""
    array = np.asarray(frame) if frame is not None else None
    if array is None or array.ndim != 3 or array.shape[-1] not in (3, 4) or array.size == 0:
        what = "None" if array is None else f"an array of shape {array.shape}"
        raise ValueError(f"{env_id} cannot render RGB frames: render() with "
                         f"render_mode='rgb_array' returned {what}, not an (H, W, 3) image")
    if array.dtype != np.uint8:
        scale = 255.0 if array.dtype.kind == "f" and array.max(initial=0) <= 1.0 else 1.0
        array = np.clip(array * scale, 0, 255).astype(np.uint8)
    return np.ascontiguousarray(array[..., :3])


def _compare_step(
    ep: DemoEpisode, t: int, obs: Any, reward: float, terminated: bool, truncated: bool
) -> str | None:
    expected = float(ep.rewards[t])
    if not math.isclose(float(reward), expected, rel_tol=1e-6, abs_tol=1e-9):
        return f"reward {float(reward):g} in replay, {expected:g} in the demo"
    for name, got, want in (
        ("terminated", bool(terminated), bool(ep.terminated[t])),
        ("truncated", bool(truncated), bool(ep.truncated[t])),
    ):
        if got != want:
            return f"{name} is {got} in replay, {want} in the demo"
    if ep.observations is not None:
        want_obs = ep.observations[t + 1] if t + 1 < len(ep) else ep.final_observation
        return _same_obs(obs, want_obs)
    return None


def upgrade_demo(demo: Demo, wrap_env: Callable[[gym.Env], gym.Env] | None) -> Demo:
    """A version-1 demo as version 2: which steps were decisions, re-derived by replaying it.

    Each episode is reset with its seed through `wrap_env` (the preprocessing the demo was
    recorded under, e.g. the Atari evaluation stack of no-op start, `FireOnLifeLoss` and
    `FireReset`) with a `DecisionMarker` on top; the marker is then fed the demo's next
    recorded action until the episode ends. The steps the preprocessing takes itself (during a
    reset, or after a served life) come out as injected, exactly as a fresh recording of the
    episode would mark them. `wrap_env=None` (a demo recorded on the raw env, a human's) marks
    every step a decision.

    Raises:
        DemoReplayError: the replay through `wrap_env` diverged from the recorded actions,
            rewards or flags: the demo was not recorded under that preprocessing.
        ValueError: the demo has no env id or an episode has no seed.
    """
    if wrap_env is None:
        return Demo(actions=demo.actions, rewards=demo.rewards, terminated=demo.terminated,
                    truncated=demo.truncated, episode_lengths=demo.episode_lengths,
                    observations=demo.observations, final_observations=demo.final_observations,
                    meta=demo.meta, decisions=np.ones(len(demo), dtype=np.bool_))
    if demo.env_id is None:
        raise ValueError("this demo has no env id, so its env cannot be re-created to upgrade it")
    decisions: list[np.ndarray] = []
    recorded_under: list[str] = []
    for i in range(demo.num_episodes):
        ep = demo.episode(i)
        if ep.seed is None:
            raise ValueError(f"episode {i} of the demo has no reset seed, so it cannot be replayed")
        kwargs = demo.env_kwargs
        if demo.meta.get("max_episode_steps") is not None:
            kwargs["max_episode_steps"] = demo.meta["max_episode_steps"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            recorder = DemoRecorder(make_env(demo.env_id, **kwargs), record_observations=False)
        env = _agent_stack(recorder, wrap_env, None)
        recorded_under = env.wrappers_below
        try:
            env.reset(seed=ep.seed)
            checked = 0
            while True:
                steps = recorder._current.actions
                checked = _check_upgrade_prefix(ep, recorder._current, i, checked)
                if recorder._current.finished or len(steps) >= len(ep):
                    break
                _, _, terminated, truncated, _ = env.step(int(ep.actions[len(steps)]))
                if (terminated or truncated) and not recorder._current.finished:
                    break  # a wrapper ended the episode early: the length check says so
            _check_upgrade_prefix(ep, recorder._current, i, checked)
            if len(recorder._current.actions) != len(ep):
                raise DemoReplayError(
                    f"upgrade of episode {i} (seed {ep.seed}): the replay under "
                    f"{recorded_under} ended after {len(recorder._current.actions)} steps, the "
                    f"demo has {len(ep)}: it was not recorded under this preprocessing",
                    episode=i, step=len(recorder._current.actions),
                )
        finally:
            env.close()
        decisions.append(np.array(recorder._current.decisions, dtype=np.bool_))
    meta = {**demo.meta, "recorded_under": recorded_under}
    return Demo(actions=demo.actions, rewards=demo.rewards, terminated=demo.terminated,
                truncated=demo.truncated, episode_lengths=demo.episode_lengths,
                observations=demo.observations, final_observations=demo.final_observations,
                meta=meta, decisions=np.concatenate(decisions))


def _check_upgrade_prefix(ep: DemoEpisode, current: _Episode, i: int, start: int) -> int:
    """Raise DemoReplayError where the steps replayed since `start` differ from the episode's;
    return how many steps are checked."""
    for t in range(start, len(current.actions)):
        if t >= len(ep):
            raise DemoReplayError(
                f"upgrade of episode {i} (seed {ep.seed}): the replay took more steps than "
                f"the demo's {len(ep)}: it was not recorded under this preprocessing",
                episode=i, step=t,
            )
        problem = None
        if current.actions[t] != ep.actions[t]:
            problem = (f"the preprocessing took action {current.actions[t]} where the demo "
                       f"has {int(ep.actions[t])}")
        elif not math.isclose(current.rewards[t], float(ep.rewards[t]), rel_tol=1e-6,
                              abs_tol=1e-9):
            problem = (f"reward {current.rewards[t]:g} in replay, {float(ep.rewards[t]):g} "
                       "in the demo")
        elif (current.terminated[t], current.truncated[t]) != (bool(ep.terminated[t]),
                                                               bool(ep.truncated[t])):
            problem = "the episode's end flags differ"
        if problem is not None:
            raise DemoReplayError(
                f"upgrade of episode {i} (seed {ep.seed}) diverged at step {t}: {problem}; "
                "the demo was not recorded under this preprocessing",
                episode=i, step=t,
            )
    return len(current.actions)
