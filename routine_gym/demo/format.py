"""The demonstration and its file: `Demo`, its episodes, and how it is saved and loaded.

A `Demo` is one or more episodes of a discrete-action env, played by an agent or a human, with
the seed that reset each episode. The env's dynamics are deterministic given the reset seed and
the actions (ALE, sticky actions included, and Procgen are), so the actions and seeds alone
reproduce a demo exactly: `replay` re-runs them and checks every reward, flag and (when stored)
observation. Shipped demos therefore leave the observations out.

Decisions and injected steps
----------------------------
Not every recorded action is one the demonstrator chose. The agent's preprocessing also steps
the primitive env: Atari's random no-op start, the FIRE of a fire reset, the NOOP and FIRE
that serve a new life. Those steps are environment plumbing, not skill (a 25-step no-op start
alone would make `NOOP×4` a "most frequent routine"), so a demo marks each step as a
*decision* (the demonstrator's policy, a person's key, each primitive of a routine it chose)
or as *injected* (a wrapper below the agent took it). The recorder learns which is which from
the agent-facing top of the stack: a `DecisionMarker` there marks the one primitive step each
of its `step` calls forwards; every other step (those taken inside a `reset`, or a second
step a wrapper takes within the same call) is injected. A recorder with no marker over it is
the top itself, and every step is a decision. Everything that reads a demo's actions (the
miners, SQIL's demo buffer, BC and GAIL pairs, the alignment score) uses the decisions only,
and an injected step splits the sequence as an episode boundary does
(`Demo.decision_segments`).

The file a demo is saved to, its size limits and how it is read without trusting it are in
`routine_gym.demo.npz`.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.atomic import atomic_write_bytes
from routine_gym.demo.npz import DEMO_FORMAT, DEMO_VERSION, _to_json, read_demo_file


def _routine_gym_version() -> str:
    # importlib.metadata rather than `routine_gym.__version__`: no import cycle with __init__.
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("routine-gym")
    except PackageNotFoundError:
        return "unknown"


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# -- the demonstration -------------------------------------------------------------------


@dataclass(frozen=True)
class DemoEpisode:
    """One episode of a `Demo`: views into the demo's arrays, plus its seed and score."""

    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    observations: np.ndarray | None
    """(T_e, *obs): the observation before each action, or None."""
    final_observation: np.ndarray | None
    """The observation after the last action, or None."""
    seed: int | None
    score: float
    decisions: np.ndarray | None = None
    """(T_e,) bool: True where the demonstrator chose the action (None: all of them)."""

    def __len__(self) -> int:
        return len(self.actions)


