"""Imitation learning from one demonstration: the pieces `algos/rapl_sqil.py`, `algos/bc.py` and
`algos/gail.py` share (SPEC §5–6).

- **The demo in the agent's view.** A demo records the *primitive* env (for Atari: grey 210×160
  frames, every step including the no-op starts, the FIRE of a fire reset and the served lives
  that the preprocessing injects); the agent sees the preprocessed view (84×84, 4-frame stack)
  at its decisions only. `agent_view_states` replays the demo from its seeds (or takes its
  stored observations), keeps the frame before each *decision* and the final one, and passes
  them through the observation half of `preprocess` (grey, resize, frame stack). That is what
  the agent saw: the frame stack sits above the wrappers that inject steps, so it sees the
  frame after a no-op start as its reset frame (padded), and after a decision followed by
  injected steps the frame after them. Decision `i` of an episode lines up with state `i`.
- **The demo buffer `D_prim ∪ D_routine`** of RAPL-SQIL as index arrays over those states:
  `primitive_transitions` gives `(s_i, a_i, s_{i+1})` for every decision, `routine_transitions`
  gives `(s_i, n + k, s_{i+|ρ_k|})` for every occurrence of every routine `ρ_k` of the library
  (occurrences lie within runs of decisions: the miners never let one span an injected step).
- **SQIL's soft target** `R_sq + Γ·α·logsumexp(Q(s', ·)/α)` (`sqil_target`, `soft_value`), with
  `R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} r` and `Γ = γ^ℓ` from `sqil_reward_and_discount`.
- **`FrameReplayMemory`**, the agent's replay memory: one stream of decisions that stores each
  frame once and rebuilds frame stacks by index.
- **`evaluate_imitation`**, the evaluation of all three scripts: score and alignment of the
  agent's primitive action trajectory with the demo's, human-normalised score on Atari.

SQIL reward convention for a routine. A demo transition gets `r = 1` for *every primitive step*
it spans, so a routine occurrence of length ℓ gets `R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} = (1 − γ^ℓ)/(1 − γ)`
and discount `Γ = γ^ℓ`: exactly the discounted SQIL reward of the ℓ primitive demo transitions
it replaces, so a routine is worth what the chain of demo steps it stands for is worth (one
decision with `r = 1` per routine would instead make long routines look worse per step, and a
plain sum would make them look better than their chain). Agent transitions get `r = 0`, so
`R_sq = 0` and `Γ = γ^ℓ` with ℓ the executed length.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.wrappers import RecordEpisodeStatistics

from routine_gym.atomic import atomic_write_text
from routine_gym.demo import Demo, record_agent_demo, replay, shipped_demo_path
from routine_gym.envs import profile_for, same_env
from routine_gym.envs.factory import (
    default_env_kwargs,
    make_primitive_env,
    preprocess,
    preprocess_observation,
)
from routine_gym.library import RoutineLibrary
from routine_gym.metrics import alignment_score, human_normalized_score
from routine_gym.mining import demo_occurrences, make_proposer
from routine_gym.replay_memory import FrameReplayMemory
from routine_gym.returns import routine_reward_and_discount

__all__ = [
    "DemoTransitions",
    "FrameReplayMemory",
    "agent_view_states",
    "build_demo_transitions",
    "check_demo_env",
    "decision_steps",
    "evaluate_imitation",
    "load_demo",
    "load_routine_library",
    "primitive_transitions",
    "routine_transitions",
    "save_evaluation",
    "soft_value",
    "sqil_reward_and_discount",
    "sqil_target",
    "state_offsets",
]


# ---------------------------------------------------------------------------------------------
# The demo: loading and checking
# ---------------------------------------------------------------------------------------------


def load_demo(env_id: str, path: str | None = None) -> tuple[Demo, str]:
    """The demo to imitate: `path`, or the demo shipped in `demos/` for `env_id`.

    Raises:
        SystemExit: no path was given and no demo of `env_id` ships, with how to make one.
        ValueError: the file is not a demo, or a demo of another env.
    """
    path = path or shipped_demo_path(env_id)
    if path is None:
        raise SystemExit(
            f"no demo of {env_id} ships in demos/, so there is nothing to imitate.\n"
            f"Record one, then pass it with --demo:\n"
            f"  routine-gym record {env_id} --policy random --episodes 10 --out demo.npz\n"
            f"  python algos/rapl_a2c.py --env-id {env_id} --mode a2c --record-demo demo.npz"
            f"   # a trained A2C expert's demo, as in the paper"
        )
    return Demo.load(path, env_id=env_id), path


def _env_action_meanings(env: gym.Env) -> list[str] | None:
    getter = getattr(env.unwrapped, "get_action_meanings", None)
    return [str(m) for m in getter()] if callable(getter) else None


def check_demo_env(demo: Demo, env_id: str, env_kwargs: dict[str, Any] | None = None) -> int:
    """Check that `demo` was recorded on the primitive env of `env_id`; its number of actions.

    The demo's actions must be the env's primitive actions: the same `Discrete(n)` and, when
    both name their actions, the same action meanings (a full-action-set Qbert demo does not fit
    the minimal-action-set env, though both are `ALE/Qbert-v5`).

    Raises:
        ValueError: naming the demo's and the env's action spaces or meanings.
    """
    if not same_env(demo.env_id, env_id):
        raise ValueError(f"the demo was recorded on {demo.env_id}, not {env_id}")
    env = make_primitive_env(env_id, **(env_kwargs if env_kwargs is not None else demo.env_kwargs))
    try:
        space = env.action_space
        meanings = _env_action_meanings(env)
    finally:
        env.close()
    if not isinstance(space, spaces.Discrete):
        raise ValueError(f"imitation needs a Discrete action space; {env_id} has {space}")
    n = int(space.n)
    if demo.num_actions != n:
        raise ValueError(
            f"the demo's action space Discrete({demo.num_actions}) does not match {env_id}'s "
            f"Discrete({n}): record the demo on the same env (same action set)"
        )
    demo_meanings = list(demo.action_meanings)
    numeric = [str(a) for a in range(n)]
    if meanings is not None and demo_meanings != numeric and demo_meanings != meanings:
        raise ValueError(
            f"the demo's actions {demo_meanings} are not {env_id}'s actions {meanings}"
        )
    return n


def load_routine_library(
    demo: Demo,
    env_id: str,
    num_routines: int,
    *,
    routines_path: str | None = None,
    proposer: str = "full",
    length_weight: float = 0.1,
    alpha: int = 2,
    seed: int = 0,
    source: dict[str, Any] | None = None,
) -> RoutineLibrary | None:
    """The K routines of a run: mined from `demo`, or the best K of a saved library.

    K larger than what the miner finds (or the saved library holds) is not an error: the run
    uses every routine there is, with a warning. `num_routines=0` gives None (no routines).

    Raises:
        ValueError: `num_routines` is negative, or the saved library was mined on another env
            or holds actions the demo's env does not have.
    """
    if num_routines < 0:
        raise ValueError(f"num_routines needs to be ≥ 0, actual value: {num_routines}")
    if num_routines == 0:
        return None
    if routines_path is not None:
        library = RoutineLibrary.load(routines_path)
        mined_on = library.source.get("env_id")
        if not same_env(mined_on, env_id):
            raise ValueError(
                f"{routines_path} was mined from a demo of {mined_on}, not {env_id}"
            )
        if library.action_meanings is not None and list(library.action_meanings) != list(
            demo.action_meanings
        ):
            raise ValueError(
                f"{routines_path} has actions {list(library.action_meanings)}, "
                f"{env_id} has {list(demo.action_meanings)}: a library of another env"
            )
        bad = [r for r in library.routines if max(r) >= demo.num_actions]
        if bad:
            raise ValueError(
                f"{routines_path}: routine {bad[0]} uses an action outside {env_id}'s "
                f"Discrete({demo.num_actions})"
            )
        if len(library) < num_routines:
            warnings.warn(
                f"{routines_path} holds {len(library)} routine(s), fewer than the "
                f"{num_routines} asked for; using {len(library)}",
                stacklevel=2,
            )
        k = min(num_routines, len(library))
        return RoutineLibrary(
            routines=library.routines[:k],
            scores=library.scores[:k],
            frequencies=library.frequencies[:k],
            occurrences=library.occurrences[:k],
            params=library.params,
            source={**library.source, "path": routines_path},
            action_meanings=library.action_meanings,
        )
    miner = make_proposer(proposer, num_routines, length_weight, alpha, seed=seed)
    with warnings.catch_warnings():
        # The miner's own "only k routines survive" warning is re-issued below, naming the run.
        warnings.simplefilter("ignore")
        library = miner.mine(demo, source=source)
    if len(library) < num_routines:
        warnings.warn(
            f"the demo yields {len(library)} routine(s) after scoring and pruning, fewer than "
            f"--num-routines {num_routines}; using {len(library)}",
            stacklevel=2,
        )
    if len(library) == 0:
        return None
    return library


# ---------------------------------------------------------------------------------------------
# The demo in the agent's view
# ---------------------------------------------------------------------------------------------


class _FramePlayback(gym.Env):
    """Plays back recorded frames: `reset` gives the first, each `step` the next (any action)."""

    def __init__(self, frames: np.ndarray) -> None:
        self.frames = frames
        self.observation_space = spaces.Box(0, 255, frames.shape[1:], frames.dtype)
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


# ---------------------------------------------------------------------------------------------
# D_prim and D_routine
# ---------------------------------------------------------------------------------------------


def sqil_reward_and_discount(
    lengths: np.ndarray | Sequence[int], gamma: float, reward: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """SQIL's `R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} r` and `Γ = γ^ℓ` for transitions of ℓ primitive steps.

    `r` is the SQIL reward of every primitive step: 1 for the demo, 0 for the agent. This is
    RAPL-A2C's routine reward (`returns.routine_reward_and_discount`) of a constant reward.

    Example:
        >>> r, d = sqil_reward_and_discount([1, 3], gamma=0.5)
        >>> r.tolist(), d.tolist()  # 1; 1 + 0.5 + 0.25
        ([1.0, 1.75], [0.5, 0.125])
    """
    lengths = np.asarray(lengths, dtype=np.int64)
    if lengths.size and lengths.min() < 1:
        raise ValueError(f"lengths need to be ≥ 1, got {int(lengths.min())}")
    max_len = int(lengths.max()) if lengths.size else 1
    rewards = np.full((max_len, lengths.size), float(reward))
    return routine_reward_and_discount(rewards, lengths, gamma)


@dataclass(frozen=True)
class DemoTransitions:
    """Demo transitions `(s, a, R_sq, Γ, s', terminal)` as indices into one array of states.

    Attributes:
        states: `(S, *obs)` the demo's states in the agent's view (`agent_view_states`).
        state_index, next_state_index: `(N,)` rows of `states` for `s` and `s'`.
        actions: `(N,)` actions of the agent's action space (`n + k` for routine `k`).
        lengths: `(N,)` primitive steps each transition spans (1 for `D_prim`).
        rewards, discounts: `(N,)` SQIL's `R_sq` and `Γ` (`sqil_reward_and_discount`).
        terminated: `(N,)` the episode terminated within the transition: no bootstrap.
    """

    states: np.ndarray
    state_index: np.ndarray
    actions: np.ndarray
    lengths: np.ndarray
    rewards: np.ndarray
    discounts: np.ndarray
    next_state_index: np.ndarray
    terminated: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def is_routine(self) -> np.ndarray:
        """`(N,)` True for the `D_routine` transitions (those spanning more than one step)."""
        return self.lengths > 1

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """`batch_size` transitions drawn uniformly with replacement (keys as the attributes)."""
        i = rng.integers(0, len(self), size=batch_size)
        return {
            "obs": self.states[self.state_index[i]],
            "actions": self.actions[i],
            "lengths": self.lengths[i],
            "rewards": self.rewards[i],
            "discounts": self.discounts[i],
            "next_obs": self.states[self.next_state_index[i]],
            "terminated": self.terminated[i],
        }


def primitive_transitions(
    episode_lengths: Sequence[int] | np.ndarray,
    actions: np.ndarray,
    terminated: np.ndarray,
) -> dict[str, np.ndarray]:
    """`D_prim`: one transition `(s_t, a_t, s_{t+1})` per demo step, as state indices.

    Args:
        episode_lengths: steps per episode.
        actions, terminated: the demo's per-step arrays (episodes concatenated).

    Returns:
        `state_index`, `actions`, `lengths` (all 1), `next_state_index`, `terminated`, with
        state indices as laid out by `state_offsets`.

    Example:
        >>> d = primitive_transitions([2, 1], np.array([4, 5, 3]), np.array([0, 1, 0], bool))
        >>> d["state_index"].tolist(), d["next_state_index"].tolist()
        ([0, 1, 3], [1, 2, 4])
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    episode = np.repeat(np.arange(lengths.size), lengths)
    state_index = np.arange(int(lengths.sum()), dtype=np.int64) + episode  # + 1 final per episode
    return {
        "state_index": state_index,
        "actions": np.asarray(actions, dtype=np.int64),
        "lengths": np.ones(state_index.size, dtype=np.int64),
        "next_state_index": state_index + 1,
        "terminated": np.asarray(terminated, dtype=bool),
    }


