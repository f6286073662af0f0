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
from itertools import chain

import numpy as np

from routine_gym.library import Routine

__all__ = ["OccurrenceIndex"]


class OccurrenceIndex:
    """Counts and locates every (overlapping) occurrence of a routine in a set of episodes.

    Every window of q ≤ Q consecutive actions inside an episode gets an integer code, and the
    codes are counted once (a table by code when the alphabet is small, else the sorted codes
    that occur), so a routine of up to Q actions is counted by one look-up, and the miner's
    ~10^4 candidates all at once (`upper_bounds`). A longer routine is bounded from above by
    the count of its rarest Q-gram (an occurrence of ρ contains one of each of its Q-grams) and
    by the number of windows of its length, and located by filtering the positions of that
    Q-gram. The miner uses the bound to count exactly only the candidates that can still make
    the library.

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
        self.alphabet, self._dense = _dense_actions(raw)
        self._dense_id = {int(a): i for i, a in enumerate(self.alphabet.tolist())}
        base = max(int(self.alphabet.size), 1)
        self._base = base
        self.max_gram = 1
        while self.max_gram < max_gram and base ** (self.max_gram + 1) < 2**62:
            self.max_gram += 1
        self._codes: dict[int, np.ndarray] = {}
        self._counts: dict[int, tuple[np.ndarray | None, np.ndarray]] = {}
        # The Q-grams' positions sorted by code (`_sorted_grams`), built when a routine longer
        # than Q is first located: scoring alone never needs them.
        self._sorted: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
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

    def _gram_counts(self, q: int) -> tuple[np.ndarray | None, np.ndarray]:
        """How often each q-gram occurs inside an episode, by window code: `(None, counts)`
        indexed by code when there are few possible codes (one counting pass), else
        `(keys, counts)` with the codes that occur, ascending (a sort)."""
        if q not in self._counts:
            codes = self.window_codes(q)
            codes = codes[codes >= 0]
            possible = self._base**q
            if possible <= max(2 * codes.size, 2**16):
                self._counts[q] = (None, np.bincount(codes, minlength=possible))
            else:
                self._counts[q] = np.unique(codes, return_counts=True)
        return self._counts[q]

    def _count_codes(self, q: int, codes: np.ndarray) -> np.ndarray:
        """The count of each q-gram code in `codes` (0 for a code that never occurs or is
        -1, a gram with an action absent from the episodes)."""
        keys, counts = self._gram_counts(q)
        if keys is None:
            return np.where(codes >= 0, counts[np.maximum(codes, 0)], 0)
        if keys.size == 0:
            return np.zeros(codes.size, dtype=np.int64)
        i = np.minimum(np.searchsorted(keys, codes), keys.size - 1)
        return np.where(keys[i] == codes, counts[i], 0)

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
        _, keys, starts, ends = self._sorted_grams()
        i = np.minimum(np.searchsorted(keys, codes), max(keys.size - 1, 0))
        if keys.size == 0 or not np.array_equal(keys[i], codes):
            return None
        return starts[i], ends[i]

    def _sorted_grams(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The start of every Q-gram inside an episode, sorted by code (stably: ascending
        within a code), with the codes that occur and each one's slice of the starts."""
        if self._sorted is None:
            codes = self.window_codes(self.max_gram)
            valid = np.flatnonzero(codes >= 0)
            positions = valid[_stable_argsort(codes[valid], self._base**self.max_gram)]
            keys, starts, counts = np.unique(
                codes[positions], return_index=True, return_counts=True
            )
            self._sorted = (positions, keys, starts, starts + counts)
        return self._sorted

    def num_windows(self, length: int) -> int:
        """How many windows of `length` actions lie inside an episode: a bound of any count."""
        return int(self._num_windows(np.array([length], dtype=np.int64))[0])

    def _num_windows(self, lengths: np.ndarray) -> np.ndarray:
        """`num_windows` of each of `lengths`."""
        i = np.searchsorted(self._sorted_lengths, lengths)
        return self._length_tail[i] - (self._sorted_lengths.size - i) * (lengths - 1)

    def upper_bound(self, routine: Sequence[int]) -> int:
        """A cheap upper bound of `count(routine)`; exact for routines of ≤ max_gram actions."""
        return int(self.upper_bounds([routine])[0])

    def upper_bounds(self, routines: Sequence[Sequence[int]]) -> np.ndarray:
        """`upper_bound` of each (non-empty) routine, all in a few vectorised passes: the
        miner bounds every candidate of a demo at once (~10^4 for a million actions).

        The bound of a routine of n actions is the smallest of the number of windows of n
        actions and the counts of its q-grams, q = min(n, Q): with n ≤ Q its own count.
        """
        lengths = np.fromiter(map(len, routines), dtype=np.int64, count=len(routines))
        bounds = self._num_windows(lengths)
        grams = np.minimum(lengths, self.max_gram)
        for q in np.unique(grams).tolist():
            group = np.flatnonzero(grams == q)
            members = [routines[i] for i in group.tolist()]
            bounds[group] = np.minimum(bounds[group], self._rarest_gram_counts(members, q))
        return bounds

    def _rarest_gram_counts(self, routines: Sequence[Sequence[int]], q: int) -> np.ndarray:
        """For routines of ≥ q actions each, the smallest count of any of their q-grams."""
        lengths = np.fromiter(map(len, routines), dtype=np.int64, count=len(routines))
        flat = np.fromiter(chain.from_iterable(routines), dtype=np.int64, count=int(lengths.sum()))
        dense = self._dense_or_absent(flat)
        # The routines lie end to end: the q-gram at p is a gram of its routine when it ends
        # inside it, and has a code when every action of it occurs in the episodes.
        m = flat.size - q + 1
        codes = np.zeros(m, dtype=np.int64)
        present = np.ones(m, dtype=bool)
        for j in range(q):
            codes = codes * self._base + np.maximum(dense[j : j + m], 0)
            present &= dense[j : j + m] >= 0
        ends = np.cumsum(lengths)
        inside = np.arange(m) + q <= np.repeat(ends, lengths)[:m]
        counts = np.full(flat.size, np.iinfo(np.int64).max, dtype=np.int64)
        counts[:m][inside] = self._count_codes(q, np.where(present, codes, -1)[inside])
        return np.minimum.reduceat(counts, ends - lengths)

    def _dense_or_absent(self, actions: np.ndarray) -> np.ndarray:
        """The dense id of each action, -1 for an action the episodes never hold."""
        if self.alphabet.size == 0:
            return np.full(actions.size, -1, dtype=np.int64)
        i = np.minimum(np.searchsorted(self.alphabet, actions), self.alphabet.size - 1)
        return np.where(self.alphabet[i] == actions, i, -1)

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
        p = self._sorted_grams()[0][spans[0][best] : spans[1][best]] - best
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

    def counts(self, routines: Sequence[Sequence[int]]) -> list[int]:
        """`count` of each routine; those of ≤ max_gram actions in one vectorised pass."""
        short = [i for i, r in enumerate(routines) if len(r) <= self.max_gram]
        exact = self.upper_bounds([routines[i] for i in short]).tolist()
        out = dict(zip(short, exact, strict=True))
        return [out[i] if i in out else self.count(r) for i, r in enumerate(routines)]

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


def _dense_actions(actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.unique(actions, return_inverse=True)`: the actions present, ascending, and each
    action's index among them; by counting when the action ids are small (a million actions
    of a few ids: one pass instead of a sort)."""
    if actions.size and actions.min() >= 0 and actions.max() < max(2 * actions.size, 2**16):
        present = np.bincount(actions) > 0
        return np.flatnonzero(present), (np.cumsum(present) - 1)[actions]
    alphabet, dense = np.unique(actions, return_inverse=True)
    return alphabet, dense.astype(np.int64)


def _stable_argsort(keys: np.ndarray, bound: int) -> np.ndarray:
    """`np.argsort(keys, kind="stable")` of non-negative keys below `bound`: numpy radix-sorts
    16-bit keys (one pass, where the merge sort of int64 keys compares n log n times)."""
    if bound <= 2**16:
        keys = keys.astype(np.uint16)
    return np.argsort(keys, kind="stable")


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
