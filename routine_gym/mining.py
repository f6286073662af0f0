"""Routine discovery: from one demonstration's actions to a `RoutineLibrary` (SPEC §2).

`SequiturMiner` is the paper's two-phase method:

1. *Proposal.* Sequitur infers a grammar of the demonstrated actions; every non-start rule,
   expanded to primitive actions, is a candidate (duplicates merged), up to `max_length`
   actions (`MAX_ROUTINE_LENGTH` = 64 by default).
2. *Selection.* Each candidate ρ is scored `f(ρ) + λ_length·|ρ|`, where `f` counts its
   occurrences in the raw action sequence (overlapping ones included, none across an episode
   boundary). Candidates are visited by descending score (ties: longer first, then
   lexicographic) and accepted unless their Levenshtein distance to an accepted routine is
   `< α`; primitives count as accepted, so with α = 2 no routine of length 2 survives. The
   first K accepted form the library.

The ablation proposers of the paper share the interface (`mine(actions) -> RoutineLibrary`),
use the same K and the routine lengths the full miner finds, and are seeded:

- `RandomRoutines` (RR): actions drawn uniformly from those present in the demo;
- `EnumerationProposer` (PbE): every action sequence of the chosen lengths, scored and pruned
  like the full miner's candidates (sequences absent from the demo score only `λ·|ρ|`);
- `RandomFetch` (RF): random contiguous slices of the demo;
- `RepeatProposer` (RP): the most frequent actions repeated, FiGAR style.

Example:
    >>> from routine_gym.mining import SequiturMiner
    >>> library = SequiturMiner(num_routines=2).mine(
    ...     [2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3]
    ... )
    >>> library.routines
    ((2, 2, 3), (4, 4, 1, 2, 2, 3))
    >>> library.frequencies
    (3, 2)
    >>> library.scores
    (3.3, 2.6)
"""

from __future__ import annotations

import heapq
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np
from rapidfuzz.distance import Levenshtein

from routine_gym.library import Routine, RoutineLibrary
from routine_gym.sequitur import _as_episodes, induce

__all__ = [
    "MAX_ROUTINE_LENGTH",
    "PROPOSERS",
    "EnumerationProposer",
    "OccurrenceIndex",
    "RandomFetch",
    "RandomRoutines",
    "RepeatProposer",
    "RoutineProposer",
    "SequiturMiner",
    "demo_occurrences",
    "make_proposer",
]


class RoutineProposer(Protocol):
    """Anything that turns demonstrated actions into a `RoutineLibrary`."""

    def mine(
        self,
        actions: Any,
        action_meanings: Sequence[str] | None = None,
        source: dict[str, Any] | None = None,
    ) -> RoutineLibrary: ...