def routine_transitions(
    episode_lengths: Sequence[int] | np.ndarray,
    actions: np.ndarray,
    terminated: np.ndarray,
    routines: Sequence[Sequence[int]],
    occurrences: Sequence[Sequence[tuple[int, int]]],
    num_primitives: int,
) -> dict[str, np.ndarray]:
    """`D_routine`: `(s_t, n + k, s_{t+|ρ_k|})` for every occurrence `(e, t)` of every routine.

    Args:
        episode_lengths, actions, terminated: the demo's, as in `primitive_transitions`.
        routines: the library's routines `ρ_k`.
        occurrences: for each routine, its `(episode, start)` occurrences in this demo
            (`RoutineLibrary.occurrences` of a library mined from it).
        num_primitives: `n`; routine `k` is action `n + k`.

    Returns:
        The arrays of `primitive_transitions`, with `lengths = |ρ_k|` and `terminated` set when
        the episode terminated on the routine's last step.

    Raises:
        ValueError: an occurrence leaves its episode or is not the routine's actions (the
            library was mined from another demo).

    Example:
        >>> d = routine_transitions([5], np.array([0, 2, 3, 2, 3]), np.zeros(5, bool),
        ...                         [(2, 3)], [((0, 1), (0, 3))], num_primitives=4)
        >>> d["state_index"].tolist(), d["actions"].tolist(), d["next_state_index"].tolist()
        ([1, 3], [4, 4], [3, 5])
    """
    lengths = np.asarray(episode_lengths, dtype=np.int64)
    actions = np.asarray(actions, dtype=np.int64)
    terminated = np.asarray(terminated, dtype=bool)
    if len(occurrences) != len(routines):
        raise ValueError(f"{len(occurrences)} occurrence lists for {len(routines)} routines")
    step_offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    offsets = state_offsets(lengths)
    rows: list[tuple[int, int, int, int, bool]] = []
    for k, (routine, occ) in enumerate(zip(routines, occurrences, strict=True)):
        routine = tuple(int(a) for a in routine)
        length = len(routine)
        for episode, start in occ:
            inside = 0 <= episode < lengths.size and 0 <= start <= lengths[episode] - length
            if not inside:
                raise ValueError(
                    f"occurrence (episode {episode}, step {start}) of routine {k} {routine} "
                    f"leaves the demo (episode lengths {lengths.tolist()}): a library mined "
                    "from another demo?"
                )
            first = step_offsets[episode] + start
            if tuple(actions[first : first + length].tolist()) != routine:
                raise ValueError(
                    f"the demo's actions at episode {episode}, step {start} are "
                    f"{actions[first : first + length].tolist()}, not routine {k} {list(routine)}:"
                    " a library mined from another demo?"
                )
            rows.append((
                offsets[episode] + start, num_primitives + k, length,
                offsets[episode] + start + length, bool(terminated[first + length - 1]),
            ))
    cols = list(zip(*rows, strict=True)) if rows else [(), (), (), (), ()]
    return {
        "state_index": np.array(cols[0], dtype=np.int64),
        "actions": np.array(cols[1], dtype=np.int64),
        "lengths": np.array(cols[2], dtype=np.int64),
        "next_state_index": np.array(cols[3], dtype=np.int64),
        "terminated": np.array(cols[4], dtype=bool),
    }


