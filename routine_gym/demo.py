"""Demonstrations: record, save, load, verify and replay the episodes RAPL learns from.

A `Demo` is one or more episodes of a discrete-action env, played by an agent or a human, with
the seed that reset each episode. The env's dynamics are deterministic given the reset seed and
the actions (ALE, sticky actions included, and Procgen are), so the actions and seeds alone
reproduce a demo exactly: `replay` re-runs them and checks every reward, flag and (when stored)
observation. Shipped demos therefore leave the observations out.

What a demo records is the *raw* env, made by `gym.make(env_id, **env_kwargs)`, with its
primitive actions: put `DemoRecorder` directly over that env. An agent trained behind
preprocessing wrappers (frame skip, frame stack, resizing, ...) is recorded by placing the
recorder *under* the preprocessing: `AtariPreprocessing(DemoRecorder(gym.make(...)))`, or
`record_agent_demo(..., wrap_env=...)`; the recorder then sees every primitive step.

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

File format (version 2)
-----------------------
One compressed NumPy archive (`.npz`, written with `np.savez_compressed` and replaced
atomically). It holds no pickles: every member is a plain numeric or unicode array, and it loads
with `np.load(path, allow_pickle=False)`. With T steps in E episodes:

| array                | shape          | dtype   | content                                       |
|----------------------|----------------|---------|-----------------------------------------------|
| `actions`            | (T,)           | int64   | primitive action ids, episodes concatenated   |
| `rewards`            | (T,)           | float64 | reward of each step                           |
| `terminated`         | (T,)           | bool    | `terminated` flag of each step                |
| `truncated`          | (T,)           | bool    | `truncated` flag of each step                 |
| `decisions`          | (T,)           | bool    | True: the demonstrator chose the action;      |
|                      |                |         | False: a wrapper injected it (version 2)      |
| `episode_lengths`    | (E,)           | int64   | steps per episode, each ≥ 1, summing to T     |
| `observations`       | (T, *obs)      | env's   | optional: the observation before each action  |
| `final_observations` | (E, *obs)      | env's   | optional: the observation after the last step |
| `meta`               | ()             | unicode | JSON object, below                            |

Episode `e` occupies steps `offsets[e] : offsets[e] + episode_lengths[e]` with
`offsets = cumsum(episode_lengths) - episode_lengths`; `final_observations[e]` is the
observation after episode `e`'s last action. Only an episode's last step may carry a
`terminated` or `truncated` flag; a last step with neither marks an episode cut short (a human
who closed the window). `observations` and `final_observations` are stored together or not at
all.

`meta` keys: `format` (`"routine-gym/demo"`), `version` (`2`), `env_id` (or null for an env
not made by `gym.make`), `env_kwargs` (the keyword arguments of `gym.make`, without
`render_mode`), `max_episode_steps` (the time limit `gym.make` applied, or null), `seeds` (the
reset seed of each episode), `num_actions`, `action_meanings`, `scores` (undiscounted return of
each episode, checked against `rewards` on load), `source` (`"agent"`, `"human"`, `"random"`,
...), `created` (ISO 8601, UTC) and `routine_gym_version`; any other key is provenance that is
kept as is (`candidates` lists every episode `record_agent_demo` chose the best from;
`recorded_under` names the wrappers between the recorder and the decision marker). A tuple
anywhere in `meta` is written as `{"__tuple__": [...]}` so that it loads back as a tuple.

Version 1 (the same without `decisions`) still loads, with every step a decision;
`routine-gym upgrade DEMO` (`upgrade_demo`) rewrites it as version 2 by replaying it through
the preprocessing it was recorded under, which re-derives the injected steps from the seeds.
Loading checks everything above and names the file and the problem in a `ValueError`.
"""

from __future__ import annotations

import inspect
import io
import json
import math
import os
import sys
import warnings
import zipfile
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.atomic import atomic_write_bytes

DEMO_FORMAT = "routine-gym/demo"
DEMO_VERSION = 2
#: File versions `Demo.load` reads (version 1 has no `decisions`: every step is a decision).
READABLE_VERSIONS = (1, 2)

