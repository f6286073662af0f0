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

The implementation follows the published algorithm step for step, on flat integer arrays
instead of one object per symbol (that is what makes it fast enough for a million actions in
pure Python). Symbol values are encoded so that a rule can never be confused with an action:
terminal `a` is stored as `2a`, a reference to rule `r` as `2r + 1`, and a rule's guard node
as `-1`.

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

import numpy as np

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
        self.rules = rules
        self.num_episodes = num_episodes
        self._expansions: list[tuple[int, ...]] | None = None

    def __len__(self) -> int:
        return len(self.rules)

    def __str__(self) -> str:
        def show(symbol: Symbol | None) -> str:
            return "|" if symbol is None else repr(symbol)

        return "\n".join(
            f"R{i} -> " + " ".join(show(s) for s in body) for i, body in enumerate(self.rules)
        )

    def _expand_all(self) -> list[tuple[int, ...]]:
        """Expansion of every rule but the start rule, children before parents (memoised)."""
        if self._expansions is None:
            expansions: list[tuple[int, ...] | None] = [None] * len(self.rules)
            for root in range(1, len(self.rules)):
                # Iterative post-order walk: deep grammars (`a` * 2**20) must not recurse.
                stack = [root]
                while stack:
                    r = stack[-1]
                    if expansions[r] is not None:
                        stack.pop()
                        continue
                    pending = [
                        s.index
                        for s in self.rules[r]
                        if isinstance(s, RuleRef) and expansions[s.index] is None
                    ]
                    if pending:
                        stack.extend(pending)
                        continue
                    out: list[int] = []
                    for s in self.rules[r]:
                        if isinstance(s, RuleRef):
                            out.extend(expansions[s.index])  # type: ignore[arg-type]
                        else:
                            out.append(s)  # type: ignore[arg-type]
                    expansions[r] = tuple(out)
                    stack.pop()
            self._expansions = expansions  # type: ignore[assignment]
        return self._expansions  # type: ignore[return-value]

    def expansions(self) -> list[tuple[int, ...]]:
        """The primitive expansion of every non-start rule, in rule order."""
        return self._expand_all()[1:]

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
        expansions = self._expand_all()
        episodes: list[list[int]] = [[]]
        for s in self.rules[0]:
            if s is None:
                episodes.append([])
            elif isinstance(s, RuleRef):
                episodes[-1].extend(expansions[s.index])
            else:
                episodes[-1].append(s)
        return episodes if self.num_episodes > 1 else episodes[0]


def _as_episodes(actions) -> list[np.ndarray]:
    """Validate the input: a sequence of actions, or a sequence of episodes of actions."""
    if isinstance(actions, np.ndarray) and actions.ndim == 1:
        episodes = [actions]
    elif isinstance(actions, Sequence | np.ndarray) and len(actions) > 0 and all(
        isinstance(e, Sequence | np.ndarray) and not isinstance(e, str) for e in actions
    ):
        episodes = list(actions)
    else:
        episodes = [actions]
    out = []
    for i, episode in enumerate(episodes):
        arr = np.asarray(episode)
        if arr.ndim != 1:
            raise ValueError(f"episode {i} must be a 1-D sequence of actions, got shape {arr.shape}")
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


