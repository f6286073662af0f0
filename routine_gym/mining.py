"""Routine discovery: from one demonstration's actions to a `RoutineLibrary` (SPEC §2).

`SequiturMiner` is the paper's two-phase method:

1. *Proposal.* Sequitur infers a grammar of the demonstrated actions; every non-start rule,
   expanded to primitive actions, is a candidate (duplicates merged).
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
    each of its Q-grams), and located by filtering the positions of that Q-gram. The miner
    uses the bound to count exactly only the candidates that can still make the library.
    """

    def __init__(self, episodes: Sequence[np.ndarray], max_gram: int = 4) -> None:
        episodes = [np.asarray(e, dtype=np.int64) for e in episodes]
        lengths = np.array([e.size for e in episodes], dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(lengths)])
        raw = np.concatenate(episodes) if episodes else np.zeros(0, dtype=np.int64)
        self.seq = raw
        self.episode_of = np.repeat(np.arange(lengths.size), lengths)
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

    def upper_bound(self, routine: Sequence[int]) -> int:
        """A cheap upper bound of `count(routine)`; exact for routines of ≤ max_gram actions."""
        q = min(len(routine), self.max_gram)
        counts = self._gram_counts(q)
        bound = self.seq.size
        for j in range(len(routine) - q + 1):
            code = self._encode(routine[j : j + q])
            bound = min(bound, 0 if code is None else counts.get(code, 0))
            if bound == 0:
                break
        return bound

    def positions(self, routine: Sequence[int]) -> np.ndarray:
        """Start positions (in the concatenated episodes) of every occurrence, ascending."""
        routine = tuple(int(a) for a in routine)
        n, q = len(routine), min(len(routine), self.max_gram)
        if n <= self.max_gram:
            code = self._encode(routine)
            if code is None:
                return np.zeros(0, dtype=np.int64)
            return np.flatnonzero(self.window_codes(n) == code)
        # Start from the rarest Q-gram of the routine, then check the other actions.
        best, best_slice = 0, (0, 0)
        for j in range(n - q + 1):
            code = self._encode(routine[j : j + q])
            if code is None:
                return np.zeros(0, dtype=np.int64)
            i = int(np.searchsorted(self._keys, code))
            if i == self._keys.size or self._keys[i] != code:
                return np.zeros(0, dtype=np.int64)
            span = (int(self._starts[i]), int(self._ends[i]))
            if j == 0 or span[1] - span[0] < best_slice[1] - best_slice[0]:
                best, best_slice = j, span
        p = self._positions[best_slice[0] : best_slice[1]] - best
        p = p[(p >= 0) & (p + n <= self.seq.size)]
        p = p[self.episode_of[p] == self.episode_of[p + n - 1]]
        for j in range(n):
            if best <= j < best + q:
                continue
            p = p[self.seq[p + j] == routine[j]]
        return p

    def count(self, routine: Sequence[int]) -> int:
        """f(ρ): overlapping occurrences, none across an episode boundary."""
        if len(routine) <= self.max_gram:
            return self.upper_bound(routine)
        return int(self.positions(routine).size)

    def occurrences(self, routine: Sequence[int]) -> tuple[tuple[int, int], ...]:
        """Every occurrence as `(episode, start within the episode)`."""
        p = self.positions(routine)
        ep = self.episode_of[p]
        return tuple(zip(ep.tolist(), (p - self.offsets[ep]).tolist(), strict=True))


@dataclass(frozen=True)
class _Demonstrated:
    """What a proposer mines: the sequences, and where each one starts in the demo."""

    episodes: list[np.ndarray]
    """The sequences mined: a demo's decision segments, or the episodes given."""
    starts: list[tuple[int, int]] | None
    """`(episode, step)` of each sequence's first action in the demo (None: as given)."""
    meanings: Sequence[str] | None
    source: dict[str, Any]

    def occurrences(self, index: OccurrenceIndex, routine: Routine) -> tuple[tuple[int, int], ...]:
        """`index.occurrences(routine)` as `(episode, step)` positions in the demo."""
        found = index.occurrences(routine)
        if self.starts is None:
            return found
        return tuple((self.starts[s][0], self.starts[s][1] + t) for s, t in found)


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
        demonstrated.occurrences(index, tuple(int(a) for a in r)) for r in routines
    )


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
        bound (its rarest Q-gram's count), and is counted only when that bound reaches the top.
        """
        heap: list[tuple[tuple[float, int, Routine], bool, int]] = []
        for routine in candidates:
            if self.near_primitive(routine):
                continue
            bound = self.index.upper_bound(routine)
            heap.append((_sort_key(bound + self.length_weight * len(routine), routine), False, 0))
        heapq.heapify(heap)
        accepted: list[tuple[Routine, float, int]] = []
        while heap and len(accepted) < k:
            key, exact, f = heapq.heappop(heap)
            routine = key[2]
            if not exact:
                score, f = self.score(routine)
                heapq.heappush(heap, (_sort_key(score, routine), True, f))
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
        max_length: ignore candidates longer than this (None: no limit).
        min_length: ignore candidates shorter than this (the scalability experiment's longer
            routines; 2 keeps every candidate).
    """

    num_routines: int = 3
    length_weight: float = 0.1
    alpha: int = 2
    prune_primitives: bool = True
    max_length: int | None = None
    min_length: int = 2

    name = "full"

    def __post_init__(self) -> None:
        _check_params(self.num_routines, self.length_weight, self.alpha)
        if self.max_length is not None and self.max_length < 2:
            raise ValueError(f"max_length needs to be ≥ 2 or None, got {self.max_length}")
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
        """Every non-start rule of the grammar, expanded; duplicates merged, order kept."""
        seen = dict.fromkeys(induce(episodes).expansions())
        longest = self.max_length if self.max_length is not None else float("inf")
        return [c for c in seen if self.min_length <= len(c) <= longest]

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
    """Shared part of the ablation proposers: the full model's lengths, seeded randomness."""

    num_routines: int = 3
    length_weight: float = 0.1
    alpha: int = 2
    prune_primitives: bool = True
    seed: int = 0
    min_length: int = 2

    name = "ablation"

    def __post_init__(self) -> None:
        _check_params(self.num_routines, self.length_weight, self.alpha)
        SequiturMiner(min_length=self.min_length)  # the same check of min_length

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
            min_length=self.min_length,
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
            windows = {
                tuple(w)
                for e in episodes
                if e.size >= n
                for w in np.lib.stride_tricks.sliding_window_view(e, n).tolist()
            }
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
) -> RoutineProposer:
    """The proposer called `name` (`full`, `random`, `enumerate`, `random-fetch`, `repeat`);
    `min_length` is the full model's shortest routine, whose lengths the ablations copy."""
    if name not in PROPOSERS:
        raise ValueError(f"unknown proposer {name!r}; choose from {', '.join(PROPOSERS)}")
    if name == "full":
        return SequiturMiner(num_routines, length_weight, alpha, prune_primitives,
                             min_length=min_length)
    return PROPOSERS[name](num_routines, length_weight, alpha, prune_primitives, seed,
                           min_length)