def _mined_from(library: RoutineLibrary, demo: Demo) -> bool:
    """Whether `library` records `demo` as its source (and so its occurrences are the demo's)."""
    source = library.source
    scores = list(source.get("scores", ()))
    return (
        bool(library.occurrences)
        and source.get("env_id") == demo.env_id
        and list(source.get("seeds", ())) == list(demo.seeds)
        and len(scores) == demo.num_episodes
        and bool(np.allclose(scores, demo.scores))
    )


def _decision_occurrences(
    library: RoutineLibrary, demo: Demo, steps: DecisionSteps
) -> tuple[tuple[tuple[int, int], ...], ...]:
    """Each routine's occurrences `(episode, decision number)` among `demo`'s decisions."""
    offsets = demo.episode_offsets
    occurrences = library.occurrences if _mined_from(library, demo) else None
    if occurrences is not None:
        for routine, occ in zip(library.routines, occurrences, strict=True):
            for e, t in occ:
                first = int(offsets[e]) + t if 0 <= e < demo.num_episodes else -1
                if not (0 <= first and first + len(routine) <= len(demo)
                        and demo.decisions[first : first + len(routine)].all()):
                    occurrences = None  # mined before the injected steps were marked
                    break
            if occurrences is None:
                break
    if occurrences is None:
        occurrences = demo_occurrences(demo, library.routines)
    return tuple(
        tuple((e, int(steps.index[int(offsets[e]) + t])) for e, t in occ) for occ in occurrences
    )


