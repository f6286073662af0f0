"""Routine discovery: from one demonstration's actions to a `RoutineLibrary` (SPEC §2).

`SequiturMiner` is the paper's two-phase method:

1. *Proposal.* Sequitur infers a grammar of the demonstrated actions; every non-start rule,
   expanded to primitive actions, is a candidate (duplicates merged), up to `max_length`
   actions (`MAX_ROUTINE_LENGTH` = 64 by default).
2. *Selection.* Each candidate ρ is scored `f(ρ) + λ_length·|ρ|`, where `f` counts its
   occurrences in the raw action sequence (overlapping ones included, none across an episode
   boundary; `routine_gym.occurrences`). Candidates are visited by descending score (ties:
   longer first, then lexicographic) and accepted unless their Levenshtein distance to an
   accepted routine is `< α`; primitives count as accepted, so with α = 2 no routine of
   length 2 survives. The first K accepted form the library. Every proposer shares this
   phase; it lives in `routine_gym.selection`.

   `selection="authors"` swaps this phase for the one in the authors' released code
   (SPEC §5b; `routine_gym.selection._Selector.select_authors`): score `f / mean f`, no
   length term, and a single pass in rule order in which a candidate too close to, or
   containing or contained in, a kept routine replaces it when its frequency is strictly
   higher.

`BPEMiner` (`make_proposer("bpe")`, `--proposer bpe`) proposes by byte-pair encoding instead
of a grammar (`routine_gym.bpe`; Subwords as Skills, NeurIPS 2024; PRISE, ICML 2024): every
token the merges make, expanded, is a candidate, selected as above.

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

import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from routine_gym.bpe import encode
from routine_gym.library import Routine, RoutineLibrary
from routine_gym.occurrences import OccurrenceIndex, _pairs
from routine_gym.selection import (
    SELECTIONS,
    _build_library,
    _check_params,
    _check_selection,
    _episodes_of,
    _Selector,
)
from routine_gym.sequitur import induce

__all__ = [
    "MAX_ROUTINE_LENGTH",
    "OTHER_PROPOSERS",
    "PROPOSERS",
    "PROPOSER_NAMES",
    "BPEMiner",
    "EnumerationProposer",
    "RandomFetch",
    "RandomRoutines",
    "RepeatProposer",
    "RoutineProposer",
    "SELECTIONS",
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
        selection: `"paper"` (the default, above) or `"authors"`, the selection of the
            authors' released code (`selection._Selector.select_authors`): score `f / mean f`
            with the mean over the candidates kept by `min_length` and `max_length`, no length
            term (`length_weight` is unused), containment pruning, one pass in rule order.
            Recorded in `params` only when `"authors"`, so the default's libraries are as
            before.
    """

    num_routines: int = 3
    length_weight: float = 0.1
    alpha: int = 2
    prune_primitives: bool = True
    max_length: int | None = MAX_ROUTINE_LENGTH
    min_length: int = 2
    selection: str = "paper"

    name = "full"

    def __post_init__(self) -> None:
        _check_params(self.num_routines, self.length_weight, self.alpha)
        _check_selection(self.selection)
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
        """The proposer's name and settings, as the library records them (`selection` only
        when it is not the paper's)."""
        params = {"proposer": self.name, **asdict(self)}
        if self.selection == "paper":
            del params["selection"]
        return params

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
        select = selector.select_authors if self.selection == "authors" else selector.select
        accepted = select(self.candidates(episodes), self.num_routines)
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
class BPEMiner(SequiturMiner):
    """Mine the K best routines of a demonstration with byte-pair encoding instead of Sequitur.

    The proposal phase merges, again and again, the most frequent pair of adjacent tokens of
    the demonstrator's decision segments (`routine_gym.bpe.encode`: pairs never span an episode
    boundary or an injected step; occurrences counted non-overlapping, as BPE merges them;
    ties to the pair whose leftmost occurrence comes first), until no pair occurs twice or
    after `max_merges` merges. Every merged token, expanded to actions, is a candidate
    (duplicates merged, merge order kept, `min_length` and `max_length` applied as to the
    grammar's rules). The selection phase is `SequiturMiner`'s, unchanged: the same score,
    pruning and top K, or with `selection="authors"` the authors' selection, merge order
    standing for rule order.

    Args:
        max_merges: stop after this many merges (None, the default: merge until no pair of
            tokens occurs twice, so that, like Sequitur's rules, every candidate was merged
            from at least two occurrences; each merge removes at least two tokens, so a demo of n
            decisions has fewer than n/2). The other arguments are `SequiturMiner`'s; the
            library's `params` records `proposer="bpe"` and `max_merges`.

    Example:
        >>> from routine_gym.mining import BPEMiner
        >>> library = BPEMiner(num_routines=2).mine(
        ...     [2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3]
        ... )
        >>> library.routines  # merges (2,2) (2,2,3) (4,4) (4,4,1) (4,4,1,2,2,3), then none
        ((2, 2, 3), (4, 4, 1, 2, 2, 3))
        >>> library.frequencies, library.params["proposer"]
        ((3, 2), 'bpe')
    """

    max_merges: int | None = None

    name = "bpe"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.max_merges is not None and (
                isinstance(self.max_merges, bool)
                or not isinstance(self.max_merges, int | np.integer) or self.max_merges < 1):
            raise ValueError(f"max_merges needs to be an integer ≥ 1 or None, got "
                             f"{self.max_merges!r}")

    def candidates(self, episodes: Sequence[np.ndarray]) -> list[Routine]:
        """Every merged token of the encoding, expanded; duplicates merged, merge order kept.

        Tokens longer than `max_length` are never expanded.
        """
        seen = dict.fromkeys(encode(episodes, self.max_merges).expansions(self.max_length))
        return [c for c in seen if self.min_length <= len(c)]


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


