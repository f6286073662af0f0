"""Sequitur: infer a hierarchical grammar from a sequence in linear time.

Sequitur (Nevill-Manning & Witten, 1997) reads the sequence one symbol at a time and keeps two
properties of its grammar true after every symbol:

- *digram uniqueness*: no pair of adjacent symbols appears more than once in the grammar;
  a repeated pair becomes a rule (or reuses the rule whose whole body it is);
- *rule utility*: every rule is used at least twice; a rule used once is inlined.

RAPL reads every non-start rule, expanded to primitive actions, as a routine candidate.

Several episodes can be given at once. They are joined with separators that occur once each,
so no digram (and so no rule) spans an episode boundary while rules are still shared across
episodes.

`_induce_python` is the reference implementation: it follows the published algorithm step for
step, on flat integer arrays instead of one object per symbol. Symbol values are encoded so that
a rule can never be confused with an action: terminal `a` is stored as `2a`, a reference to rule
`r` as `2r + 1`, and a rule's guard node as `-1`. The compiled core `sequitur`
(`routine_gym/_native/_sequitur.cpp`, built by `pip install` where there is a C++17 compiler)
ports it function for function, with an explicit stack instead of recursion, and gives the
same grammar about 14 times faster (a million actions in about 0.4 s instead of 5.5 s); `induce`
uses it where `routine_gym._native.core("sequitur")` finds it (built, and not turned off by
`ROUTINE_GYM_NATIVE`). The core
also expands the rules (`Grammar.expansions`, the miner's candidates) from its flat output, so
a grammar built by it decodes its rule bodies into Python objects only when they are read.

Example:
    >>> from routine_gym.sequitur import induce
    >>> grammar = induce([0, 1, 2, 3, 1, 2, 0, 1, 2, 3])
    >>> print(grammar)
    R0 -> R1 R2 R1
    R1 -> 0 R2 3
    R2 -> 1 2
    >>> grammar.expansions()
    [(0, 1, 2, 3), (1, 2)]
    >>> grammar.expand()
    [0, 1, 2, 3, 1, 2, 0, 1, 2, 3]
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from types import ModuleType
from typing import Literal

import numpy as np

from routine_gym import _native

__all__ = ["Grammar", "RuleRef", "induce"]

_NIL = -1
_GUARD = -1


@dataclass(frozen=True, slots=True)
class RuleRef:
    """A reference to rule `index` inside a rule body (actions are plain `int`s)."""

    index: int

    def __repr__(self) -> str:
        return f"R{self.index}"


Symbol = int | RuleRef


class Grammar:
    """The grammar Sequitur inferred: rule 0 generates the input, rules 1.. are the structure.

    Attributes:
        rules: the rule bodies; `rules[0]` is the start rule. A body holds actions (`int`) and
            `RuleRef`s. In the start rule, episodes are separated by `None`.
        num_episodes: how many episodes the input had.
    """

    def __init__(self, rules: list[tuple[Symbol | None, ...]], num_episodes: int) -> None:
        self._rules: list[tuple[Symbol | None, ...]] | None = rules
        self.num_episodes = num_episodes
        self._expansions: dict[int, tuple[int, ...]] = {}
        self._lengths: list[int] | None = None
        # `induce`'s flat rules (offsets, codes, max_action) and the compiled core that reads
        # them; None for a grammar built from rule bodies or by the Python backend.
        self._flat: tuple[np.ndarray, np.ndarray, int] | None = None
        self._core: ModuleType | None = None

    @classmethod
    def _from_flat(
        cls, offsets: np.ndarray, codes: np.ndarray, max_action: int, num_episodes: int,
        core: ModuleType | None,
    ) -> Grammar:
        """The grammar of flat `(offsets, codes)` (see `_collect`), its rule bodies decoded
        on first use: the miner only wants the expansions, which the core reads from the
        flat form (decoding a million-action grammar's bodies costs more than its rules)."""
        grammar = cls([], num_episodes)
        grammar._rules = None  # decoded from `_flat` when first read
        grammar._flat = (offsets, codes, max_action)
        grammar._core = core
        return grammar

    @property
    def rules(self) -> list[tuple[Symbol | None, ...]]:
        """The rule bodies (see the class docstring)."""
        if self._rules is None:
            assert self._flat is not None
            self._rules = _decode(*self._flat)
        return self._rules

    def __len__(self) -> int:
        if self._rules is None and self._flat is not None:
            return self._flat[0].size - 1
        return len(self.rules)

    def __str__(self) -> str:
        def show(symbol: Symbol | None) -> str:
            return "|" if symbol is None else repr(symbol)

        return "\n".join(
            f"R{i} -> " + " ".join(show(s) for s in body) for i, body in enumerate(self.rules)
        )

    def expansion_lengths(self) -> list[int]:
        """How many actions each rule expands to (rule 0: the whole input, separators
        excluded), computed from the rule bodies without expanding anything."""
        if self._lengths is None and self._core is not None:
            self._core_expansions(0)  # sets the lengths; no rule is 0 actions long
        if self._lengths is None:
            lengths = [-1] * len(self.rules)
            for root in range(len(self.rules)):
                # Iterative post-order walk: deep grammars (`a` * 2**20) must not recurse.
                stack = [root]
                while stack:
                    r = stack[-1]
                    if lengths[r] >= 0:
                        stack.pop()
                        continue
                    pending = [
                        s.index
                        for s in self.rules[r]
                        if isinstance(s, RuleRef) and lengths[s.index] < 0
                    ]
                    if pending:
                        stack.extend(pending)
                        continue
                    lengths[r] = sum(
                        lengths[s.index] if isinstance(s, RuleRef) else s is not None
                        for s in self.rules[r]
                    )
                    stack.pop()
            self._lengths = lengths
        return self._lengths

    def _expansion(self, root: int) -> tuple[int, ...]:
        """Expansion of non-start rule `root`, its sub-rules' memoised on the way."""
        expansions = self._expansions
        stack = [root]
        while stack:
            r = stack[-1]
            if r in expansions:
                stack.pop()
                continue
            pending = [
                s.index
                for s in self.rules[r]
                if isinstance(s, RuleRef) and s.index not in expansions
            ]
            if pending:
                stack.extend(pending)
                continue
            out: list[int] = []
            for s in self.rules[r]:
                if isinstance(s, RuleRef):
                    out.extend(expansions[s.index])
                else:
                    out.append(s)  # type: ignore[arg-type]
            expansions[r] = tuple(out)
            stack.pop()
        return expansions[root]

    def expansions(self, max_length: int | None = None) -> list[tuple[int, ...]]:
        """The primitive expansion of every non-start rule, in rule order.

        With `max_length`, only the rules of at most that many actions, and only they are
        expanded (their lengths come from `expansion_lengths`): the rules of `a` * 2**20
        expand to 2, 4, ..., 2**19 actions, of which a miner bounded at 64 wants five.
        """
        if self._core is not None:
            return self._core_expansions(-1 if max_length is None else max_length)
        if max_length is None:
            return [self._expansion(r) for r in range(1, len(self.rules))]
        lengths = self.expansion_lengths()
        return [
            self._expansion(r) for r in range(1, len(self.rules)) if lengths[r] <= max_length
        ]

    def _core_expansions(self, max_length: int) -> list[tuple[int, ...]]:
        """`expansions(max_length)` by the compiled core (every rule when `max_length` < 0);
        it gives `expansion_lengths` on the way."""
        assert self._flat is not None and self._core is not None
        offsets, codes, max_action = self._flat
        raw_lengths, raw_actions = self._core.expansions(offsets, codes, max_action, max_length)
        lengths = np.frombuffer(raw_lengths, dtype=np.int64).tolist()
        self._lengths = lengths
        actions = np.frombuffer(raw_actions, dtype=np.int64).tolist()
        out = []
        end = 0
        for n in lengths[1:]:
            if max_length < 0 or n <= max_length:
                start, end = end, end + n
                out.append(tuple(actions[start:end]))
        return out

    def rule_uses(self) -> list[int]:
        """How many times each rule is referenced in the grammar (rule 0: 0)."""
        uses = [0] * len(self.rules)
        for body in self.rules:
            for s in body:
                if isinstance(s, RuleRef):
                    uses[s.index] += 1
        return uses

    def expand(self) -> list[int] | list[list[int]]:
        """The input back: one list of actions, or a list of episodes if several were given."""
        episodes: list[list[int]] = [[]]
        for s in self.rules[0]:
            if s is None:
                episodes.append([])
            elif isinstance(s, RuleRef):
                episodes[-1].extend(self._expansion(s.index))
            else:
                episodes[-1].append(s)
        return episodes if self.num_episodes > 1 else episodes[0]


def _as_episodes(actions) -> list[np.ndarray]:
    """Validate the input: a sequence of actions, or a sequence of episodes of actions."""
    if isinstance(actions, np.ndarray) and actions.ndim == 1:
        episodes = [actions]
    elif (
        isinstance(actions, Sequence | np.ndarray)
        and len(actions) > 0
        and all(isinstance(e, Sequence | np.ndarray) and not isinstance(e, str) for e in actions)
    ):
        episodes = list(actions)
    else:
        episodes = [actions]
    out = []
    for i, episode in enumerate(episodes):
        arr = np.asarray(episode)
        if arr.ndim != 1:
            raise ValueError(
                f"episode {i} must be a 1-D sequence of actions, got shape {arr.shape}"
            )
        if arr.size and not np.issubdtype(arr.dtype, np.integer):
            if np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)):
                arr = arr.astype(np.int64)
            else:
                raise TypeError(f"actions must be integers, got dtype {arr.dtype} in episode {i}")
        if arr.size and arr.min() < 0:
            raise ValueError(f"actions must be non-negative, got {int(arr.min())} in episode {i}")
        if arr.size and arr.max() >= 2**30:
            raise ValueError(f"action ids must be below 2**30, got {int(arr.max())}")
        out.append(arr.astype(np.int64, copy=False))
    return out