def induce(actions: Sequence[int] | Sequence[Sequence[int]] | np.ndarray) -> Grammar:
    """Infer the Sequitur grammar of one action sequence or of several episodes.

    Args:
        actions: non-negative integer action ids, as one sequence or as a list of episodes.
            No rule spans two episodes.

    Returns:
        The `Grammar`; `grammar.expand()` gives `actions` back.
    """
    episodes = _as_episodes(actions)
    max_action = max((int(e.max()) for e in episodes if e.size), default=0)

    # Symbol storage: parallel arrays indexed by symbol id.
    val: list[int] = []  # 2a for action a, 2r+1 for rule r, _GUARD for a rule's guard node
    nxt: list[int] = []
    prv: list[int] = []
    guard: list[int] = []  # guard symbol id of each rule
    count: list[int] = []  # references to each rule
    guard_rule: dict[int, int] = {}  # guard symbol id -> rule
    table: dict[int, int] = {}  # digram key -> id of the first symbol of its occurrence

    def new_symbol(v: int) -> int:
        val.append(v)
        nxt.append(_NIL)
        prv.append(_NIL)
        if v >= 0 and v & 1:
            count[v >> 1] += 1
        return len(val) - 1

    def new_rule() -> int:
        r = len(guard)
        g = new_symbol(_GUARD)
        nxt[g] = g
        prv[g] = g
        guard.append(g)
        count.append(0)
        guard_rule[g] = r
        return r

    def delete_digram(s: int) -> None:
        n = nxt[s]
        vs, vn = val[s], val[n]
        if vs < 0 or vn < 0:
            return
        k = (vs << 32) | vn
        if table.get(k) == s:
            del table[k]

    def join(left: int, right: int) -> None:
        if nxt[left] != _NIL:
            delete_digram(left)
            # In a run like `aaa` only the first `aa` is indexed; when a symbol of the run is
            # removed, the overlapping digram that remains must be indexed instead.
            rp, rn = prv[right], nxt[right]
            v = val[right]
            if rp != _NIL and rn != _NIL and v >= 0 and v == val[rp] and v == val[rn]:
                table[(v << 32) | v] = right
            lp, ln = prv[left], nxt[left]
            v = val[left]
            if lp != _NIL and ln != _NIL and v >= 0 and v == val[lp] and v == val[ln]:
                table[(v << 32) | v] = lp
        nxt[left] = right
        prv[right] = left

    def insert_after(x: int, y: int) -> None:
        join(y, nxt[x])
        join(x, y)

    def delete(x: int) -> None:
        join(prv[x], nxt[x])
        delete_digram(x)
        v = val[x]
        if v >= 0 and v & 1:
            count[v >> 1] -= 1

    def check(s: int) -> bool:
        """Index the digram starting at `s`, or resolve it if it already occurs."""
        n = nxt[s]
        vs, vn = val[s], val[n]
        if vs < 0 or vn < 0:
            return False
        k = (vs << 32) | vn
        m = table.get(k)
        if m is None:
            table[k] = s
            return False
        if nxt[m] != s and m != s:  # overlapping occurrences (`aaa`) are left alone
            match(s, m)
        return True

    def substitute(s: int, r: int) -> None:
        """Replace the digram starting at `s` by a reference to rule `r`."""
        q = prv[s]
        delete(nxt[q])
        delete(nxt[q])
        insert_after(q, new_symbol(2 * r + 1))
        if not check(q):
            check(nxt[q])

    def match(s: int, m: int) -> None:
        """The digram at `s` repeats the one at `m`: make (or reuse) a rule for it."""
        pm, nn = prv[m], nxt[nxt[m]]
        if val[pm] == _GUARD and val[nn] == _GUARD:
            # The earlier occurrence is the whole body of a rule: reuse that rule.
            r = guard_rule[pm]
            substitute(s, r)
        else:
            r = new_rule()
            g = guard[r]
            insert_after(prv[g], new_symbol(val[s]))
            insert_after(prv[g], new_symbol(val[nxt[s]]))
            substitute(m, r)
            substitute(s, r)
            first = nxt[g]
            table[(val[first] << 32) | val[nxt[first]]] = first
        # Rule utility: the rule at the head of r's body may now be used only once.
        first = nxt[guard[r]]
        v = val[first]
        if v & 1 and count[v >> 1] == 1:
            expand(first)

    def expand(s: int) -> None:
        """`s` is the last use of its rule: put the rule's body in its place."""
        left, right = prv[s], nxt[s]
        r = val[s] >> 1
        g = guard[r]
        f, last = nxt[g], prv[g]
        delete_digram(s)
        join(left, f)
        join(last, right)
        vl, vr = val[last], val[right]
        if vl >= 0 and vr >= 0:
            table[(vl << 32) | vr] = last
        count[r] = 0
        del guard_rule[g]

    start = new_rule()
    start_guard = guard[start]
    # Each separator is a terminal that occurs once, so no digram containing it can repeat.
    separator = max_action + 1

    old_limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(old_limit, 100_000))
    try:
        for i, episode in enumerate(episodes):
            if i > 0:
                s = new_symbol(2 * separator)
                separator += 1
                insert_after(prv[start_guard], s)
                check(prv[s])
            for a in episode.tolist():
                s = new_symbol(2 * a)
                insert_after(prv[start_guard], s)
                check(prv[s])
    finally:
        sys.setrecursionlimit(old_limit)

    return _collect(val, nxt, guard, start, max_action, len(episodes))


def _collect(
    val: list[int], nxt: list[int], guard: list[int], start: int, max_action: int, n_eps: int
) -> Grammar:
    """Read the live rules from the symbol arrays, numbered in order of first appearance."""
    number = {start: 0}
    order = [start]
    rules: list[tuple[Symbol | None, ...]] = []
    i = 0
    while i < len(order):
        r = order[i]
        body: list[Symbol | None] = []
        g = guard[r]
        s = nxt[g]
        while s != g:
            v = val[s]
            if v & 1:
                child = v >> 1
                if child not in number:
                    number[child] = len(order)
                    order.append(child)
                body.append(RuleRef(number[child]))
            elif (v >> 1) > max_action:
                body.append(None)  # episode separator
            else:
                body.append(v >> 1)
            s = nxt[s]
        rules.append(tuple(body))
        i += 1
    return Grammar(rules, n_eps)