@dataclass(frozen=True, eq=False)
class Demo:
    """Episodes of a discrete-action env: actions, rewards, flags, optional observations, meta.

    The layout and the `meta` keys are those of the file format (`routine_gym.demo.npz`). Arrays
    are converted to the documented dtypes and validated on construction; `meta` is completed
    with defaults (`num_actions` from the largest action, ids as action meanings, no seeds,
    source `"unknown"`), and `meta["scores"]` is always recomputed from `rewards`.

    Example:
        >>> import numpy as np
        >>> demo = Demo(
        ...     actions=np.array([1, 1, 0, 2, 2]), rewards=np.array([0.0, 1, 0, 0, 5]),
        ...     terminated=np.array([0, 0, 1, 0, 0], dtype=bool),
        ...     truncated=np.array([0, 0, 0, 0, 1], dtype=bool),
        ...     episode_lengths=np.array([3, 2]), meta={"seeds": [0, 1]},
        ... )
        >>> demo.num_episodes, len(demo), demo.scores.tolist(), demo.score
        (2, 5, [1.0, 5.0], 5.0)
        >>> [a.tolist() for a in demo.episode_actions()]
        [[1, 1, 0], [2, 2]]
    """

    actions: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    episode_lengths: np.ndarray
    observations: np.ndarray | None = None
    final_observations: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    decisions: np.ndarray | None = None
    """(T,) bool: True where the demonstrator chose the action; None makes every step one."""

    def __post_init__(self) -> None:
        set_ = object.__setattr__  # frozen: normalised values are written once, here
        actions = np.asarray(self.actions)
        if actions.ndim != 1:
            raise ValueError(f"actions must be 1-D, got shape {actions.shape}")
        if actions.size and actions.dtype.kind not in "iu":
            raise ValueError(f"actions must be integer action ids, got dtype {actions.dtype}")
        set_(self, "actions", actions.astype(np.int64, copy=False))
        num_steps = len(actions)
        set_(self, "rewards", self._float_array("rewards", self.rewards, num_steps))
        for name in ("terminated", "truncated"):
            set_(self, name, self._bool_array(name, getattr(self, name), num_steps))
        decisions = np.ones(num_steps, dtype=np.bool_) if self.decisions is None else (
            self._bool_array("decisions", self.decisions, num_steps))
        set_(self, "decisions", decisions)

        lengths = np.asarray(self.episode_lengths)
        if lengths.ndim != 1 or (lengths.size and lengths.dtype.kind not in "iu"):
            raise ValueError(
                f"episode_lengths must be a 1-D integer array, got shape {lengths.shape} "
                f"and dtype {lengths.dtype}"
            )
        lengths = lengths.astype(np.int64, copy=False)
        if len(lengths) == 0:
            raise ValueError("a demo needs at least one episode; episode_lengths is empty")
        if lengths.min() < 1:
            raise ValueError(f"every episode needs at least one step; episode_lengths={lengths}")
        if lengths.sum() != num_steps:
            raise ValueError(
                f"episode_lengths sum to {lengths.sum()} but there are {num_steps} actions"
            )
        set_(self, "episode_lengths", lengths)
        self._check_flags()
        self._check_observations()
        set_(self, "meta", self._complete_meta(dict(self.meta)))

    @staticmethod
    def _float_array(name: str, value: Any, num_steps: int) -> np.ndarray:
        arr = np.asarray(value)
        if arr.shape != (num_steps,):
            raise ValueError(f"{name} has shape {arr.shape}, expected ({num_steps},)")
        if arr.size and arr.dtype.kind not in "biuf":
            raise ValueError(f"{name} must be numeric, got dtype {arr.dtype}")
        return arr.astype(np.float64, copy=False)

    @staticmethod
    def _bool_array(name: str, value: Any, num_steps: int) -> np.ndarray:
        arr = np.asarray(value)
        if arr.shape != (num_steps,):
            raise ValueError(f"{name} has shape {arr.shape}, expected ({num_steps},)")
        if arr.dtype != np.bool_:
            if arr.size and (arr.dtype.kind not in "iu" or not np.isin(arr, (0, 1)).all()):
                raise ValueError(f"{name} must be booleans, got dtype {arr.dtype}")
            arr = arr.astype(np.bool_)
        return arr

    def _check_flags(self) -> None:
        ends = np.cumsum(self.episode_lengths) - 1
        done = self.terminated | self.truncated
        done[ends] = False
        if done.any():
            step = int(np.flatnonzero(done)[0])
            episode = int(np.searchsorted(ends, step))
            raise ValueError(
                f"step {step} (episode {episode}) is terminated or truncated but is not the "
                "last step of its episode: episode_lengths disagree with the flags"
            )

    def _check_observations(self) -> None:
        obs, final = self.observations, self.final_observations
        if obs is None and final is None:
            return
        if obs is None or final is None:
            raise ValueError(
                "observations and final_observations are stored together or not at all"
            )
        obs, final = np.asarray(obs), np.asarray(final)
        for name, arr, rows in (
            ("observations", obs, len(self.actions)),
            ("final_observations", final, len(self.episode_lengths)),
        ):
            if arr.dtype.hasobject:
                raise ValueError(f"{name} must be a numeric array, got dtype {arr.dtype}")
            if arr.ndim == 0 or arr.shape[0] != rows:
                raise ValueError(f"{name} has shape {arr.shape}, expected {rows} rows")
        if obs.shape[1:] != final.shape[1:] or obs.dtype != final.dtype:
            raise ValueError(
                f"observations {obs.dtype}{list(obs.shape[1:])} and final_observations "
                f"{final.dtype}{list(final.shape[1:])} disagree"
            )
        object.__setattr__(self, "observations", obs)
        object.__setattr__(self, "final_observations", final)

    def _complete_meta(self, meta: dict[str, Any]) -> dict[str, Any]:
        num_episodes = len(self.episode_lengths)
        max_action = int(self.actions.max()) if len(self.actions) else -1
        num_actions = meta.get("num_actions")
        if num_actions is None:
            num_actions = max_action + 1
        if isinstance(num_actions, bool) or not isinstance(num_actions, int | np.integer):
            raise ValueError(f"meta num_actions must be an integer, got {num_actions!r}")
        num_actions = int(num_actions)
        if self.actions.size and self.actions.min() < 0:
            raise ValueError(f"actions must be ≥ 0, got {int(self.actions.min())}")
        if max_action >= num_actions:
            step = int(np.argmax(self.actions >= num_actions))
            raise ValueError(
                f"action {max_action} (first out-of-range at step {step}) is outside the "
                f"action space Discrete({num_actions})"
            )
        meanings = meta.get("action_meanings")
        if meanings is None:
            meanings = [str(a) for a in range(num_actions)]
        meanings = [str(m) for m in meanings]
        if len(meanings) != num_actions:
            raise ValueError(
                f"meta has {len(meanings)} action meanings for {num_actions} actions"
            )
        seeds = meta.get("seeds")
        if seeds is None:
            seeds = [None] * num_episodes
        seeds = list(seeds)
        if len(seeds) != num_episodes:
            raise ValueError(f"meta has {len(seeds)} seeds for {num_episodes} episodes")
        for s in seeds:
            if s is not None and (isinstance(s, bool) or not isinstance(s, int | np.integer)):
                raise ValueError(f"seeds must be integers or None, got {s!r}")
        env_id = meta.get("env_id")
        if env_id is not None and not isinstance(env_id, str):
            raise ValueError(f"meta env_id must be a string or None, got {env_id!r}")
        env_kwargs = meta.get("env_kwargs") or {}
        if not isinstance(env_kwargs, dict):
            raise ValueError(f"meta env_kwargs must be a dict, got {env_kwargs!r}")
        completed = {
            "format": DEMO_FORMAT,
            "version": DEMO_VERSION,
            "env_id": env_id,
            "env_kwargs": env_kwargs,
            "max_episode_steps": meta.get("max_episode_steps"),
            "seeds": [None if s is None else int(s) for s in seeds],
            "num_actions": num_actions,
            "action_meanings": meanings,
            "scores": [float(s) for s in self._episode_scores()],
            "source": str(meta.get("source", "unknown")),
            "created": str(meta.get("created") or _now()),
            "routine_gym_version": str(meta.get("routine_gym_version") or _routine_gym_version()),
        }
        extra = {k: v for k, v in meta.items() if k not in completed}
        completed.update(extra)
        try:  # fail here, not halfway through save()
            json.dumps(_to_json(completed))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"meta must be JSON-serialisable: {exc}") from exc
        return completed

    def _episode_scores(self) -> np.ndarray:
        return np.add.reduceat(self.rewards, self.episode_offsets)

    # -- accessors -----------------------------------------------------------------------

    def __len__(self) -> int:
        """Total number of steps (actions) over all episodes."""
        return len(self.actions)

    def __repr__(self) -> str:
        scores = ", ".join(f"{s:g}" for s in self.scores[:5])
        more = ", ..." if self.num_episodes > 5 else ""
        return (
            f"Demo(env_id={self.env_id!r}, episodes={self.num_episodes}, steps={len(self)}, "
            f"scores=[{scores}{more}], source={self.meta['source']!r}, "
            f"observations={self.has_observations})"
        )

    @property
    def num_episodes(self) -> int:
        return len(self.episode_lengths)

    @property
    def episode_offsets(self) -> np.ndarray:
        """Index of each episode's first step in the concatenated arrays."""
        return np.cumsum(self.episode_lengths) - self.episode_lengths

    @property
    def num_actions(self) -> int:
        return int(self.meta["num_actions"])

    @property
    def action_meanings(self) -> tuple[str, ...]:
        return tuple(self.meta["action_meanings"])

    @property
    def env_id(self) -> str | None:
        return self.meta["env_id"]

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return dict(self.meta["env_kwargs"])

    @property
    def seeds(self) -> tuple[int | None, ...]:
        return tuple(self.meta["seeds"])

    @property
    def scores(self) -> np.ndarray:
        """Undiscounted return of each episode."""
        return np.asarray(self.meta["scores"], dtype=np.float64)

    @property
    def best_episode(self) -> int:
        """Index of the highest-scoring episode (the first one on ties)."""
        return int(np.argmax(self.scores))

    @property
    def score(self) -> float:
        """The score of the best episode (of the only one, for a single-episode demo)."""
        return float(self.scores.max())

    @property
    def has_observations(self) -> bool:
        return self.observations is not None

    def _index(self, i: int) -> int:
        if isinstance(i, bool) or not isinstance(i, int | np.integer):
            raise TypeError(f"episode index must be an integer, got {i!r}")
        if not -self.num_episodes <= i < self.num_episodes:
            raise IndexError(f"episode {i} out of range for a demo of {self.num_episodes} episodes")
        return int(i) % self.num_episodes

    def _indices(self, episodes: int | Sequence[int] | None) -> list[int]:
        if episodes is None:
            return list(range(self.num_episodes))
        if np.ndim(episodes) == 0:
            return [self._index(episodes)]
        return [self._index(i) for i in episodes]

    def episode(self, i: int) -> DemoEpisode:
        """Episode `i` (negative counts from the end) as views into this demo's arrays."""
        i = self._index(i)
        start = int(self.episode_offsets[i])
        sl = slice(start, start + int(self.episode_lengths[i]))
        return DemoEpisode(
            actions=self.actions[sl],
            rewards=self.rewards[sl],
            terminated=self.terminated[sl],
            truncated=self.truncated[sl],
            observations=None if self.observations is None else self.observations[sl],
            final_observation=(
                None if self.final_observations is None else self.final_observations[i]
            ),
            seed=self.meta["seeds"][i],
            score=float(self.meta["scores"][i]),
            decisions=self.decisions[sl],
        )

    def episode_actions(self) -> list[np.ndarray]:
        """Every recorded action of each episode, injected steps included (for replay)."""
        return np.split(self.actions, np.cumsum(self.episode_lengths)[:-1])

    @property
    def num_decisions(self) -> int:
        """Steps the demonstrator decided."""
        return int(self.decisions.sum())

    @property
    def num_injected(self) -> int:
        """Steps a wrapper below the demonstrator injected."""
        return len(self) - self.num_decisions

    def decision_actions(self) -> list[np.ndarray]:
        """The demonstrator's actions of each episode, injected steps left out.

        This is the trajectory `ι_d` the alignment score compares an agent with.

        Example:
            >>> demo = Demo(actions=np.array([0, 0, 2, 3, 0, 2]), rewards=np.zeros(6),
            ...             terminated=np.array([0, 0, 0, 0, 0, 1], bool),
            ...             truncated=np.zeros(6, bool), episode_lengths=np.array([6]),
            ...             decisions=np.array([0, 0, 1, 1, 0, 1], bool))
            >>> [a.tolist() for a in demo.decision_actions()]
            [[2, 3, 2]]
        """
        return [
            actions[decided]
            for actions, decided in zip(
                self.episode_actions(),
                np.split(self.decisions, np.cumsum(self.episode_lengths)[:-1]),
                strict=True,
            )
        ]

    def decision_segments(self) -> tuple[list[np.ndarray], list[tuple[int, int]]]:
        """Maximal runs of decided steps, and where each starts: what the miners consume.

        An injected step splits an episode as an episode boundary does, so no routine found
        in the segments spans one. Returns the segments' actions and, for each, `(episode,
        step)`: its episode and the index of its first step within that episode.

        Example:
            >>> demo = Demo(actions=np.array([0, 0, 2, 3, 0, 2, 3, 1]), rewards=np.zeros(8),
            ...             terminated=np.array([0, 0, 0, 0, 0, 0, 0, 1], bool),
            ...             truncated=np.zeros(8, bool), episode_lengths=np.array([8]),
            ...             decisions=np.array([0, 0, 1, 1, 0, 1, 1, 1], bool))
            >>> segments, starts = demo.decision_segments()
            >>> [s.tolist() for s in segments], starts
            ([[2, 3], [2, 3, 1]], [(0, 2), (0, 5)])
        """
        segments: list[np.ndarray] = []
        starts: list[tuple[int, int]] = []
        for e, offset in enumerate(self.episode_offsets.tolist()):
            end = offset + int(self.episode_lengths[e])
            decided = self.decisions[offset:end]
            # Run boundaries: where `decided` switches on (a start) and off (an end).
            padded = np.concatenate([[False], decided, [False]]).astype(np.int8)
            edges = np.diff(padded)
            for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
                segments.append(self.actions[offset + a : offset + b])
                starts.append((e, int(a)))
        return segments, starts

    def select(self, episodes: int | Sequence[int]) -> Demo:
        """A new demo of the given episodes, in the given order, with their seeds and meta."""
        indices = self._indices(episodes)
        if not indices:
            raise ValueError("select() needs at least one episode")
        parts = [self.episode(i) for i in indices]
        meta = dict(self.meta)
        meta["seeds"] = [self.meta["seeds"][i] for i in indices]
        del meta["scores"]
        return Demo(
            actions=np.concatenate([p.actions for p in parts]),
            rewards=np.concatenate([p.rewards for p in parts]),
            terminated=np.concatenate([p.terminated for p in parts]),
            truncated=np.concatenate([p.truncated for p in parts]),
            episode_lengths=self.episode_lengths[indices],
            observations=(
                None if self.observations is None
                else np.concatenate([p.observations for p in parts])
            ),
            final_observations=(
                None if self.final_observations is None else self.final_observations[indices]
            ),
            meta=meta,
            decisions=np.concatenate([p.decisions for p in parts]),
        )

    def best(self) -> Demo:
        """A single-episode demo of the best episode (the first one on ties)."""
        return self.select([self.best_episode])

    # -- files ---------------------------------------------------------------------------

    def save(self, path: str | os.PathLike, include_observations: bool = True) -> None:
        """Write the demo to `path` (format in `routine_gym.demo.npz`), atomically.

        `include_observations=False` leaves the observations out: the seeds and actions are
        enough for `replay` to regenerate them, and the file is a few KB instead of MBs.
        The path is used as given (no `.npz` is appended).
        """
        arrays: dict[str, np.ndarray] = {
            "actions": self.actions,
            "rewards": self.rewards,
            "terminated": self.terminated,
            "truncated": self.truncated,
            "decisions": self.decisions,
            "episode_lengths": self.episode_lengths,
            "meta": np.array(json.dumps(_to_json(self.meta), indent=1)),
        }
        if include_observations and self.observations is not None:
            arrays["observations"] = self.observations
            arrays["final_observations"] = self.final_observations
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays)
        atomic_write_bytes(path, buffer.getvalue())

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        env: gym.Env | None = None,
        env_id: str | None = None,
    ) -> Demo:
        """Read a demo written by `save`, never unpickling anything.

        Args:
            path: the `.npz` file.
            env: when given, the demo must have been recorded on an env with the same id (when
                both have one) and the same number of actions.
            env_id: when given, the demo must have been recorded on this env id.

        Raises:
            FileNotFoundError: `path` does not exist.
            ValueError: naming the file and the problem, for a file that is not a demo
                (not a zip, truncated, corrupt, missing arrays, unknown format or version),
                an inconsistent one (lengths, flags, scores), actions outside the action
                space, or a demo of another env.
        """
        path = os.fspath(path)
        meta, arrays = read_demo_file(path)

        stored_scores = meta.get("scores")
        try:
            demo = cls(meta=meta, **arrays)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: {exc}") from exc
        if stored_scores is not None and not (
            len(stored_scores) == demo.num_episodes
            and np.allclose(stored_scores, demo.scores, rtol=1e-9, atol=1e-9)
        ):
            raise ValueError(
                f"{path}: meta scores {stored_scores} disagree with the rewards, which sum to "
                f"{demo.scores.tolist()}"
            )
        try:
            _check_env(demo, env=env, env_id=env_id)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc
        return demo


def _check_env(demo: Demo, env: gym.Env | None = None, env_id: str | None = None) -> None:
    """Raise ValueError when `demo` was not recorded on `env` / `env_id`."""
    from routine_gym.envs import same_env

    expected = env_id
    if expected is None and env is not None and env.spec is not None:
        expected = env.spec.id
    if not same_env(expected, demo.env_id):  # by registered spec: `module:EnvId` is EnvId
        raise ValueError(f"demo was recorded on {demo.env_id}, not {expected}")
    if env is not None:
        space = env.action_space
        if not isinstance(space, gym.spaces.Discrete):
            raise ValueError(f"a demo has discrete actions; the env's action space is {space}")
        if int(space.n) != demo.num_actions:
            raise ValueError(
                f"demo has {demo.num_actions} actions, the env has Discrete({int(space.n)})"
            )