def induce(
    actions: Sequence[int] | Sequence[Sequence[int]] | np.ndarray,
    backend: Literal["auto", "c", "python"] = "auto",
) -> Grammar:
    """Infer the Sequitur grammar of one action sequence or of several episodes.

    Args:
        actions: non-negative integer action ids below 2**30, as one sequence or as a list of
            episodes. No rule spans two episodes.
        backend: `"c"` runs the compiled core (ImportError where it is not built or is
            turned off), `"python"` the pure-Python reference, `"auto"` the compiled core where
            `routine_gym._native.core` finds it and otherwise the reference (with its one-time
            warning where the core is not built). Both give the same grammar.

    Returns:
        The `Grammar`; `grammar.expand()` gives `actions` back.
    """
    core = _backend_module(backend)
    episodes = _as_episodes(actions)
    encoded, max_action = _encode(episodes)
    if core is None:
        offsets, codes = _induce_python(encoded)
        return Grammar(_decode(offsets, codes, max_action), len(episodes))
    raw_offsets, raw_codes = core.induce(encoded)
    offsets = np.frombuffer(raw_offsets, dtype=np.int64)
    codes = np.frombuffer(raw_codes, dtype=np.int64)
    return Grammar._from_flat(offsets, codes, max_action, len(episodes), core)