class OccurrenceIndex:
    """Counts and locates every (overlapping) occurrence of a routine in a set of episodes.

    Every window of q ≤ Q consecutive actions inside an episode gets an integer code, so a
    routine of up to Q actions is counted by one dictionary look-up. A longer routine is
    bounded from above by the count of its rarest Q-gram (an occurrence of ρ contains one of
    each of its Q-grams) and by the number of windows of its length, and located by filtering
    the positions of that Q-gram. The miner uses the bound to count exactly only the
    candidates that can still make the library.

    Filtering action by action costs (positions) × (length): on a million copies of one
    action, 10^6 × 2^19 for the grammar's longest rule. When that would exceed a few passes
    over the input, the filter checks two blocks instead: windows of 2^k actions get ids by
    prefix doubling (the id of a 2^k-block is that of the pair of its 2^(k-1)-halves, built
    once per k in O(n log n)), and ρ occurs at p exactly when the 2^k-blocks at p and at
    p + |ρ| - 2^k, which cover it, have the ids of ρ's first and last 2^k actions.
    """

    #: Positions × Q-gram checks above which a long routine is located by block ids.
    _FILTER_BUDGET = 4

    def __init__(self, episodes: Sequence[np.ndarray], max_gram: int = 4) -> None:
        episodes = [np.asarray(e, dtype=np.int64) for e in episodes]
        lengths = np.array([e.size for e in episodes], dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(lengths)])
        raw = np.concatenate(episodes) if episodes else np.zeros(0, dtype=np.int64)
        self.seq = raw
        self.episode_of = np.repeat(np.arange(lengths.size), lengths)
        # Episode lengths ascending, with suffix sums: windows of any length in O(log E).
        self._sorted_lengths = np.sort(lengths)
        self._length_tail = np.concatenate([np.cumsum(self._sorted_lengths[::-1])[::-1], [0]])
        # Dense ids keep the window codes small whatever the action ids are.
        self.alphabet, dense = np.unique(raw, return_inverse=True)
        self._dense = dense.astype(np.int64)
        self._dense_id = {int(a): i for i, a in enumerate(self.alphabet.tolist())}
        base = max(int(self.alphabet.size), 1)
        self._base = base
        self.max_gram = 1
        while self.max_gram < max_gram and base ** (self.max_gram + 1) < 2**62:
            self.max_gram += 1
        self._codes: dict[int, np.ndarray] = {}
        self._counts: dict[int, dict[int, int]] = {}
        q = self.max_gram
        codes = self.window_codes(q)
        valid = np.flatnonzero(codes >= 0)
        self._positions = valid[np.argsort(codes[valid], kind="stable")]
        self._keys, self._starts, counts = np.unique(
            codes[self._positions], return_index=True, return_counts=True
        )
        self._ends = self._starts + counts
        # Block ids by prefix doubling, built on demand: level k ids the 2^k-blocks.
        self._block_ids: list[np.ndarray] = [self._dense]
        self._block_keys: list[np.ndarray] = [np.arange(base, dtype=np.int64)]

    def window_codes(self, q: int) -> np.ndarray:
        """Code of the q actions starting at each position; -1 where they leave the episode."""
        if q not in self._codes:
            n = self._dense.size
            codes = np.full(n, -1, dtype=np.int64)
            m = n - q + 1
            if m > 0:
                window = np.zeros(m, dtype=np.int64)
                for j in range(q):
                    window = window * self._base + self._dense[j : j + m]
                inside = self.episode_of[:m] == self.episode_of[q - 1 : q - 1 + m]
                codes[:m][inside] = window[inside]
            self._codes[q] = codes
        return self._codes[q]

    def _gram_counts(self, q: int) -> dict[int, int]:
        if q not in self._counts:
            codes = self.window_codes(q)
            keys, counts = np.unique(codes[codes >= 0], return_counts=True)
            self._counts[q] = dict(zip(keys.tolist(), counts.tolist(), strict=True))
        return self._counts[q]

    def _encode(self, gram: Sequence[int]) -> int | None:
        """Window code of `gram`, or None when one of its actions never occurs."""
        code = 0
        for a in gram:
            i = self._dense_id.get(a)
            if i is None:
                return None
            code = code * self._base + i
        return code

    def _dense_routine(self, routine: Sequence[int]) -> np.ndarray | None:
        """The dense ids of `routine`'s actions, or None when one of them never occurs."""
        r = np.asarray(routine, dtype=np.int64)
        i = np.minimum(np.searchsorted(self.alphabet, r), max(self.alphabet.size - 1, 0))
        if self.alphabet.size == 0 or not np.array_equal(self.alphabet[i], r):
            return None
        return i.astype(np.int64)

    def _gram_spans(self, routine: Sequence[int]) -> tuple[np.ndarray, np.ndarray] | None:
        """For each Q-gram of a routine of ≥ Q actions, its slice of the sorted positions;
        None when one of them never occurs. Vectorised: routines can be 2^19 actions long."""
        q = self.max_gram
        dense = self._dense_routine(routine)
        if dense is None:
            return None
        m = dense.size - q + 1
        codes = np.zeros(m, dtype=np.int64)
        for j in range(q):
            codes = codes * self._base + dense[j : j + m]
        i = np.minimum(np.searchsorted(self._keys, codes), max(self._keys.size - 1, 0))
        if self._keys.size == 0 or not np.array_equal(self._keys[i], codes):
            return None
        return self._starts[i], self._ends[i]

    def num_windows(self, length: int) -> int:
        """How many windows of `length` actions lie inside an episode: a bound of any count."""
        i = int(np.searchsorted(self._sorted_lengths, length))
        return int(self._length_tail[i]) - (self._sorted_lengths.size - i) * (length - 1)

    def upper_bound(self, routine: Sequence[int]) -> int:
        """A cheap upper bound of `count(routine)`; exact for routines of ≤ max_gram actions."""
        n = len(routine)
        q = min(n, self.max_gram)
        bound = self.num_windows(n)
        if n - q + 1 > 16:
            spans = self._gram_spans(routine)
            return 0 if spans is None else min(bound, int((spans[1] - spans[0]).min()))
        counts = self._gram_counts(q)
        for j in range(n - q + 1):
            code = self._encode(routine[j : j + q])
            bound = min(bound, 0 if code is None else counts.get(code, 0))
            if bound == 0:
                break
        return bound

    def _block_level(self, k: int) -> np.ndarray:
        """Ids of the 2^k-blocks (-1 where a block leaves its episode), built by doubling."""
        while len(self._block_ids) <= k:
            prev = self._block_ids[-1]
            h = 1 << (len(self._block_ids) - 1)
            size = self._block_keys[-1].size
            m = max(prev.size - h, 0)
            left, right = prev[:m], prev[h : h + m]
            inside = (left >= 0) & (right >= 0) & (self.episode_of[:m] == self.episode_of[h:])
            keys, ids = _dense_ids(left[inside] * size + right[inside])
            level = np.full(prev.size, -1, dtype=np.int64)
            level[:m][inside] = ids
            self._block_ids.append(level)
            self._block_keys.append(keys)
        return self._block_ids[k]

    def _block_id(self, dense: np.ndarray, k: int) -> int | None:
        """The level-k id of a 2^k-block of dense action ids; None when it never occurs."""
        ids = dense
        for level in range(1, k + 1):
            size = self._block_keys[level - 1].size
            pairs = ids[0::2] * size + ids[1::2]
            keys = self._block_keys[level]
            i = np.minimum(np.searchsorted(keys, pairs), max(keys.size - 1, 0))
            if keys.size == 0 or not np.array_equal(keys[i], pairs):
                return None
            ids = i
        return int(ids[0])

    def _rarest_gram_starts(self, routine: Sequence[int]) -> tuple[int, np.ndarray]:
        """Where (j) the rarest Q-gram of a routine longer than Q sits in it, and the starts
        p it leaves: the gram at p + j, and p .. p + |ρ| - 1 inside one episode."""
        n = len(routine)
        spans = self._gram_spans(routine)
        if spans is None:
            return 0, np.zeros(0, dtype=np.int64)
        best = int(np.argmin(spans[1] - spans[0]))
        p = self._positions[spans[0][best] : spans[1][best]] - best
        p = p[(p >= 0) & (p + n <= self.seq.size)]
        return best, p[self.episode_of[p] == self.episode_of[p + n - 1]]

    def refined_bound(self, routine: Sequence[int]) -> int:
        """A tighter upper bound of `count(routine)` than `upper_bound`, in O(its rarest
        Q-gram's count): the starts that gram leaves where the routine fits in its episode.
        On a periodic input (`0 1 0 1 ...`) it is exact, where `upper_bound` counts every
        window of the routine's length."""
        if len(routine) <= self.max_gram:
            return self.upper_bound(routine)
        return int(self._rarest_gram_starts(tuple(int(a) for a in routine))[1].size)

    def positions(self, routine: Sequence[int]) -> np.ndarray:
        """Start positions (in the concatenated episodes) of every occurrence, ascending."""
        routine = tuple(int(a) for a in routine)
        n, q = len(routine), min(len(routine), self.max_gram)
        if n <= self.max_gram:
            code = self._encode(routine)
            if code is None:
                return np.zeros(0, dtype=np.int64)
            return np.flatnonzero(self.window_codes(n) == code)
        # Start from the rarest Q-gram of the routine, then check the rest.
        best, p = self._rarest_gram_starts(routine)
        checks = -(-(n - q) // q)
        if p.size * checks <= self._FILTER_BUDGET * self.seq.size:
            # Q actions at a time; the Q-grams at j and n - q cover the routine.
            codes = self.window_codes(q)
            for j in [*range(0, n - q, q), n - q]:
                if j == best:
                    continue
                p = p[codes[p + j] == self._encode(routine[j : j + q])]
            return p
        return self._block_filter(routine, p)

    def _block_filter(self, routine: Routine, p: np.ndarray) -> np.ndarray:
        """The starts in `p` (inside one episode each) where `routine` occurs, by block ids."""
        n = len(routine)
        k = n.bit_length() - 1
        level = self._block_level(k)
        dense = self._dense_routine(routine)
        if dense is None:
            return np.zeros(0, dtype=np.int64)
        first, last = self._block_id(dense[: 1 << k], k), self._block_id(dense[n - (1 << k) :], k)
        if first is None or last is None:
            return np.zeros(0, dtype=np.int64)
        return p[(level[p] == first) & (level[p + n - (1 << k)] == last)]

    def count(self, routine: Sequence[int]) -> int:
        """f(ρ): overlapping occurrences, none across an episode boundary."""
        if len(routine) <= self.max_gram:
            return self.upper_bound(routine)
        return int(self.positions(routine).size)

    def occurrence_array(self, routine: Sequence[int]) -> np.ndarray:
        """Every occurrence as a row `(episode, start within the episode)`: shape (f, 2)."""
        p = self.positions(routine)
        ep = self.episode_of[p]
        return np.stack([ep, p - self.offsets[ep]], axis=1)

    def occurrences(self, routine: Sequence[int]) -> tuple[tuple[int, int], ...]:
        """Every occurrence as `(episode, start within the episode)`."""
        return _pairs(self.occurrence_array(routine))

    def distinct_windows(self, length: int) -> list[Routine]:
        """Every distinct window of `length` actions inside an episode, in order of first
        occurrence; each is built once, however often it repeats."""
        k = length.bit_length() - 1
        level = self._block_level(k)
        m = self.seq.size - length + 1
        if m <= 0:
            return []
        first, last = level[:m], level[length - (1 << k) : length - (1 << k) + m]
        inside = (first >= 0) & (last >= 0) & (self.episode_of[:m] == self.episode_of[length - 1 :])
        starts = np.flatnonzero(inside)
        size = max(self._block_keys[k].size, 1)
        _, index = np.unique(first[starts] * size + last[starts], return_index=True)
        seq = self.seq.tolist()
        return [tuple(seq[s : s + length]) for s in np.sort(starts[index]).tolist()]


def _dense_ids(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.unique(keys, return_inverse=True)` with a stable (radix/merge) sort: numpy's
    default introsort is ten times slower on the two alternating keys of `0 1 0 1 ...`."""
    order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    new = np.empty(ordered.size, dtype=bool)
    new[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=new[1:])
    ids = np.empty(ordered.size, dtype=np.int64)
    ids[order] = np.cumsum(new) - 1
    return ordered[new], ids


def _pairs(rows: np.ndarray) -> tuple[tuple[int, int], ...]:
    """An (f, 2) integer array as a tuple of `(int, int)` pairs."""
    return tuple(zip(rows[:, 0].tolist(), rows[:, 1].tolist(), strict=True))


@dataclass(frozen=True)
class _Demonstrated:
    """What a proposer mines: the sequences, and where each one starts in the demo."""

    episodes: list[np.ndarray]
    """The sequences mined: a demo's decision segments, or the episodes given."""
    starts: list[tuple[int, int]] | None
    """`(episode, step)` of each sequence's first action in the demo (None: as given)."""
    meanings: Sequence[str] | None
    source: dict[str, Any]

    def occurrences(self, index: OccurrenceIndex, routine: Routine) -> np.ndarray:
        """`index.occurrence_array(routine)` as `(episode, step)` rows of the demo."""
        found = index.occurrence_array(routine)
        if self.starts is None:
            return found
        starts = np.asarray(self.starts, dtype=np.int64).reshape(-1, 2)[found[:, 0]]
        return np.stack([starts[:, 0], starts[:, 1] + found[:, 1]], axis=1)


def _episodes_of(actions: Any) -> _Demonstrated:
    """The sequences to mine, action meanings and a source description, from actions or a `Demo`.

    A `Demo` gives its decision segments (`Demo.decision_segments`): the steps its wrappers
    injected split the sequence as episode boundaries do, so no routine spans one, and
    occurrence positions are mapped back to `(episode, step)` of the demo.
    """
    meanings = None
    source: dict[str, Any] = {}
    starts = None
    if hasattr(actions, "decision_segments"):  # a routine_gym.demo.Demo
        demo = actions
        meta = getattr(demo, "meta", {}) or {}
        meanings = meta.get("action_meanings")
        source = {
            k: meta[k] for k in ("env_id", "seeds", "scores", "source", "path") if k in meta
        }
        actions, starts = demo.decision_segments()
        if not actions:
            raise ValueError(
                "the demonstration is empty: it has no step the demonstrator decided "
                "(every step was injected by a wrapper)"
            )
    episodes = _as_episodes(actions)
    total = sum(e.size for e in episodes)
    if total == 0:
        raise ValueError("the demonstration is empty: there are no actions to mine routines from")
    if max(e.size for e in episodes) < 2:
        raise ValueError(
            "the demonstration has no episode of two or more actions: a routine needs at least "
            "two consecutive actions"
        )
    return _Demonstrated(episodes, starts, meanings, source)


def demo_occurrences(demo: Any, routines: Sequence[Sequence[int]]) -> tuple[
    tuple[tuple[int, int], ...], ...
]:
    """Every occurrence `(episode, step)` of each routine in a `Demo`'s decisions.

    Found as the miners find them: overlapping ones counted, none across an episode boundary
    or an injected step; `step` indexes the episode's recorded steps.
    """
    demonstrated = _episodes_of(demo)
    index = OccurrenceIndex(demonstrated.episodes)
    return tuple(
        _pairs(demonstrated.occurrences(index, tuple(int(a) for a in r))) for r in routines
    )


#: The default bound on a routine's length (`SequiturMiner.max_length`, the scripts'
#: `--max-routine-length`); see `SequiturMiner` for why 64.
MAX_ROUTINE_LENGTH = 64


def _check_params(num_routines: int, length_weight: float, alpha: int) -> None:
    if isinstance(num_routines, bool) or not isinstance(num_routines, int | np.integer):
        raise TypeError(f"num_routines must be an int, got {type(num_routines).__name__}")
    if num_routines <= 0:
        raise ValueError(f"num_routines needs to be ≥ 1, actual value: {num_routines}")
    if alpha < 1:
        raise ValueError(f"alpha (the Levenshtein pruning distance) needs to be ≥ 1, got {alpha}")
    if not np.isfinite(length_weight) or length_weight < 0:
        raise ValueError(f"length_weight needs to be a finite number ≥ 0, got {length_weight}")


def _sort_key(score: float, routine: Routine) -> tuple[float, int, Routine]:
    return (-round(score, 9), -len(routine), routine)


class _Selector:
    """Score, prune and pick: the selection phase every proposer shares."""

    def __init__(self, index: OccurrenceIndex, length_weight: float, alpha: int,
                 prune_primitives: bool) -> None:
        self.index = index
        self.length_weight = length_weight
        self.alpha = alpha
        self.prune_primitives = prune_primitives

    def score(self, routine: Routine) -> tuple[float, int]:
        f = self.index.count(routine)
        # Rounded so that f + λ·len ties exactly whatever the floating-point path.
        return round(f + self.length_weight * len(routine), 9), f

    def near_primitive(self, routine: Routine) -> bool:
        # The Levenshtein distance from ρ to a one-action sequence [a] is |ρ| - 1 when a is in
        # ρ and |ρ| otherwise; its minimum over the primitives (ρ's own actions among them)
        # is |ρ| - 1.
        return self.prune_primitives and len(routine) - 1 < self.alpha

    def near_accepted(self, routine: Routine, accepted: Sequence[Routine]) -> bool:
        return any(
            Levenshtein.distance(routine, r, score_cutoff=self.alpha) < self.alpha
            for r in accepted
        )

    def select(self, candidates: Sequence[Routine], k: int) -> list[tuple[Routine, float, int]]:
        """The first `k` candidates by descending score that survive pruning.

        Exact frequencies are computed lazily: a candidate waits in the heap under an upper
        bound (`OccurrenceIndex.upper_bound`), is refined (`refined_bound`) when that reaches
        the top, and is counted only when the refined bound reaches the top. Each value is at
        least the next, so the order is that of the exact scores, but a candidate that cannot
        make the library is never counted: on a million copies of one action, the rules of
        2^19 actions are not.
        """
        exact_below = self.index.max_gram  # upper_bound is exact up to this length
        heap: list[tuple[tuple[float, int, Routine], int, int]] = []
        for routine in candidates:
            if self.near_primitive(routine):
                continue
            bound = self.index.upper_bound(routine)
            heap.append((_sort_key(bound + self.length_weight * len(routine), routine), 0, 0))
        heapq.heapify(heap)
        accepted: list[tuple[Routine, float, int]] = []
        while heap and len(accepted) < k:
            key, stage, f = heapq.heappop(heap)
            routine = key[2]
            if stage == 0 and len(routine) > exact_below:
                bound = self.index.refined_bound(routine)
                heapq.heappush(
                    heap, (_sort_key(bound + self.length_weight * len(routine), routine), 1, 0)
                )
                continue
            if stage < 2:
                score, f = self.score(routine)
                heapq.heappush(heap, (_sort_key(score, routine), 2, f))
                continue
            if self.near_accepted(routine, [r for r, _, _ in accepted]):
                continue
            accepted.append((routine, -key[0], f))
        return accepted


def _build_library(
    accepted: Sequence[tuple[Routine, float, int]],
    index: OccurrenceIndex,
    demonstrated: _Demonstrated,
    k: int,
    params: dict[str, Any],
    meanings: Sequence[str] | None,
    source: dict[str, Any],
) -> RoutineLibrary:
    if len(accepted) < k:
        warnings.warn(
            f"only {len(accepted)} routine(s) survive scoring and pruning, fewer than the "
            f"{k} asked for; returning {len(accepted)}",
            stacklevel=3,
        )
    return RoutineLibrary(
        routines=tuple(r for r, _, _ in accepted),
        scores=tuple(s for _, s, _ in accepted),
        frequencies=tuple(f for _, _, f in accepted),
        occurrences=tuple(demonstrated.occurrences(index, r) for r, _, _ in accepted),
        params=params,
        source=source,
        action_meanings=None if meanings is None else tuple(meanings),
    )


@dataclass
class SequiturMiner:
    """Mine the K best routines of a demonstration with Sequitur (the paper's full model).

    Args:
        num_routines: K, the size of the library.
        length_weight: λ_length in the score `f(ρ) + λ_length·|ρ|`.
        alpha: a candidate closer than `alpha` (Levenshtein) to an accepted routine is pruned.
        prune_primitives: count the primitive actions as accepted routines, so candidates
            within `alpha` of a single action are pruned too (the authors' behaviour).
        max_length: ignore candidates longer than this (None: no limit). The default,
            `MAX_ROUTINE_LENGTH` = 64, is three times the longest candidate of any shipped demo
            (22 actions, MinAtar Freeway), so no shipped library changes, and it bounds what a
            routine costs downstream: the wrapper pads every step's `info` arrays (actions,
            rewards, observations) to the longest routine, and a 49,152-action routine mined
            from a 5.6 KB demo made `rapl_a2c.py` with 4 envs need 3.8 GB.
        min_length: ignore candidates shorter than this (the scalability experiment's longer
            routines; 2 keeps every candidate).
    """

    num_routines: int = 3
    length_weight: float = 0.1
    alpha: int = 2
    prune_primitives: bool = True
    max_length: int | None = MAX_ROUTINE_LENGTH
    min_length: int = 2

    name = "full"

    def __post_init__(self) -> None:
        _check_params(self.num_routines, self.length_weight, self.alpha)
        if self.max_length is not None and (
                isinstance(self.max_length, bool)
                or not isinstance(self.max_length, int | np.integer) or self.max_length < 2):
            raise ValueError(f"max_length needs to be ≥ 2 or None, got {self.max_length!r}")
        if isinstance(self.min_length, bool) or not isinstance(self.min_length, int) or (
                self.min_length < 2):
            raise ValueError(f"min_length needs to be an integer ≥ 2, got {self.min_length!r}")
        if self.max_length is not None and self.min_length > self.max_length:
            raise ValueError(f"min_length {self.min_length} is above max_length "
                             f"{self.max_length}: no candidate could be kept")

    def params(self) -> dict[str, Any]:
        """The proposer's name and settings, as the library records them."""
        return {"proposer": self.name, **asdict(self)}

    def candidates(self, episodes: Sequence[np.ndarray]) -> list[Routine]:
        """Every non-start rule of the grammar, expanded; duplicates merged, order kept.

        Rules longer than `max_length` are never expanded.
        """
        seen = dict.fromkeys(induce(episodes).expansions(self.max_length))
        return [c for c in seen if self.min_length <= len(c)]

    def mine(
        self,
        actions: Any,
        action_meanings: Sequence[str] | None = None,
        source: dict[str, Any] | None = None,
    ) -> RoutineLibrary:
        """Mine a `RoutineLibrary` from actions, episodes of actions, or a `Demo`."""
        demonstrated = _episodes_of(actions)
        episodes = demonstrated.episodes
        index = OccurrenceIndex(episodes)
        selector = _Selector(index, self.length_weight, self.alpha, self.prune_primitives)
        accepted = selector.select(self.candidates(episodes), self.num_routines)
        return _build_library(
            accepted,
            index,
            demonstrated,
            self.num_routines,
            self.params(),
            action_meanings if action_meanings is not None else demonstrated.meanings,
            {**demonstrated.source, **(source or {})},
        )


@dataclass
class _Ablation:
    """Shared part of the ablation proposers: the full model's lengths, seeded randomness.

    The lengths come from a `SequiturMiner` with the same `min_length` and `max_length`, so
    every proposer respects the same bound.
    """

    num_routines: int = 3
    length_weight: float = 0.1
    alpha: int = 2
    prune_primitives: bool = True
    seed: int = 0
    min_length: int = 2
    max_length: int | None = MAX_ROUTINE_LENGTH

    name = "ablation"

    def __post_init__(self) -> None:
        _check_params(self.num_routines, self.length_weight, self.alpha)
        # The same checks of min_length and max_length.
        SequiturMiner(min_length=self.min_length, max_length=self.max_length)

    def params(self) -> dict[str, Any]:
        """The proposer's name and settings, as the library records them."""
        return {"proposer": self.name, **asdict(self)}

    def mine(
        self,
        actions: Any,
        action_meanings: Sequence[str] | None = None,
        source: dict[str, Any] | None = None,
    ) -> RoutineLibrary:
        demonstrated = _episodes_of(actions)
        episodes = demonstrated.episodes
        index = OccurrenceIndex(episodes)
        selector = _Selector(index, self.length_weight, self.alpha, self.prune_primitives)
        full = SequiturMiner(
            self.num_routines, self.length_weight, self.alpha, self.prune_primitives,
            min_length=self.min_length, max_length=self.max_length,
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lengths = full.mine(episodes).lengths
        rng = np.random.default_rng(self.seed)
        routines = self.propose(episodes, index, selector, lengths, rng)
        accepted = [(r, *selector.score(r)) for r in routines]
        return _build_library(
            accepted,
            index,
            demonstrated,
            self.num_routines,
            self.params(),
            action_meanings if action_meanings is not None else demonstrated.meanings,
            {**demonstrated.source, **(source or {})},
        )

    def propose(self, episodes, index, selector, lengths, rng) -> list[Routine]:
        raise NotImplementedError


@dataclass
class RandomRoutines(_Ablation):
    """RR: routines of the full model's lengths, actions drawn from those in the demo."""

    name = "random"

    def propose(self, episodes, index, selector, lengths, rng) -> list[Routine]:
        present = index.alphabet
        return [tuple(int(a) for a in rng.choice(present, size=n)) for n in lengths]


@dataclass
class EnumerationProposer(_Ablation):
    """PbE: every sequence of each chosen length, scored and pruned like the full model.

    A sequence absent from the demo scores only `λ·|ρ|`, below any that occurs, so the search
    only has to enumerate the demo's own windows unless too few of them survive pruning.
    """

    name = "enumerate"

    def propose(self, episodes, index, selector, lengths, rng) -> list[Routine]:
        accepted: list[Routine] = []
        for n in lengths:
            windows = index.distinct_windows(n)
            best = selector.select(
                [w for w in windows if not selector.near_accepted(w, accepted)], 1
            )
            if best:
                accepted.append(best[0][0])
        return accepted


@dataclass
class RandomFetch(_Ablation):
    """RF: random contiguous slices of the demo, of the full model's lengths."""

    name = "random-fetch"

    def propose(self, episodes, index, selector, lengths, rng) -> list[Routine]:
        out = []
        for n in lengths:
            fitting = [e for e in episodes if e.size >= n]
            e = fitting[int(rng.integers(len(fitting)))]
            start = int(rng.integers(e.size - n + 1))
            out.append(tuple(int(a) for a in e[start : start + n]))
        return out


@dataclass
class RepeatProposer(_Ablation):
    """RP: the k-th most frequent action repeated to the k-th length (FiGAR-style)."""

    name = "repeat"

    def propose(self, episodes, index, selector, lengths, rng) -> list[Routine]:
        actions, counts = np.unique(index.seq, return_counts=True)
        ranked = actions[np.lexsort((actions, -counts))]
        return [(int(ranked[k % ranked.size]),) * n for k, n in enumerate(lengths)]


PROPOSERS: dict[str, type] = {
    "full": SequiturMiner,
    "random": RandomRoutines,
    "enumerate": EnumerationProposer,
    "random-fetch": RandomFetch,
    "repeat": RepeatProposer,
}


def make_proposer(
    name: str = "full",
    num_routines: int = 3,
    length_weight: float = 0.1,
    alpha: int = 2,
    seed: int = 0,
    prune_primitives: bool = True,
    min_length: int = 2,
    max_length: int | None = MAX_ROUTINE_LENGTH,
) -> RoutineProposer:
    """The proposer called `name` (`full`, `random`, `enumerate`, `random-fetch`, `repeat`);
    `min_length` and `max_length` bound the full model's routines, whose lengths the
    ablations copy."""
    if name not in PROPOSERS:
        raise ValueError(f"unknown proposer {name!r}; choose from {', '.join(PROPOSERS)}")
    if name == "full":
        return SequiturMiner(num_routines, length_weight, alpha, prune_primitives,
                             min_length=min_length, max_length=max_length)
    return PROPOSERS[name](num_routines, length_weight, alpha, prune_primitives, seed,
                           min_length, max_length)
