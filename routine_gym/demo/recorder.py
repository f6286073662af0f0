"""Recording: `DemoRecorder` turns the episodes of a discrete-action env into a `Demo`.

What a demo records is the *raw* env, made by `gym.make(env_id, **env_kwargs)`, with its
primitive actions: put `DemoRecorder` directly over that env. An agent trained behind
preprocessing wrappers (frame skip, frame stack, resizing, ...) is recorded by placing the
recorder *under* the preprocessing: `AtariPreprocessing(DemoRecorder(gym.make(...)))`, or
`record_agent_demo(..., wrap_env=...)`; the recorder then sees every primitive step.
Which recorded steps the demonstrator decided and which a wrapper injected is told by a
`DecisionMarker` at the agent-facing top of the stack (see `routine_gym.demo.format`).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.demo.format import Demo
from routine_gym.demo.npz import _to_json

# Seeds drawn for an unseeded reset stay below 2**31 so that every env accepts them.
_MAX_DRAWN_SEED = 2**31 - 1


def _as_action(action: Any) -> int:
    """An integer action id from an int, a NumPy integer, a 1-element array or tensor."""
    arr = np.asarray(action)
    if arr.size != 1 or arr.dtype.kind not in "iu":
        raise TypeError(f"a discrete action must be a single integer, got {action!r}")
    return int(arr.reshape(()))


def _action_meanings(env: gym.Env, n: int) -> list[str]:
    getter = getattr(env.unwrapped, "get_action_meanings", None)
    if getter is not None:
        try:
            meanings = [str(m) for m in getter()]
        except Exception:  # a broken helper should not stop a recording
            meanings = []
        if len(meanings) == n:
            return meanings
    return [str(a) for a in range(n)]


def _env_metadata(env: gym.Env) -> dict[str, Any]:
    """The meta keys that describe `env`: id, JSON-able kwargs, time limit, actions."""
    n = int(env.action_space.n)
    meta: dict[str, Any] = {
        "env_id": None,
        "env_kwargs": {},
        "max_episode_steps": None,
        "num_actions": n,
        "action_meanings": _action_meanings(env, n),
    }
    spec = env.spec
    if spec is None:
        return meta
    if spec.additional_wrappers:
        names = [w.name for w in spec.additional_wrappers]
        meta["wrappers_below_recorder"] = names
        warnings.warn(
            f"DemoRecorder wraps {spec.id} behind the wrappers {names}; a demo records the raw "
            "env made by gym.make, and replay re-creates only that. Put the recorder directly "
            "over gym.make(...) and any preprocessing over the recorder.",
            stacklevel=3,
        )
    kwargs = {}
    for key, value in spec.kwargs.items():
        if key == "render_mode":  # rendering does not change the dynamics; replay runs headless
            continue
        try:
            json.dumps(_to_json(value))
        except (TypeError, ValueError):
            warnings.warn(
                f"env kwarg {key}={value!r} of {spec.id} is not JSON-serialisable and is left "
                "out of the demo; replay will make the env without it",
                stacklevel=3,
            )
            continue
        kwargs[key] = value
    meta.update(env_id=spec.id, env_kwargs=kwargs, max_episode_steps=spec.max_episode_steps)
    return meta


class _Episode:
    """The growing record of one episode inside `DemoRecorder`."""

    def __init__(self, seed: int, first_obs: np.ndarray | None) -> None:
        self.seed = seed
        self.actions: list[int] = []
        self.rewards: list[float] = []
        self.terminated: list[bool] = []
        self.truncated: list[bool] = []
        self.decisions: list[bool] = []
        self.observations: list[np.ndarray] | None = None if first_obs is None else [first_obs]
        self.finished = False

    @property
    def score(self) -> float:
        return float(sum(self.rewards))


class DemoRecorder(gym.Wrapper):
    """Record every transition of every episode of a discrete-action env as a `Demo`.

    Put it directly over the env made by `gym.make(env_id, **kwargs)`: the id, kwargs, time
    limit and action meanings come from that env's spec, so `replay` can re-create it. An env
    not made by `gym.make` (no spec) records too, but its demo can only be replayed on an env
    passed explicitly. Preprocessing for an agent goes *over* the recorder.

    Each step is recorded as a decision of the demonstrator or as injected by a wrapper (see
    `routine_gym.demo.format`): put `DecisionMarker` at the agent-facing top of the stack (below a
    `RoutineActionWrapper`, whose routine steps are each a decision); with no marker every step
    is a decision.

    Each `reset` starts an episode and records its seed. A reset without a seed gets one from
    the recorder (`seed + number of completed episodes` when `seed` is given, else a fresh
    random one) and passes it to the env, so every recorded episode can be replayed. An
    episode ends when a step is terminated or truncated; an episode abandoned by a reset
    before it ended is dropped, and `demo(include_unfinished=True)` adds the one in progress.
    Stepping before the first reset or after the episode ended raises `RuntimeError`.

    Example:
        >>> import gymnasium as gym
        >>> recorder = DemoRecorder(gym.make("CartPole-v1"), record_observations=False)
        >>> _ = recorder.reset(seed=3)
        >>> done = False
        >>> while not done:
        ...     _, _, terminated, truncated, _ = recorder.step(1)
        ...     done = terminated or truncated
        >>> demo = recorder.demo()
        >>> demo.num_episodes, demo.seeds, demo.env_id
        (1, (3,), 'CartPole-v1')

    Args:
        env: the env to record; its action space must be `Discrete(n)` (start 0).
        record_observations: keep the observation before each action and the final one.
            Off, only actions, rewards and flags are kept (enough to replay).
        seed: base of the seeds given to resets called without one; None draws random ones.
        source: `meta["source"]` of the demos made (`"agent"`, `"human"`, ...).
    """

    def __init__(
        self,
        env: gym.Env,
        record_observations: bool = True,
        seed: int | None = None,
        source: str = "unknown",
    ) -> None:
        if not isinstance(env.action_space, gym.spaces.Discrete):
            raise TypeError(
                f"DemoRecorder records discrete actions; the env's action space is "
                f"{env.action_space}"
            )
        if int(env.action_space.start) != 0:
            raise ValueError(
                f"DemoRecorder needs a Discrete action space starting at 0, "
                f"actual start: {env.action_space.start}"
            )
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
            raise ValueError(f"seed must be a non-negative integer or None, actual value: {seed!r}")
        super().__init__(env)
        self.record_observations = bool(record_observations)
        self.base_seed = seed
        self.source = source
        self._env_meta = _env_metadata(env)
        self._num_actions = int(env.action_space.n)
        self._seed_rng = np.random.default_rng()
        self._episodes: list[_Episode] = []
        self._current: _Episode | None = None
        self._marker: DecisionMarker | None = None
        self._decision_pending = False

    @property
    def num_episodes(self) -> int:
        """Number of completed (terminated or truncated) episodes recorded so far."""
        return len(self._episodes)

    @property
    def episode_scores(self) -> list[float]:
        """Undiscounted return of each completed episode."""
        return [e.score for e in self._episodes]

    def _observation(self, obs: Any) -> np.ndarray:
        arr = np.array(obs, copy=True)  # a copy: some envs reuse their observation buffer
        if arr.dtype.hasobject:
            raise TypeError(
                f"record_observations=True needs array observations, got {type(obs).__name__}; "
                "use record_observations=False (replay regenerates them)"
            )
        return arr

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the env with `seed` (or one the recorder chooses) and start an episode."""
        if seed is None:
            if self.base_seed is not None:
                seed = self.base_seed + len(self._episodes)
            else:
                seed = int(self._seed_rng.integers(_MAX_DRAWN_SEED))
        obs, info = self.env.reset(seed=seed, options=options)
        first = self._observation(obs) if self.record_observations else None
        self._current = _Episode(int(seed), first)
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Step the env and record the transition."""
        episode = self._current
        if episode is None:
            raise RuntimeError("DemoRecorder.step() called before reset()")
        if episode.finished:
            raise RuntimeError("DemoRecorder.step() called after the episode ended; call reset()")
        a = _as_action(action)
        if not 0 <= a < self._num_actions:
            raise ValueError(
                f"action {a} is outside the action space Discrete({self._num_actions})"
            )
        if self._marker is None:
            decision = True  # the recorder is the top of the stack: its caller decides
        else:  # the one step the marker forwards is the decision; the rest are injected
            decision, self._decision_pending = self._decision_pending, False
        obs, reward, terminated, truncated, info = self.env.step(action)
        episode.actions.append(a)
        episode.decisions.append(decision)
        episode.rewards.append(float(reward))
        episode.terminated.append(bool(terminated))
        episode.truncated.append(bool(truncated))
        if episode.observations is not None:
            episode.observations.append(self._observation(obs))
        if terminated or truncated:
            episode.finished = True
            self._episodes.append(episode)
        return obs, reward, terminated, truncated, info

    def _keep_unfinished(self) -> None:
        """Count the episode in progress (if it has steps) as completed, as it stands."""
        episode = self._current
        if episode is not None and not episode.finished and episode.actions:
            episode.finished = True
            self._episodes.append(episode)

    def clear(self) -> None:
        """Forget the completed episodes; an episode in progress goes on being recorded."""
        self._episodes = []

    def demo(
        self,
        episodes: int | Sequence[int] | None = None,
        include_unfinished: bool = False,
        meta: dict[str, Any] | None = None,
    ) -> Demo:
        """A `Demo` of the completed episodes (or of those at the indices `episodes`).

        Args:
            episodes: indices into the completed episodes, None for all; `demo().best()`
                gives the best one.
            include_unfinished: also include the episode in progress, if it has steps.
            meta: extra `meta` entries (provenance: the policy, a note, ...).
        """
        recorded = list(self._episodes)
        current = self._current
        if include_unfinished and current is not None and not current.finished:
            if current.actions:
                recorded.append(current)
        if not recorded:
            raise ValueError("DemoRecorder has no completed episode to make a demo of")
        observations = final = None
        if self.record_observations and all(e.observations is not None for e in recorded):
            observations = np.stack([o for e in recorded for o in e.observations[:-1]])
            final = np.stack([e.observations[-1] for e in recorded])
        demo = Demo(
            actions=np.array([a for e in recorded for a in e.actions], dtype=np.int64),
            rewards=np.array([r for e in recorded for r in e.rewards], dtype=np.float64),
            terminated=np.array([f for e in recorded for f in e.terminated], dtype=np.bool_),
            truncated=np.array([f for e in recorded for f in e.truncated], dtype=np.bool_),
            episode_lengths=np.array([len(e.actions) for e in recorded], dtype=np.int64),
            observations=observations,
            final_observations=final,
            meta={
                **self._env_meta,
                "seeds": [e.seed for e in recorded],
                "source": self.source,
                **({} if self._marker is None
                   else {"recorded_under": self._marker.wrappers_below}),
                **(meta or {}),
            },
            decisions=np.array([d for e in recorded for d in e.decisions], dtype=np.bool_),
        )
        if episodes is not None:
            demo = demo.select(episodes)
        return demo

    def save(
        self,
        path: str | os.PathLike,
        episodes: int | Sequence[int] | None = None,
        include_observations: bool = True,
        include_unfinished: bool = False,
        meta: dict[str, Any] | None = None,
    ) -> Demo:
        """Save `demo(episodes, include_unfinished, meta)` to `path` and return it."""
        demo = self.demo(episodes, include_unfinished=include_unfinished, meta=meta)
        demo.save(path, include_observations=include_observations)
        return demo


class DecisionMarker(gym.Wrapper):
    """The agent-facing top of a recorded stack: the step it forwards is a decision.

    A `DemoRecorder` under preprocessing sees more primitive steps than the agent takes: the
    no-ops of a no-op start, the FIRE of a fire reset, the NOOP and FIRE that serve a new life.
    This wrapper tells it which is which. Of the primitive steps the recorder sees during one
    call of `DecisionMarker.step`, the first is the agent's action (a decision); any other step
    (one taken inside a `reset`, or a further step a wrapper takes in the same call) was
    injected by a wrapper. Any wrapper a user adds between the two is covered, with no list
    of known ones. Put it directly under a `RoutineActionWrapper`, so that each primitive of a
    routine the agent chose is a decision; `record_agent_demo` builds that stack.

    Example:
        >>> import gymnasium as gym, routine_gym
        >>> from routine_gym.envs.atari import FireReset
        >>> routine_gym.register_envs()  # ALE's ids, for a gym.make of your own
        >>> recorder = DemoRecorder(gym.make("ALE/Breakout-v5", frameskip=4),
        ...                         record_observations=False)
        >>> env = DecisionMarker(FireReset(recorder))
        >>> _ = env.reset(seed=0)        # FireReset presses FIRE: injected
        >>> _ = env.step(3)              # the agent's LEFT: a decision
        >>> recorder.demo(include_unfinished=True).decisions.tolist()
        [False, True]

    Args:
        env: the stack to mark, with a `DemoRecorder` somewhere below it.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        below, inner = [], env
        while not isinstance(inner, DemoRecorder):
            if not isinstance(inner, gym.Wrapper):
                raise ValueError(
                    "DecisionMarker needs a DemoRecorder below it in the wrapper stack; "
                    f"found none under {type(env).__name__}"
                )
            below.append(type(inner).__name__)
            inner = inner.env
        if inner._marker is not None and inner._marker is not self:
            raise ValueError("this DemoRecorder already has a DecisionMarker over it")
        self.recorder: DemoRecorder = inner
        #: The wrapper classes between the recorder and this marker, innermost first.
        self.wrappers_below: list[str] = below[::-1]
        inner._marker = self

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self.recorder._decision_pending = False  # every step of a reset is injected
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any):
        self.recorder._decision_pending = True
        try:
            return self.env.step(action)
        finally:
            self.recorder._decision_pending = False


def _agent_stack(
    recorder: DemoRecorder,
    wrap_env: Callable[[gym.Env], gym.Env] | None,
    routines: Sequence[Sequence[int]] | None,
    stop_rule: Any = None,
) -> gym.Env:
    """`RoutineActionWrapper(DecisionMarker(wrap_env(recorder)))`, checked; the routine
    wrapper asks `stop_rule` before each inner step (`set_stop_rule`) when one is given."""
    from routine_gym.wrapper import RoutineActionWrapper

    has_routines = routines is not None and len(routines) > 0
    if stop_rule is not None and not has_routines:
        raise ValueError("a stop_rule stops routines: give the routines too")
    env = wrap_env(recorder) if wrap_env is not None else recorder
    inner = env
    while isinstance(inner, gym.Wrapper) and inner is not recorder:
        if isinstance(inner, RoutineActionWrapper):
            raise ValueError(
                "wrap_env returned a stack with a RoutineActionWrapper; pass the routines as "
                "record_agent_demo(..., routines=...) so each routine step counts as a decision"
            )
        inner = inner.env
    env = DecisionMarker(env)
    if has_routines:
        env = RoutineActionWrapper(env, routines, record_observations=False)
        env.set_stop_rule(stop_rule)
    return env