def _backend_module(backend: str) -> ModuleType | None:
    """The compiled core for `backend`, or None for the pure-Python reference."""
    if backend == "python":
        return None
    if backend == "c":
        reason = _native.unavailable("sequitur")
        if reason is not None:
            raise ImportError(f"backend='c' needs the compiled core 'sequitur': {reason}; use "
                              "backend='python'")
        return _native.core("sequitur")
    if backend != "auto":
        raise ValueError(f"backend must be 'auto', 'c' or 'python', got {backend!r}")
    return _native.core("sequitur")


def _encode(episodes: list[np.ndarray]) -> tuple[np.ndarray, int]:
    """The symbol values to append, episodes joined by separators; and the largest action.

    Each separator is a terminal above every action that occurs once, so no digram containing
    it can repeat.
    """
    max_action = max((int(e.max()) for e in episodes if e.size), default=0)
    parts: list[np.ndarray] = []
    for i, episode in enumerate(episodes):
        if i > 0:
            parts.append(np.array([2 * (max_action + i)], dtype=np.int64))
        parts.append(2 * episode)
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.int64), max_action


class _PythonSequitur:
    """The reference Sequitur's state and steps: the symbols of every rule body, as parallel
    arrays indexed by symbol id, and the index of the digrams that occur.

    Each rule body is a circular doubly linked list through its guard node. The methods are the
    steps of the published algorithm (and the functions of the C++ core): `check` indexes a new
    digram or resolves a repeated one (`match`), `substitute` replaces a digram by a rule
    reference, and `expand` inlines a rule that is used only once (rule utility).
    """

    def __init__(self) -> None:
        self.val: list[int] = []  # 2a for action a, 2r+1 for rule r, _GUARD for a guard node
        self.nxt: list[int] = []
        self.prv: list[int] = []
        self.guard: list[int] = []  # guard symbol id of each rule
        self.count: list[int] = []  # references to each rule
        self.guard_rule: dict[int, int] = {}  # guard symbol id -> rule
        self.table: dict[int, int] = {}  # digram key -> id of the first symbol of its occurrence

    def new_symbol(self, v: int) -> int:
        self.val.append(v)
        self.nxt.append(_NIL)
        self.prv.append(_NIL)
        if v >= 0 and v & 1:
            self.count[v >> 1] += 1
        return len(self.val) - 1

    def new_rule(self) -> int:
        r = len(self.guard)
        g = self.new_symbol(_GUARD)
        self.nxt[g] = g
        self.prv[g] = g
        self.guard.append(g)
        self.count.append(0)
        self.guard_rule[g] = r
        return r

    def append(self, rule: int, v: int) -> None:
        """Add symbol value `v` at the end of `rule` and enforce digram uniqueness."""
        s = self.new_symbol(v)
        self.insert_after(self.prv[self.guard[rule]], s)
        self.check(self.prv[s])

    def delete_digram(self, s: int) -> None:
        val, table = self.val, self.table
        vs, vn = val[s], val[self.nxt[s]]
        if vs < 0 or vn < 0:
            return
        k = (vs << 32) | vn
        if table.get(k) == s:
            del table[k]

    def join(self, left: int, right: int) -> None:
        val, nxt, prv = self.val, self.nxt, self.prv
        if nxt[left] != _NIL:
            self.delete_digram(left)
            # In a run like `aaa` only the first `aa` is indexed; when a symbol of the run is
            # removed, the overlapping digram that remains must be indexed instead.
            rp, rn = prv[right], nxt[right]
            v = val[right]
            if rp != _NIL and rn != _NIL and v >= 0 and v == val[rp] and v == val[rn]:
                self.table[(v << 32) | v] = right
            lp, ln = prv[left], nxt[left]
            v = val[left]
            if lp != _NIL and ln != _NIL and v >= 0 and v == val[lp] and v == val[ln]:
                self.table[(v << 32) | v] = lp
        nxt[left] = right
        prv[right] = left

    def insert_after(self, x: int, y: int) -> None:
        self.join(y, self.nxt[x])
        self.join(x, y)

    def delete(self, x: int) -> None:
        self.join(self.prv[x], self.nxt[x])
        self.delete_digram(x)
        v = self.val[x]
        if v >= 0 and v & 1:
            self.count[v >> 1] -= 1

    def check(self, s: int) -> bool:
        """Index the digram starting at `s`, or resolve it if it already occurs."""
        val, nxt = self.val, self.nxt
        vs, vn = val[s], val[nxt[s]]
        if vs < 0 or vn < 0:
            return False
        k = (vs << 32) | vn
        m = self.table.get(k)
        if m is None:
            self.table[k] = s
            return False
        if nxt[m] != s and m != s:  # overlapping occurrences (`aaa`) are left alone
            self.match(s, m)
        return True

    def substitute(self, s: int, r: int) -> None:
        """Replace the digram starting at `s` by a reference to rule `r`."""
        q = self.prv[s]
        self.delete(self.nxt[q])
        self.delete(self.nxt[q])
        self.insert_after(q, self.new_symbol(2 * r + 1))
        if not self.check(q):
            self.check(self.nxt[q])

    def match(self, s: int, m: int) -> None:
        """The digram at `s` repeats the one at `m`: make (or reuse) a rule for it."""
        val, nxt, prv = self.val, self.nxt, self.prv
        pm, nn = prv[m], nxt[nxt[m]]
        if val[pm] == _GUARD and val[nn] == _GUARD:
            # The earlier occurrence is the whole body of a rule: reuse that rule.
            r = self.guard_rule[pm]
            self.substitute(s, r)
        else:
            r = self.new_rule()
            g = self.guard[r]
            self.insert_after(prv[g], self.new_symbol(val[s]))
            self.insert_after(prv[g], self.new_symbol(val[nxt[s]]))
            self.substitute(m, r)
            self.substitute(s, r)
            first = nxt[g]
            self.table[(val[first] << 32) | val[nxt[first]]] = first
        # Rule utility: the rule at the head of r's body may now be used only once.
        first = nxt[self.guard[r]]
        v = val[first]
        if v & 1 and self.count[v >> 1] == 1:
            self.expand(first)

    def expand(self, s: int) -> None:
        """`s` is the last use of its rule: put the rule's body in its place."""
        val, nxt, prv = self.val, self.nxt, self.prv
        left, right = prv[s], nxt[s]
        r = val[s] >> 1
        g = self.guard[r]
        f, last = nxt[g], prv[g]
        self.delete_digram(s)
        self.join(left, f)
        self.join(last, right)
        vl, vr = val[last], val[right]
        if vl >= 0 and vr >= 0:
            self.table[(vl << 32) | vr] = last
        self.count[r] = 0
        del self.guard_rule[g]