def build_demo_transitions(
    demo: Demo,
    states: np.ndarray,
    gamma: float,
    library: RoutineLibrary | None = None,
    num_primitives: int | None = None,
) -> DemoTransitions:
    """`D_prim ∪ D_routine` of `demo`'s decisions over its agent-view `states`, SQIL rewards.

    Only the demonstrator's decisions make transitions (`decision_steps`); an injected step
    makes none. Occurrences come from `library.occurrences` when the library was mined from
    this demo (its `source` names the demo's env, seeds and scores, and every occurrence lies
    on decisions; `routine_transitions` still checks them against the actions). A library mined
    elsewhere (`--routines LIB.json`, or from the demo before its injected steps were marked)
    is located in this demo's decisions afresh, as the miner would have.
    """
    steps = decision_steps(demo)
    expected = int(steps.lengths.sum() + demo.num_episodes)
    if len(states) != expected:
        raise ValueError(f"{len(states)} states for a demo that needs {expected}")
    n = demo.num_actions if num_primitives is None else num_primitives
    parts = [primitive_transitions(steps.lengths, steps.actions, steps.terminated)]
    if library is not None and len(library) > 0:
        occurrences = _decision_occurrences(library, demo, steps)
        parts.append(routine_transitions(steps.lengths, steps.actions, steps.terminated,
                                         library.routines, occurrences, n))
    merged = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    rewards, discounts = sqil_reward_and_discount(merged["lengths"], gamma, reward=1.0)
    return DemoTransitions(states=states, rewards=rewards, discounts=discounts, **merged)


