"""The selection phase every proposer shares (SPEC §2): from candidate routines to a library.

A proposer of `routine_gym.mining` hands its candidates to a `_Selector` over the demonstration's
`OccurrenceIndex`: each candidate ρ is scored `f(ρ) + λ_length·|ρ|` (`f`: its occurrences,
overlapping ones included, none across an episode boundary), candidates are visited by
descending score and pruned within Levenshtein distance `α` of an accepted routine (and of the
primitives), and the first K accepted form the `RoutineLibrary` (`_build_library`).
`_Selector.select_authors` is the selection of the authors' released code (SPEC §5b). What a
proposer mines, a demo's decision segments or the episodes given, is read by `_episodes_of`.

The names are private: `routine_gym.mining` is the public face (its proposers, `SELECTIONS`).
"""

from __future__ import annotations

import heapq
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from rapidfuzz.distance import Levenshtein

from routine_gym.library import Routine, RoutineLibrary
from routine_gym.occurrences import OccurrenceIndex
from routine_gym.sequitur import _as_episodes


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

def _check_params(num_routines: int, length_weight: float, alpha: int) -> None:
    if isinstance(num_routines, bool) or not isinstance(num_routines, int | np.integer):
        raise TypeError(f"num_routines must be an int, got {type(num_routines).__name__}")
    if num_routines <= 0:
        raise ValueError(f"num_routines needs to be ≥ 1, actual value: {num_routines}")
    if alpha < 1:
        raise ValueError(f"alpha (the Levenshtein pruning distance) needs to be ≥ 1, got {alpha}")
    if not np.isfinite(length_weight) or length_weight < 0:
        raise ValueError(f"length_weight needs to be a finite number ≥ 0, got {length_weight}")


#: The selection phases `SequiturMiner` offers: the paper's (the default) and the one in the
#: authors' released code (SPEC §5b).
SELECTIONS = ("paper", "authors")


def _check_selection(selection: str) -> None:
    if selection not in SELECTIONS:
        raise ValueError(
            f"selection needs to be one of {', '.join(SELECTIONS)}, actual value: {selection!r}"
        )


def _contains(outer: Routine, inner: Routine) -> bool:
    """Whether `inner` is a contiguous run of `outer` (the authors' `whether_a_contain_b`)."""
    n = len(inner)
    return any(outer[i : i + n] == inner for i in range(len(outer) - n + 1))


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
        kept = [routine for routine in candidates if not self.near_primitive(routine)]
        bounds = self.index.upper_bounds(kept).tolist()
        heap: list[tuple[tuple[float, int, Routine], int, int]] = [
            (_sort_key(bound + self.length_weight * len(routine), routine), 0, 0)
            for routine, bound in zip(kept, bounds, strict=True)
        ]
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

    def select_authors(
        self, candidates: Sequence[Routine], k: int
    ) -> list[tuple[Routine, float, int]]:
        """The selection of the authors' released code (SPEC §5b), on our candidates.

        `make_demo_discover_rt/sq_rt_proposal.py` at 7192f0b, `evaluate_routines`:

        - every candidate is counted, and scored `f / mean f` over all the candidates
          (l. 98, 104); the length weight is never passed on (l. 42, 83: `size_weight=0`),
          so `length_weight` plays no part;
        - one pass over the candidates in rule order (the order `candidates` gives: the
          grammar's rules numbered by first appearance, as their `get_grammar` numbers them
          and `run_sequitur` collects them, l. 55-67; visited l. 87, 102). A candidate within
          `α` of a primitive is dropped (l. 108-111, with `prune_primitives`). Otherwise it
          is compared with the kept routines in the order they were kept, and only with the
          *first* one it conflicts with: Levenshtein `< α`, or either contains the other as
          a contiguous run (l. 118-119). If its score is strictly higher it replaces that
          routine (removed; the candidate goes to the end of the kept list, whatever else it
          conflicts with), else it is dropped (l. 121-127). A candidate with no conflict is
          kept (l. 129-130);
        - the kept routines are sorted by descending score, ties in the order kept (Python's
          stable sort, `rank_one_by_another`), and the first `k` form the library (l. 139-142).

        Their count (l. 89-95) misses an occurrence that ends on the sequence's last action
        (l. 91-92: `end_pos >= len` should be `>`), and that is copied: it changes shipped
        libraries (`bench/results/authors_selection.md`): MinAtar Breakout's routines come in
        another order, MiniQbert's and CoinRun's first routine and ALE Breakout's second lose
        an occurrence, and every demo whose last actions end a candidate gets another mean,
        so other scores. Their code takes one sequence; ours counts episodes (and a demo's
        decision segments) apart, and only the occurrence ending on the last action of the
        last one is missed. Scores are compared as frequencies, which order exactly as
        `f / mean f` do.
        """
        counted = [
            (routine, f - self._ends_the_input(routine))
            for routine, f in zip(candidates, self.index.counts(candidates), strict=True)
        ]
        if not counted:
            return []
        mean_f = sum(f for _, f in counted) / len(counted)
        kept: list[tuple[Routine, int]] = []
        for routine, f in counted:
            if self.near_primitive(routine):
                continue
            for i, (other, g) in enumerate(kept):
                if (self.near_accepted(routine, [other]) or _contains(routine, other)
                        or _contains(other, routine)):
                    if f > g:
                        del kept[i]
                        kept.append((routine, f))
                    break
            else:
                kept.append((routine, f))
        ranked = sorted(kept, key=lambda pair: -pair[1])
        return [(routine, f / mean_f, f) for routine, f in ranked[:k]]

    def _ends_the_input(self, routine: Routine) -> bool:
        """Whether `routine` occurs at the very end of the last episode mined."""
        last = self.index.seq[int(self.index.offsets[-2]):]
        return len(routine) <= last.size and np.array_equal(last[last.size - len(routine):],
                                                            routine)


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