def _induce_python(encoded: np.ndarray) -> tuple[list[int], list[int]]:
    """Reference Sequitur over encoded symbol values; returns the live rules as `_collect` does."""
    sequitur = _PythonSequitur()
    start = sequitur.new_rule()
    old_limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(old_limit, 100_000))
    try:
        for v in encoded.tolist():
            sequitur.append(start, v)
    finally:
        sys.setrecursionlimit(old_limit)
    return _collect(sequitur.val, sequitur.nxt, sequitur.guard, start)


def _collect(
    val: list[int], nxt: list[int], guard: list[int], start: int
) -> tuple[list[int], list[int]]:
    """The live rules, numbered in order of first appearance, as flat `(offsets, codes)`.

    Rule `i` is `codes[offsets[i]:offsets[i + 1]]`; a code is `2a` for terminal `a` (episode
    separators included) and `2k + 1` for a reference to rule number `k`.
    """
    number = {start: 0}
    order = [start]
    offsets = [0]
    codes: list[int] = []
    i = 0
    while i < len(order):
        g = guard[order[i]]
        s = nxt[g]
        while s != g:
            v = val[s]
            if v & 1:
                child = v >> 1
                if child not in number:
                    number[child] = len(order)
                    order.append(child)
                codes.append(2 * number[child] + 1)
            else:
                codes.append(v)
            s = nxt[s]
        offsets.append(len(codes))
        i += 1
    return offsets, codes


def _decode(
    offsets: Sequence[int] | np.ndarray,
    codes: Sequence[int] | np.ndarray,
    max_action: int,
) -> list[tuple[Symbol | None, ...]]:
    """Turn flat `(offsets, codes)` into rule bodies (actions, `RuleRef`s, `None` separators)."""
    codes = np.asarray(codes, dtype=np.int64)
    offsets = np.asarray(offsets, dtype=np.int64)
    # Vectorised: a million-action grammar has ~10^5 codes, too many for a per-code Python branch.
    decoded = codes >> 1
    symbols = decoded.astype(object)
    is_rule = (codes & 1).astype(bool)
    refs = np.empty(len(offsets) - 1, dtype=object)
    refs[:] = [RuleRef(k) for k in range(len(refs))]
    symbols[is_rule] = refs[decoded[is_rule]]
    symbols[~is_rule & (decoded > max_action)] = None
    flat = symbols.tolist()
    return [tuple(flat[a:b]) for a, b in pairwise(offsets.tolist())]