_STEP_ARRAYS = ("actions", "rewards", "terminated", "truncated")
_REQUIRED_ARRAYS = (*_STEP_ARRAYS, "episode_lengths", "meta")
_OBS_ARRAYS = ("observations", "final_observations")
_V2_ARRAYS = ("decisions",)
# Seeds drawn for an unseeded reset stay below 2**31 so that every env accepts them.
_MAX_DRAWN_SEED = 2**31 - 1


def _routine_gym_version() -> str:
    # importlib.metadata rather than `routine_gym.__version__`: no import cycle with __init__.
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("routine-gym")
    except PackageNotFoundError:
        return "unknown"


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


# -- JSON helpers ------------------------------------------------------------------------


def _to_json(value: Any) -> Any:
    """`value` as JSON-able data (tuples tagged so they come back); TypeError if impossible."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return {"__tuple__": [_to_json(v) for v in value]}
    if isinstance(value, list):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError(f"dict keys must be strings: {list(value)!r}")
        return {k: _to_json(v) for k, v in value.items()}
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable: {value!r}")


def _from_json(value: Any) -> Any:
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    if isinstance(value, dict):
        if set(value) == {"__tuple__"} and isinstance(value["__tuple__"], list):
            return tuple(_from_json(v) for v in value["__tuple__"])
        return {k: _from_json(v) for k, v in value.items()}
    return value


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

    The layout and the `meta` keys are those of the file format in the module docstring. Arrays
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
        """Write the demo to `path` (format in the module docstring), atomically.

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
        if not os.path.exists(path):
            raise FileNotFoundError(f"{path}: no such demo file")
        if not os.path.isfile(path):
            raise ValueError(f"{path}: not a file")
        if not zipfile.is_zipfile(path):
            raise ValueError(
                f"{path}: not a routine-gym demo: not an .npz (zip) archive; "
                "the file may be truncated or corrupt"
            )
        try:
            with np.load(path, allow_pickle=False) as data:
                names = set(data.files)
                if "meta" not in names:
                    raise ValueError(
                        f"not a routine-gym demo: it has no 'meta' array (arrays: {sorted(names)})"
                    )
                meta = _parse_meta(_read_array(data, "meta"))
                required = _REQUIRED_ARRAYS + (_V2_ARRAYS if meta["version"] >= 2 else ())
                missing = [n for n in required if n not in names]
                if missing:
                    raise ValueError(f"missing arrays {missing} (arrays: {sorted(names)})")
                arrays = {
                    n: _read_array(data, n)
                    for n in (*required, *_OBS_ARRAYS)
                    if n in names and n != "meta"
                }
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
            raise ValueError(f"{path}: corrupt demo file ({type(exc).__name__}: {exc})") from exc
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from exc

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


def _read_array(data: Any, name: str) -> np.ndarray:
    try:
        arr = data[name]
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise ValueError(
                f"array {name!r} holds pickled Python objects, which routine-gym never loads"
            ) from exc
        raise ValueError(f"array {name!r} is not a valid array ({exc})") from exc
    if not isinstance(arr, np.ndarray):  # NpzFile hands back raw bytes for a non-.npy member
        raise ValueError(f"member {name!r} is not a .npy array")
    return arr


