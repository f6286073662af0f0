"""`RoutineLibrary`: the routines mined from a demonstration, with their evidence.

A routine is a tuple of primitive action ids. The library keeps, for each routine, the score
that ranked it, its frequency in the demonstration and where it occurs, together with the
parameters of the miner and a description of the source, so that a library saved next to a
training run says exactly how it was made.
"""

from __future__ import annotations

import itertools
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from routine_gym.atomic import atomic_write_text

Routine = tuple[int, ...]

LIBRARY_FORMAT = "routine-gym/library"
LIBRARY_VERSION = 1

#: The occurrences of a routine a library keeps (the first ones, in demo order); its frequency
#: is still the full count. A repetitive demo of 10^6 actions holds a routine ~10^5 times: kept
#: whole, they made a 128 MB `routines.json`, copied into every run folder and checkpoint, and
#: gigabytes of memory. The shipped demos' routines occur at most ~1,000 times, so their
#: libraries keep every occurrence (`occurrences_complete`).
MAX_KEPT_OCCURRENCES = 5_000


@dataclass(frozen=True)
class RoutineLibrary:
    """Routines with the evidence that selected them.

    Attributes:
        routines: the routines, each a tuple of primitive action ids, in the proposer's order:
            best first for the Sequitur miner, the full model's order for the ablations.
        scores: the score of each routine (`f + λ·len` for the Sequitur miner).
        frequencies: overlapping occurrences of each routine in the demonstration.
        occurrences: for each routine, its occurrences as `(episode, start)` pairs, where
            `start` indexes the episode's action sequence (given as pairs or as an integer
            array of shape (f, 2), the miners' fast path: a routine can occur 10^6 times);
            only the first `MAX_KEPT_OCCURRENCES` are kept (`occurrences_complete`).
        params: the parameters of the proposer that made the library.
        source: where the actions came from (demo path, env id, seed, ...).
        action_meanings: names of the primitive actions, when known.
    """

    routines: tuple[Routine, ...]
    scores: tuple[float, ...] = ()
    frequencies: tuple[int, ...] = ()
    occurrences: tuple[tuple[tuple[int, int], ...], ...] = ()
    params: dict[str, Any] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    action_meanings: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        routines = tuple(tuple(_action_id(a, i) for a in r) for i, r in enumerate(self.routines))
        object.__setattr__(self, "routines", routines)
        for name in ("scores", "frequencies", "occurrences"):
            value = getattr(self, name)
            if value and len(value) != len(routines):
                raise ValueError(
                    f"RoutineLibrary.{name} has {len(value)} entries for {len(routines)} routines"
                )
        for i, routine in enumerate(routines):
            if len(routine) == 0:
                raise ValueError(f"routine {i} is empty")
            if min(routine) < 0:
                raise ValueError(f"routine {i} contains a negative action: {routine}")
        object.__setattr__(self, "scores", tuple(float(s) for s in self.scores))
        object.__setattr__(self, "frequencies", tuple(int(f) for f in self.frequencies))
        object.__setattr__(
            self, "occurrences", tuple(_occurrence_pairs(occ) for occ in self.occurrences)
        )
        if self.action_meanings is not None:
            object.__setattr__(self, "action_meanings", tuple(self.action_meanings))
            n = len(self.action_meanings)
            for i, routine in enumerate(routines):
                if max(routine) >= n:
                    raise ValueError(
                        f"routine {i} {list(routine)} uses action {max(routine)}, outside the "
                        f"library's {n} actions {list(self.action_meanings)}"
                    )

    def __len__(self) -> int:
        return len(self.routines)

    def __iter__(self):
        return iter(self.routines)

    def __getitem__(self, k: int) -> Routine:
        return self.routines[k]

    @property
    def occurrences_complete(self) -> bool:
        """Whether `occurrences` holds every occurrence of every routine: none was left out
        for `MAX_KEPT_OCCURRENCES` (known from the frequencies; False without them)."""
        return (bool(self.occurrences) and len(self.frequencies) == len(self.occurrences)
                and all(len(o) == f for o, f in zip(self.occurrences, self.frequencies,
                                                    strict=True)))

    @property
    def lengths(self) -> tuple[int, ...]:
        return tuple(len(r) for r in self.routines)

    def name(self, k: int, action_meanings: Sequence[str] | None = None) -> str:
        """Routine `k` in action names (`"UP UP RIGHT"`), or ids when no names are known."""
        meanings = action_meanings if action_meanings is not None else self.action_meanings
        return routine_name(self.routines[k], meanings)

    def describe(self, action_meanings: Sequence[str] | None = None) -> str:
        """A readable table of the routines with their scores and frequencies."""
        lines = []
        params = ", ".join(f"{k}={v}" for k, v in self.params.items())
        lines.append(f"RoutineLibrary: {len(self)} routines ({params})")
        for k, routine in enumerate(self.routines):
            parts = [f"  [{k}] len={len(routine):<3d}"]
            if self.scores:
                parts.append(f"score={self.scores[k]:<8.2f}")
            if self.frequencies:
                parts.append(f"freq={self.frequencies[k]:<6d}")
            parts.append(self.name(k, action_meanings))
            lines.append(" ".join(parts))
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.describe()

    # -- JSON round trip ---------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": LIBRARY_FORMAT,
            "version": LIBRARY_VERSION,
            "routines": [list(r) for r in self.routines],
            "scores": list(self.scores),
            "frequencies": list(self.frequencies),
            "occurrences": [[list(o) for o in occ] for occ in self.occurrences],
            "params": self.params,
            "source": self.source,
            "action_meanings": None if self.action_meanings is None else list(self.action_meanings),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RoutineLibrary:
        if not isinstance(data, dict) or data.get("format") != LIBRARY_FORMAT:
            raise ValueError(f"not a routine library (expected format {LIBRARY_FORMAT!r})")
        if data.get("version") != LIBRARY_VERSION:
            raise ValueError(
                f"routine library version {data.get('version')!r} is not supported "
                f"(this routine-gym reads version {LIBRARY_VERSION})"
            )
        try:
            return cls(
                routines=tuple(tuple(r) for r in data["routines"]),
                scores=tuple(data.get("scores", ())),
                frequencies=tuple(data.get("frequencies", ())),
                occurrences=tuple(
                    tuple(tuple(o) for o in occ) for occ in data.get("occurrences", ())
                ),
                params=dict(data.get("params", {})),
                source=dict(data.get("source", {})),
                action_meanings=data.get("action_meanings"),
            )
        except (KeyError, TypeError) as exc:
            raise ValueError(f"malformed routine library: {exc!r}") from exc

    def save(self, path: str | os.PathLike) -> None:
        """Write the library as JSON, atomically (a crash never leaves half a file)."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike) -> RoutineLibrary:
        """Read a library written by `save`.

        Raises:
            FileNotFoundError: no file at `path`.
            routine_gym.errors.UsageError: naming the file, for a file that is not a valid
                library (not JSON, not one, a routine with a non-integer or negative action or
                one outside its named actions).
        """
        from routine_gym.errors import UsageError

        if not os.path.isfile(path):
            if os.path.exists(path):
                raise UsageError(f"{path}: not a file")
            raise FileNotFoundError(f"{path}: no such routine library file")
        try:
            with open(path, encoding="utf-8") as f:
                data = json.load(f)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise UsageError(f"{path}: not a routine library: not valid JSON ({exc})") from exc
        try:
            return cls.from_dict(data)
        except ValueError as exc:
            raise UsageError(f"{path}: {exc}") from exc


def _action_id(action: Any, routine: int) -> int:
    """An action id: an integer (or an integral float such as 2.0), never a truncated 2.7."""
    if isinstance(action, bool):
        raise ValueError(f"routine {routine} has a boolean action {action!r}")
    if isinstance(action, int | np.integer):
        return int(action)
    if isinstance(action, float | np.floating) and float(action).is_integer():
        return int(action)
    raise ValueError(f"routine {routine} has a non-integer action {action!r}")


def _occurrence_pairs(occ: Any) -> tuple[tuple[int, int], ...]:
    """One routine's first `MAX_KEPT_OCCURRENCES` occurrences as a tuple of `(int, int)` pairs."""
    if isinstance(occ, np.ndarray) and occ.ndim == 2 and occ.shape[1] == 2 and (
            np.issubdtype(occ.dtype, np.integer)):
        occ = occ[:MAX_KEPT_OCCURRENCES]
        return tuple(zip(occ[:, 0].tolist(), occ[:, 1].tolist(), strict=True))
    return tuple((int(e), int(s)) for e, s in itertools.islice(occ, MAX_KEPT_OCCURRENCES))


def routine_name(routine: Sequence[int], action_meanings: Sequence[str] | None = None) -> str:
    """`(2, 2, 3)` as `"UP UP RIGHT"` given the env's action meanings, else `"2 2 3"`."""
    if action_meanings is None:
        return " ".join(str(a) for a in routine)
    return " ".join(
        action_meanings[a] if 0 <= a < len(action_meanings) else f"?{a}" for a in routine
    )