# ---------------------------------------------------------------------------------------------
# The soft Q target
# ---------------------------------------------------------------------------------------------


def soft_value(q: torch.Tensor, temperature: float) -> torch.Tensor:
    """`V(s) = α·log Σ_a exp(Q(s, a)/α)`, the soft value of soft Q-learning (last axis)."""
    if temperature <= 0:
        raise ValueError(f"the temperature α needs to be > 0, actual value: {temperature}")
    return temperature * torch.logsumexp(q / temperature, dim=-1)


def sqil_target(
    rewards: torch.Tensor,
    discounts: torch.Tensor,
    terminated: torch.Tensor,
    next_q: torch.Tensor,
    temperature: float,
) -> torch.Tensor:
    """SQIL's target `R_sq + Γ·α·logsumexp(Q(s', ·)/α)`, with no bootstrap after termination.

    Args:
        rewards: `(B,)` `R_sq` of each transition (see `sqil_reward_and_discount`).
        discounts: `(B,)` `Γ = γ^ℓ`.
        terminated: `(B,)` bool; a terminated transition's target is its reward alone.
        next_q: `(B, A)` Q-values of the next state (the target network's).
        temperature: α.
    """
    bootstrap = soft_value(next_q, temperature) * (~terminated.bool()).to(next_q.dtype)
    return rewards + discounts * bootstrap


# ---------------------------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------------------------