#: The paper's proposers (SPEC §2): the full model and its discovery ablations.
PROPOSERS: dict[str, type] = {
    "full": SequiturMiner,
    "random": RandomRoutines,
    "enumerate": EnumerationProposer,
    "random-fetch": RandomFetch,
    "repeat": RepeatProposer,
}
#: Proposers beyond the paper's: byte-pair encoding (`BPEMiner`, issue 29).
OTHER_PROPOSERS: dict[str, type] = {"bpe": BPEMiner}
#: The name of every proposer, the paper's first: the one list of `--proposer`'s choices (the
#: `routine-gym mine` command takes it from here; tests/test_house.py holds the scripts'
#: `Literal`s, which tyro needs spelled out, to it).
PROPOSER_NAMES: tuple[str, ...] = (*PROPOSERS, *OTHER_PROPOSERS)


def make_proposer(
    name: str = "full",
    num_routines: int = 3,
    length_weight: float = 0.1,
    alpha: int = 2,
    seed: int = 0,
    prune_primitives: bool = True,
    min_length: int = 2,
    max_length: int | None = MAX_ROUTINE_LENGTH,
    selection: str = "paper",
) -> RoutineProposer:
    """The proposer called `name` (`full`, `random`, `enumerate`, `random-fetch`, `repeat`,
    `bpe`); `min_length` and `max_length` bound the full model's routines, whose lengths the
    ablations copy, and BPE's; `selection` (`paper` or `authors`, see `SequiturMiner`) is the
    full model's and BPE's only: the ablations score and prune the paper's way."""
    if name not in PROPOSER_NAMES:
        raise ValueError(f"unknown proposer {name!r}; choose from {', '.join(PROPOSER_NAMES)}")
    _check_selection(selection)
    if name in ("full", "bpe"):
        miner = SequiturMiner if name == "full" else BPEMiner
        return miner(num_routines, length_weight, alpha, prune_primitives,
                     min_length=min_length, max_length=max_length, selection=selection)
    if selection != "paper":
        raise ValueError(
            f"selection {selection!r} is the full and bpe proposers' only; the {name!r} "
            "ablation scores and prunes the paper's way"
        )
    return PROPOSERS[name](num_routines, length_weight, alpha, prune_primitives, seed,
                           min_length, max_length)
