"""Byte-pair encoding of demonstrated actions: the candidates of the `bpe` proposer (issue 29).

Byte-pair encoding (Gage 1994; as a proposer of macro-actions, Subwords as Skills, NeurIPS 2024,
and PRISE, ICML 2024) starts from the actions as tokens and repeatedly replaces the most
frequent pair of adjacent tokens by a new token. Every token a merge creates, expanded to
actions, is a candidate routine (`routine_gym.mining.BPEMiner` scores, prunes and picks them as
`SequiturMiner` does its rules).

The rules, fixed here so that the result is deterministic:

- **Boundaries.** Several sequences (episodes, or a demo's decision segments) are encoded side
  by side and no pair spans two of them, so no token crosses an episode boundary or an
  injected step.
- **Counting.** A pair's frequency counts non-overlapping occurrences, as BPE merges them: in a
  run of L equal tokens `x`, the pair `(x, x)` occurs ⌊L/2⌋ times, taken left to right.
- **Ties.** Among the pairs of the highest count, the one whose leftmost occurrence starts
  first (positions in the order the sequences are given, then along each) is merged.
- **How many merges.** Until no pair occurs twice (a token made of a pair seen once is no
  routine), or `max_merges` merges when given.

Token ids: an action keeps its id; the token made by the i-th merge (from 0) is
`num_actions + i`, with `num_actions` one more than the largest action id.

Example:
    >>> from routine_gym.bpe import encode
    >>> encoding = encode([0, 1, 0, 1, 2, 0, 1])
    >>> encoding.merges  # (0, 1) occurs 3 times and becomes token 3; then no pair twice
    ((0, 1),)
    >>> encoding.segments
    ((3, 3, 2, 3),)
    >>> encoding.expansions()
    [(0, 1)]

The tokens are a doubly linked list, each pair keeps the set of its positions, and a heap
orders the pairs by (count, first position), an entry renewed when a merge changes the pair's
occurrences. A merge of k occurrences costs O(k log n) and removes k tokens, so the whole
encoding costs about O(n log n) (plus a recount of a pair `(x, x)`'s positions each time it
reaches the top of the heap after a change), not the O(n) per merge of recounting every pair.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from routine_gym.sequitur import _as_episodes

__all__ = ["Encoding", "encode"]

Pair = tuple[int, int]


@dataclass(frozen=True)
class Encoding:
    """The result of byte-pair encoding a set of action sequences."""

    merges: tuple[Pair, ...]
    """The pair of tokens merged at each step, in order; merge i made token `num_actions + i`."""
    segments: tuple[tuple[int, ...], ...]
    """Each input sequence as the tokens left after the last merge."""
    num_actions: int
    """One more than the largest action id: the id of the first merged token."""
    counts: tuple[int, ...]
    """How many (non-overlapping) occurrences each merge replaced."""

    def length(self, token: int) -> int:
        """How many actions `token` stands for."""
        return len(self.expansion(token))

    def expansion(self, token: int) -> tuple[int, ...]:
        """The actions `token` stands for."""
        if token < 0 or token >= self.num_actions + len(self.merges):
            raise ValueError(f"token {token} is neither an action nor a merge of this encoding "
                             f"(tokens 0..{self.num_actions + len(self.merges) - 1})")
        out: list[int] = []
        stack = [token]
        while stack:
            t = stack.pop()
            if t < self.num_actions:
                out.append(t)
            else:
                left, right = self.merges[t - self.num_actions]
                stack.extend((right, left))
        return tuple(out)

    def expansions(self, max_length: int | None = None) -> list[tuple[int, ...]]:
        """Every merged token in actions, in merge order, the ones longer than `max_length`
        left out (None: all); duplicates are kept (two merges can spell the same actions)."""
        base = self.num_actions
        lengths: list[int] = []  # of the merged tokens
        expanded: dict[int, tuple[int, ...]] = {}

        def actions(token: int) -> tuple[int, ...]:
            # A part of a token kept is no longer than it, so it was kept too.
            return expanded[token] if token >= base else (token,)

        for i, (left, right) in enumerate(self.merges):
            lengths.append(sum(lengths[t - base] if t >= base else 1 for t in (left, right)))
            if max_length is None or lengths[-1] <= max_length:
                expanded[base + i] = actions(left) + actions(right)
        return list(expanded.values())

    def expand(self) -> list[list[int]]:
        """Each sequence back in actions (the input, exactly)."""
        return [[a for t in segment for a in self.expansion(t)] for segment in self.segments]


def _non_overlapping(positions: Sequence[int], nxt: list[int]) -> int:
    """How many of the sorted occurrences of a pair `(x, x)` BPE merges: taken left to right,
    one whose left token is the right token of the last one taken is skipped."""
    count = 0
    blocked = -1
    for p in positions:
        if p != blocked:
            count += 1
            blocked = nxt[p]
    return count


def _linked(episodes: Sequence[np.ndarray]) -> tuple[list[int], list[int], list[int], list[int]]:
    """`(tok, nxt, prv, starts)`: every sequence's tokens in one list, doubly linked, and the
    position of each sequence's first token; -1 ends a sequence, so no pair spans two."""
    tok: list[int] = np.concatenate(episodes).tolist() if episodes else []
    n = len(tok)
    nxt = list(range(1, n + 1))
    prv = list(range(-1, n - 1))
    starts = np.concatenate([[0], np.cumsum([e.size for e in episodes])])[:-1].tolist()
    for e, s in zip(episodes, starts, strict=True):
        if e.size:
            prv[s] = -1
            nxt[s + e.size - 1] = -1
    return tok, nxt, prv, starts