def demo_file_version(path: str | os.PathLike) -> int:
    """The format version a demo file was written in (1 or 2), read from its `meta` alone.

    Raises:
        ValueError: naming the file, for a file that is not a readable demo.
    """
    path = os.fspath(path)
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a routine-gym demo: not an .npz (zip) archive")
    try:
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data.files:
                raise ValueError("not a routine-gym demo: it has no 'meta' array")
            return int(_parse_meta(_read_array(data, "meta"))["version"])
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        raise ValueError(f"{path}: corrupt demo file ({type(exc).__name__}: {exc})") from exc
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _parse_meta(arr: np.ndarray) -> dict[str, Any]:
    if arr.shape != () or arr.dtype.kind != "U":
        raise ValueError(
            f"'meta' must be a 0-d unicode array of JSON, got dtype {arr.dtype} shape {arr.shape}"
        )
    try:
        meta = json.loads(str(arr[()]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"'meta' is not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"'meta' must be a JSON object, got {type(meta).__name__}")
    if meta.get("format") != DEMO_FORMAT:
        raise ValueError(
            f"not a routine-gym demo: format is {meta.get('format')!r}, expected {DEMO_FORMAT!r}"
        )
    version = meta.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise ValueError(
            f"demo format version {version!r} is not supported; "
            f"this routine-gym reads versions {', '.join(map(str, READABLE_VERSIONS))}"
        )
    return _from_json(meta)


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


# -- recording ---------------------------------------------------------------------------


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
    the module docstring): put `DecisionMarker` at the agent-facing top of the stack (below a
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
        >>> import gymnasium as gym
        >>> from routine_gym.envs.atari import FireReset
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


# -- replay ------------------------------------------------------------------------------


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
        env = gym.make(demo.env_id, **kwargs)
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


# -- agent and human demos ---------------------------------------------------------------


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
        gym.make(env_id, **kwargs), record_observations=record_observations, source="agent"
    )
    env = _agent_stack(recorder, wrap_env, routines)
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


def _agent_stack(
    recorder: DemoRecorder,
    wrap_env: Callable[[gym.Env], gym.Env] | None,
    routines: Sequence[Sequence[int]] | None,
) -> gym.Env:
    """`RoutineActionWrapper(DecisionMarker(wrap_env(recorder)))`, checked."""
    from routine_gym.wrapper import RoutineActionWrapper

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
    if routines is not None and len(routines) > 0:
        env = RoutineActionWrapper(env, routines, record_observations=False)
    return env


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
            recorder = DemoRecorder(gym.make(demo.env_id, **kwargs), record_observations=False)
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
    env = gym.make(env_id, **kwargs)
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


__all__ = [
    "DEMOS_DIR",
    "DEMO_FORMAT",
    "DEMO_SUITE",
    "DEMO_VERSION",
    "Demo",
    "DemoEpisode",
    "DemoRecorder",
    "DemoReplayError",
    "ReplayResult",
    "DecisionMarker",
    "READABLE_VERSIONS",
    "demo_file_version",
    "demo_filename",
    "upgrade_demo",
    "record_agent_demo",
    "record_human_demo",
    "replay",
    "shipped_demo_path",
]


#: Where the shipped demonstrations live. The repository's top-level `demos/` folder is installed
#: as `routine_gym/demos/` (package data, mapped in pyproject.toml); an editable install or a
#: source checkout has no such folder and reads `demos/` in place, next to the package.
_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
DEMOS_DIR = os.path.join(_PACKAGE_DIR, "demos")
if not os.path.isdir(DEMOS_DIR):
    DEMOS_DIR = os.path.join(os.path.dirname(_PACKAGE_DIR), "demos")


#: The demonstration suite shipped in `demos/`: the paper's Atari games and CoinRun, one
#: trained agent's demo each. `routine-gym show-demos` lists it; the scripts default to it.
DEMO_SUITE: tuple[str, ...] = (
    "ALE/Qbert-v5",
    "ALE/Breakout-v5",
    "ALE/SpaceInvaders-v5",
    "ALE/BeamRider-v5",
    "ALE/Seaquest-v5",
    "ALE/MsPacman-v5",
    "procgen/CoinRun-v0",
)


def demo_filename(env_id: str) -> str:
    """The file name of `env_id`'s shipped demo: `ALE/Qbert-v5` → `ALE-Qbert-v5.npz`."""
    return env_id.replace("/", "-") + ".npz"


def shipped_demo_path(env_id: str) -> str | None:
    """The path of the demo shipped in `demos/` for `env_id`, or None if there is none."""
    from routine_gym.envs import canonical_env_id

    path = os.path.join(DEMOS_DIR, demo_filename(canonical_env_id(env_id)))
    return path if os.path.isfile(path) else None
