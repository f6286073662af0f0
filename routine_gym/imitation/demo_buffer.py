"""The demo buffer: RAPL-SQIL's `D_prim ∪ D_routine`, and the (state, action) pairs of BC and GAIL.

Both index the demo's states in the agent's view (`routine_gym.imitation.agent_view`), one per
decision of the demonstrator plus each episode's final state; injected steps make no
transition.

- `primitive_transitions` gives `D_prim`, `(s_i, a_i, s_{i+1})` for every decision;
  `routine_transitions` gives `D_routine`, `(s_i, n + k, s_{i+|ρ_k|})` for every occurrence of
  every routine `ρ_k` of the library (occurrences lie within runs of decisions: the miners never
  let one span an injected step); `build_demo_transitions` joins them with SQIL's rewards.
- `demo_pairs` gives the `(s_i, a_i)` pairs of every decision that BC fits and GAIL's
  discriminator reads.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from routine_gym.demo import Demo
from routine_gym.imitation.agent_view import DecisionSteps, decision_steps, state_offsets
from routine_gym.imitation.soft_q import sqil_reward_and_discount
from routine_gym.library import RoutineLibrary
from routine_gym.mining import demo_occurrences

__all__ = [
    "DemoPairs",
    "DemoTransitions",
    "build_demo_transitions",
    "demo_pairs",
    "primitive_transitions",
    "routine_transitions",
]


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
    """Whether `library` records `demo` as its source (and so its occurrences are the demo's)
    and keeps every one of them (a library of a repetitive demo keeps only the first ones)."""
    source = library.source
    scores = list(source.get("scores", ()))
    return (
        library.occurrences_complete
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


@dataclass(frozen=True)
class DemoPairs:
    """The demonstrator's `(state, action)` pairs, one per decision (what BC and GAIL learn from).

    Attributes:
        states: `(S, *obs)` the demo's states in the agent's view (`agent_view_states`).
        state_index: `(N,)` the row of `states` before each decision.
        actions: `(N,)` the decided primitive actions.
    """

    states: np.ndarray
    state_index: np.ndarray
    actions: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def observations(self) -> np.ndarray:
        """`(N, *obs)` the state before each decision."""
        return self.states[self.state_index]


def demo_pairs(demo: Demo, states: np.ndarray) -> DemoPairs:
    """The `(s_i, a_i)` pair of every decision of `demo`, over its agent-view `states`.

    Example:
        >>> demo = Demo(actions=np.array([0, 2, 3]), rewards=np.zeros(3),
        ...             terminated=np.array([0, 0, 1], bool), truncated=np.zeros(3, bool),
        ...             episode_lengths=np.array([3]), decisions=np.array([0, 1, 1], bool))
        >>> pairs = demo_pairs(demo, np.zeros((3, 1)))  # 2 decisions + the final state
        >>> pairs.state_index.tolist(), pairs.actions.tolist()
        ([0, 1], [2, 3])
    """
    steps = decision_steps(demo)
    expected = int(steps.lengths.sum() + demo.num_episodes)
    if len(states) != expected:
        raise ValueError(f"{len(states)} states for a demo that needs {expected}")
    d_prim = primitive_transitions(steps.lengths, steps.actions, steps.terminated)
    return DemoPairs(states=states, state_index=d_prim["state_index"], actions=d_prim["actions"])
