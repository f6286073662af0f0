"""Occurrences of a routine in demonstrated episodes: the `f(ρ)` of the miners' score (SPEC §2).

`OccurrenceIndex` counts and locates every occurrence of an action sequence in a set of
episodes, overlapping ones included and none across an episode boundary, fast enough for the
miners to score every candidate of a million-action demo (`routine_gym.mining`).

Example:
    >>> from routine_gym.occurrences import OccurrenceIndex
    >>> index = OccurrenceIndex([[0, 1, 0, 1, 0], [1, 0, 1]])
    >>> index.count((0, 1, 0))
    2
    >>> index.occurrences((1, 0))  # (episode, start within the episode)
    ((0, 1), (0, 3), (1, 0))
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from routine_gym.library import Routine

__all__ = ["OccurrenceIndex"]


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