def evaluate_imitation(
    env_id: str,
    policy: Callable[[np.ndarray], int],
    demo: Demo,
    episodes: int,
    seed: int,
    *,
    routines: RoutineLibrary | Sequence[Sequence[int]] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    max_steps: int | None = None,
) -> dict[str, Any]:
    """Run `policy` for `episodes` full episodes and compare its actions with the demo's.

    The env is the demo's primitive env under the agent's evaluation view (`preprocess` with
    `training=False`: no life-loss episodes, no reward clipping) and the routines, with a
    `DemoRecorder` under the preprocessing and a `DecisionMarker` over it, so each episode's
    decided *primitive* action trajectory — a routine decision counted as its executed
    primitive actions, the steps the preprocessing injects (Atari's no-op starts, FIRE, served
    lives) left out, as in the demo — is what gets aligned with the demo's best episode.
    `lengths` are the episodes' primitive steps, injected ones included.

    Args:
        env_id: the env.
        policy: maps an observation of the agent's view to an action of `Discrete(n + K)`.
        demo: the demonstration; its best episode is the reference trajectory `ι_d`.
        episodes: episodes to run, reset with seeds `seed, seed + 1, …`.
        seed: the first reset seed.
        routines: the routines the policy can choose (None: primitives only).
        env_kwargs: `gym.make` keyword arguments (default: the demo's).
        max_steps: cap on the primitive steps of an episode (None: the env's own limit).

    Returns:
        A JSON-able summary: per-episode `returns`, `lengths`, `alignments`; their
        `mean_*`/`std_*`; `human_normalized_score` (of the mean return, Atari only).
    """
    if episodes < 1:
        raise ValueError(f"episodes needs to be ≥ 1, actual value: {episodes}")
    kwargs = {**default_env_kwargs(env_id), **(demo.env_kwargs if env_kwargs is None
                                                else env_kwargs)}

    def wrap(env: gym.Env) -> gym.Env:
        return preprocess(RecordEpisodeStatistics(env), env_id, training=False)

    played = record_agent_demo(
        env_id, policy, num_episodes=episodes, seed=seed, env_kwargs=kwargs, keep="all",
        max_steps=max_steps, progress=False, wrap_env=wrap, routines=routines,
    )
    # ι_d and ι_t: the demonstrator's and the agent's decided primitive actions (a routine as
    # its executed primitives), without the steps the preprocessing injected into either.
    reference = demo.decision_actions()[demo.best_episode]
    trajectories = played.decision_actions()
    alignments = [alignment_score(reference, actions) for actions in trajectories]
    returns = played.scores.tolist()
    summary: dict[str, Any] = {
        "env_id": env_id,
        "episodes": episodes,
        "returns": returns,
        "lengths": played.episode_lengths.tolist(),
        "decisions": [len(a) for a in trajectories],
        "alignments": alignments,
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "mean_alignment": float(np.mean(alignments)),
        "std_alignment": float(np.std(alignments)),
        "demo_score": float(demo.scores[demo.best_episode]),
        "demo_length": len(reference),
        "env_kwargs": kwargs,
    }
    score_key = profile_for(env_id).score_key(env_id)
    if score_key is not None:
        try:
            summary["human_normalized_score"] = float(
                human_normalized_score(summary["mean_return"], score_key)
            )
        except ValueError:
            pass  # a game outside the published table
    return summary


def save_evaluation(summary: dict[str, Any], run_path: str, writer: Any, global_step: int) -> None:
    """Write `eval.json` (atomically) and the `eval/*` TensorBoard scalars; print one line."""
    atomic_write_text(os.path.join(run_path, "eval.json"), json.dumps(summary, indent=2) + "\n")
    writer.add_scalar("eval/mean_return", summary["mean_return"], global_step)
    writer.add_scalar("eval/mean_alignment", summary["mean_alignment"], global_step)
    writer.add_scalar("eval/std_alignment", summary["std_alignment"], global_step)
    line = (f"eval over {summary['episodes']} episodes: return {summary['mean_return']:.1f} ± "
            f"{summary['std_return']:.1f}, alignment {summary['mean_alignment']:.3f} ± "
            f"{summary['std_alignment']:.3f}")
    if "human_normalized_score" in summary:
        writer.add_scalar("eval/human_normalized_score", summary["human_normalized_score"],
                          global_step)
        line += f", human-normalised {summary['human_normalized_score']:.1%}"
    print(line, flush=True)
