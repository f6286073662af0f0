"""The demo in the agent's view: the states the agent saw at the demonstrator's decisions.

A demo records the *primitive* env (for Atari: grey 210×160 frames, every step including the
no-op starts, the FIRE of a fire reset and the served lives that the preprocessing injects);
the agent sees the preprocessed view (84×84, 4-frame stack) at its decisions only.
`agent_view_states` replays the demo from its seeds (or takes its stored observations), keeps
the frame before each *decision* and the final one, and passes them through the observation
half of the env's preprocessing (`EnvProfile.observation_view`: grey, resize, frame stack).
That is what the agent saw: the frame stack sits above the wrappers that inject steps, so it
sees the frame after a no-op start as its reset frame (padded), and after a decision followed
by injected steps the frame after them. Decision `i` of an episode lines up with state `i`
(`state_offsets` of `decision_steps(demo).lengths` says where each episode starts).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from routine_gym.demo import Demo, replay
from routine_gym.envs.factory import preprocess_observation

__all__ = ["DecisionSteps", "agent_view_states", "decision_steps", "state_offsets"]


class _FramePlayback(gym.Env):
    """Plays back recorded frames: `reset` gives the first, each `step` the next (any action)."""

    def __init__(self, frames: np.ndarray) -> None:
        self.frames = frames
        if frames.dtype == np.bool_:
            low, high = 0, 1
        elif frames.dtype.kind in "iu":
            low, high = np.iinfo(frames.dtype).min, np.iinfo(frames.dtype).max
        else:
            low, high = -np.inf, np.inf
        self.observation_space = spaces.Box(low, high, frames.shape[1:], frames.dtype)
        self.action_space = spaces.Discrete(1)
        self._t = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._t = 0
        return self.frames[0], {}

    def step(self, action: Any):
        self._t += 1
        return self.frames[self._t], 0.0, False, False, {}


def state_offsets(episode_lengths: Sequence[int] | np.ndarray) -> np.ndarray:
    """Where each episode's states start in the array of `agent_view_states`.

    Episode `e` of `T_e` steps has `T_e + 1` states (before each action, then the final one),
    so its state `t` is at `state_offsets(lengths)[e] + t`.

    Example:
        >>> state_offsets([3, 2]).tolist()
        [0, 4]
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(lengths + 1)[:-1]]).astype(np.int64)


@dataclass(frozen=True)
class DecisionSteps:
    """A demo's decisions, the steps imitation learns from, with injected steps left out.

    Attributes:
        lengths: `(E,)` decisions of each episode, `D_e`.
        actions: `(Σ D_e,)` the decided actions, episodes concatenated.
        terminated: `(Σ D_e,)` the episode terminated at the decision's step or at a step
            injected after it (before the next decision).
        index: `(T,)` each step's decision number within its episode, −1 for an injected step.
    """

    lengths: np.ndarray
    actions: np.ndarray
    terminated: np.ndarray
    index: np.ndarray


def decision_steps(demo: Demo) -> DecisionSteps:
    """The decided steps of `demo` (see `DecisionSteps`).

    Example:
        >>> demo = Demo(actions=np.array([0, 2, 3, 0, 4]), rewards=np.zeros(5),
        ...             terminated=np.array([0, 0, 0, 0, 1], bool), truncated=np.zeros(5, bool),
        ...             episode_lengths=np.array([5]),
        ...             decisions=np.array([0, 1, 1, 0, 1], bool))
        >>> d = decision_steps(demo)
        >>> d.lengths.tolist(), d.actions.tolist(), d.index.tolist()
        ([3], [2, 3, 4], [-1, 0, 1, -1, 2])
    """
    decided = demo.decisions
    episode = np.repeat(np.arange(demo.num_episodes), demo.episode_lengths)
    lengths = np.bincount(episode[decided], minlength=demo.num_episodes).astype(np.int64)
    # Decision number within the episode: a running count of decisions minus the episode's start.
    running = np.cumsum(decided) - 1
    before = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    index = np.where(decided, running - before[episode], -1).astype(np.int64)
    # A termination on an injected step belongs to the decision before it.
    owner = np.maximum.accumulate(np.where(decided, np.arange(len(demo)), -1))
    terminated = np.zeros(int(lengths.sum()), dtype=bool)
    ends = demo.terminated & (owner >= 0) & (episode[np.maximum(owner, 0)] == episode)
    terminated[running[owner[ends]]] = True
    return DecisionSteps(lengths=lengths, actions=demo.actions[decided], terminated=terminated,
                         index=index)


def agent_view_states(demo: Demo, env_id: str) -> np.ndarray:
    """The demo's states as the agent saw them: `(Σ_e (D_e + 1), *agent_obs_shape)`.

    Episode `e` contributes the state before each of its `D_e` decisions and the state after
    its last step, at `state_offsets(decision_steps(demo).lengths)[e]`; injected steps have no
    state of their own (the agent never saw one). A demo without observations (the shipped
    ones) is replayed from its seeds in its env; the replay checks every reward and flag.
    Atari frames go through grey/resize/stack as in `preprocess` (see the module docstring);
    other envs' observations are used as they are.

    Raises:
        ValueError: the demo stores no observations and cannot be replayed (no seeds, or no env
            id), naming the remedy.
        routine_gym.demo.DemoReplayError: the replay diverged from the demo.
    """
    source = demo
    if not demo.has_observations:
        if demo.env_id is None or any(s is None for s in demo.seeds):
            raise ValueError(
                "the demo stores no observations and cannot be replayed (it has no env id or "
                "no reset seeds), so there are no demo states to learn from; record it with "
                "observations (DemoRecorder(..., record_observations=True)) or with seeds"
            )
        source = replay(demo, record_observations=True).demo
    states = []
    for e in range(source.num_episodes):
        episode = source.episode(e)
        decided = demo.episode(e).decisions
        frames = np.concatenate([episode.observations[decided], episode.final_observation[None]])
        playback = _FramePlayback(frames)
        view = preprocess_observation(playback, env_id)
        if view is playback:  # the agent sees the env's observations as they are
            states.append(frames)
            continue
        obs, _ = view.reset()
        stacked = [obs]
        for _ in range(len(frames) - 1):
            obs = view.step(0)[0]
            stacked.append(obs)
        states.append(np.stack(stacked))
    return np.concatenate(states)