def _pair_positions(tok: list[int], nxt: list[int]
                    ) -> tuple[dict[Pair, set[int]], dict[Pair, list[int]]]:
    """`(where, order)`: every pair's left positions (overlapping ones too), and a lazy min-heap
    of them that gives the pair's first occurrence (a position no longer the pair's is dropped
    when it reaches the top)."""
    where: dict[Pair, set[int]] = {}
    order: dict[Pair, list[int]] = {}
    for p in range(len(tok)):
        q = nxt[p]
        if q >= 0:
            pair = (tok[p], tok[q])
            if pair in where:
                where[pair].add(p)
                order[pair].append(p)  # ascending: already a heap
            else:
                where[pair] = {p}
                order[pair] = [p]
    return where, order


def _segments(episodes: Sequence[np.ndarray], starts: list[int], tok: list[int],
              nxt: list[int]) -> tuple[tuple[int, ...], ...]:
    """The tokens of each sequence, read along the links from its first position."""
    segments = []
    for e, s in zip(episodes, starts, strict=True):
        tokens = []
        p = s if e.size else -1
        while p >= 0:
            tokens.append(tok[p])
            p = nxt[p]
        segments.append(tuple(tokens))
    return tuple(segments)


def encode(actions: Any, max_merges: int | None = None) -> Encoding:
    """Byte-pair encode one sequence of actions or several (episodes, decision segments).

    Args:
        actions: a sequence of integer action ids, or a sequence of such sequences; no pair
            spans two of them.
        max_merges: stop after this many merges (None: when no pair occurs twice).

    Returns:
        The `Encoding`: the merges in order, the final tokens of each sequence.
    """
    if max_merges is not None and (isinstance(max_merges, bool)
                                   or not isinstance(max_merges, int | np.integer)
                                   or max_merges < 1):
        raise ValueError(f"max_merges needs to be an integer ≥ 1 or None, got {max_merges!r}")
    episodes = _as_episodes(actions)
    tok, nxt, prv, starts = _linked(episodes)
    num_actions = max(tok) + 1 if tok else 0
    alive = [True] * len(tok)
    where, order = _pair_positions(tok, nxt)

    def first(pair: Pair) -> int:
        positions = order[pair]
        while positions[0] not in where[pair]:
            heapq.heappop(positions)
        return positions[0]

    # Heap entries (-count, first position, pair, version, exact): an entry is current while
    # its version is the pair's. The count of a pair (x, x) is entered as its overlapping count,
    # an upper bound, and made exact when it reaches the top, so the heap's order is that of
    # the exact (count, first position).
    version: dict[Pair, int] = {}

    def entry(pair: Pair) -> tuple[int, int, Pair, int, bool] | None:
        """The pair's heap entry after a change (None, and forgotten, when it is gone)."""
        version[pair] = version.get(pair, 0) + 1
        if not where.get(pair):
            where.pop(pair, None)
            order.pop(pair, None)
            return None
        return (-len(where[pair]), first(pair), pair, version[pair], pair[0] != pair[1])

    heap = [e for e in map(entry, list(where)) if e is not None]
    heapq.heapify(heap)

    merges: list[Pair] = []
    counts: list[int] = []
    touched: set[Pair] = set()

    def remove(pair: Pair, p: int) -> None:
        where[pair].discard(p)
        touched.add(pair)

    def add(pair: Pair, p: int) -> None:
        if pair in where:
            where[pair].add(p)
            heapq.heappush(order[pair], p)
        else:
            where[pair] = {p}
            order[pair] = [p]
        touched.add(pair)

    while heap and (max_merges is None or len(merges) < max_merges):
        neg, at, pair, v, exact = heapq.heappop(heap)
        if version.get(pair) != v:
            continue
        if not exact:
            count = _non_overlapping(sorted(where[pair]), nxt)
            heapq.heappush(heap, (-count, at, pair, v, True))
            continue
        if -neg < 2:
            break
        x, y = pair
        z = num_actions + len(merges)
        done = 0
        touched.clear()
        for p in sorted(where[pair]):
            # An occurrence overlapped by one merged before it is gone (x == y).
            q = nxt[p]
            if not alive[p] or tok[p] != x or q < 0 or tok[q] != y:
                continue
            a, b = prv[p], nxt[q]
            if a >= 0:
                remove((tok[a], x), a)
            remove(pair, p)
            if b >= 0:
                remove((y, tok[b]), q)
            tok[p] = z
            alive[q] = False
            nxt[p] = b
            if b >= 0:
                prv[b] = p
                add((z, tok[b]), p)
            if a >= 0:
                add((tok[a], z), a)
            done += 1
        merges.append(pair)
        counts.append(done)
        for changed in touched:
            e = entry(changed)
            if e is not None:
                heapq.heappush(heap, e)

    return Encoding(tuple(merges), _segments(episodes, starts, tok, nxt), num_actions,
                    tuple(counts))
