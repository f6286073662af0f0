"""Sequitur (SPEC §2, grammar): the known grammars worked by hand, the four invariants as
properties, episodes, agreement with scikit-sequitur, and the input checks.

Letters stand for actions: a=0, b=1, c=2, d=3. In the hand derivations below, `X` is a rule
while it is being built; the final rules are numbered by first appearance, as `Grammar` does.
"""

from __future__ import annotations

import functools
import random
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from routine_gym.sequitur import Grammar, RuleRef, induce


def _backend_available(backend: str) -> bool:
    try:
        induce([0, 1], backend=backend)
    except ImportError:
        return False
    return True


BACKENDS = [
    "python",
    pytest.param(
        "c",
        marks=pytest.mark.skipif(
            not _backend_available("c"), reason="the compiled core 'sequitur' is not there"
        ),
    ),
]


def letters(word: str) -> list[int]:
    return [ord(c) - ord("a") for c in word]


def bodies(grammar: Grammar) -> list[str]:
    """The rules as `"R1 2 R2"`-style strings, the way the hand derivations write them."""
    return [" ".join("|" if s is None else repr(s) for s in body) for body in grammar.rules]


# -- the invariants, checked independently of the implementation -------------------------------


def assert_invariants(grammar: Grammar, episodes: list[list[int]]) -> None:
    """The four invariants of SPEC §2, plus the episode boundaries."""
    # 1. The start rule gives the input back.
    expected = episodes if len(episodes) > 1 else episodes[0]
    assert grammar.expand() == expected
    assert grammar.num_episodes == len(episodes)

    # Symbols are actions (plain ints), rule references, or episode separators in rule 0 only.
    for i, body in enumerate(grammar.rules):
        for s in body:
            if s is None:
                assert i == 0, f"rule {i} holds an episode separator: it spans a boundary"
            elif isinstance(s, RuleRef):
                assert 1 <= s.index < len(grammar.rules)
            else:
                assert type(s) is int and s >= 0
    assert grammar.rules[0].count(None) == len(episodes) - 1

    # 2. Digram uniqueness: non-overlapping occurrences over all bodies. In a run `x x x` the
    # two `x x` overlap, and Sequitur rightly leaves them alone, so they count once.
    seen: Counter[tuple] = Counter()
    for body in grammar.rules:
        last_start: dict[tuple, int] = {}
        for j in range(len(body) - 1):
            digram = (body[j], body[j + 1])
            if None in digram:  # each separator is a distinct symbol that occurs once
                continue
            if j - last_start.get(digram, -2) >= 2:
                seen[digram] += 1
                last_start[digram] = j
    repeated = {d: n for d, n in seen.items() if n > 1}
    assert not repeated, f"digrams occur twice: {repeated}\n{grammar}"

    # 3. Rule utility: every non-start rule is used at least twice.
    uses = grammar.rule_uses()
    assert uses[0] == 0
    assert all(u >= 2 for u in uses[1:]), f"uses {uses}\n{grammar}"

    # 4. Every non-start rule body has at least two symbols.
    assert all(len(body) >= 2 for body in grammar.rules[1:])

    # The expansions agree with the rules (a rule is its children's expansions concatenated).
    assert len(grammar.expansions()) == len(grammar.rules) - 1
    for body, expansion in zip(grammar.rules[1:], grammar.expansions(), strict=True):
        flat: list[int] = []
        for s in body:
            flat.extend(grammar.expansions()[s.index - 1] if isinstance(s, RuleRef) else [s])
        assert tuple(flat) == expansion


def test_invariant_checker_catches_a_repeated_digram():
    """The digram check counts `x x x x` as two occurrences and `x x x` as one."""
    broken = Grammar([(0, 0, 0, 0)], 1)
    with pytest.raises(AssertionError, match="digrams occur twice"):
        assert_invariants(broken, [[0, 0, 0, 0]])
    assert_invariants(Grammar([(0, 0, 0)], 1), [[0, 0, 0]])


# -- known grammars, worked by hand -----------------------------------------------------------

KNOWN = {
    # a b c d b c: `b c` repeats → X=bc: a X d X. Then a b c → a X d X a X; `a X` repeats →
    # Y=aX: Y d X Y; d → `Y d` repeats → Z=Yd: Z X Z, and Y (used once) is inlined: Z = a X d.
    "abcdbcabcd": ["R1 R2 R1", "0 R2 3", "1 2"],
    # a b c a b → A=ab: A c A; d a b → A c A d A; c → `A c` repeats → B=Ac: B A d B;
    # a b → B A d B A; `B A` repeats → C=BA: C d C, B used once → C = A c A; d → `C d`
    # repeats → D=Cd: D D, C used once → D = A c A d.
    "abcabdabcabd": ["R1 R1", "R2 2 R2 3", "0 1"],
    # a b b b: the two `b b` overlap and are left alone; a b → A=ab: A b b A (the `b b` left
    # behind by removing the first b must stay indexed); c b b → `b b` repeats → B=bb.
    "abbbabcbb": ["R1 R2 R1 2 R2", "0 1", "1 1"],
    # The same shape with c d d d: A=cd, B=dd.
    "cdddcdadd": ["R1 R2 R1 0 R2", "2 3", "3 3"],
    # As `abbbabcbb`, but the run is left of a `c`: A=ab gives A b b c A; c b b → B=bb.
    "abbbcabcbb": ["R1 R2 2 R1 2 R2", "0 1", "1 1"],
    # b b b a b b → X=bb: X b a X; b → Y=Xb, X inlined: Y a Y with Y=bbb; a → Z=Ya, Y inlined:
    # Z Z with Z=bbba; b a → W=ba (inside Z): Z=b b W, Z Z W; b b → V=bb (inside Z, where the
    # `b b` of the old run must still be indexed): Z=V W, Z Z W V.
    "bbbabbbababb": ["R1 R1 R2 R3", "R3 R2", "1 0", "1 1"],
    # a a a: overlapping, nothing; a a a a: `a a` at 2 repeats the one at 0 → A A; then a.
    "aaaaa": ["R1 R1 0", "0 0"],
    # A A after four; A A A after six; A A A A after eight → B=AA: B B.
    "aaaaaaaa": ["R1 R1", "R2 R2", "0 0"],
}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("word", list(KNOWN))
def test_known_grammar(word, backend):
    grammar = induce(letters(word), backend=backend)
    assert bodies(grammar) == KNOWN[word]
    assert_invariants(grammar, [letters(word)])


def test_doc_example_rule_bodies_hold_rule_refs_and_ints():
    """`abcdbcabcd` → R0 -> R1 R2 R1; R1 -> 0 R2 3; R2 -> 1 2, as objects, not strings."""
    grammar = induce([0, 1, 2, 3, 1, 2, 0, 1, 2, 3])
    assert grammar.rules == [
        (RuleRef(1), RuleRef(2), RuleRef(1)),
        (0, RuleRef(2), 3),
        (1, 2),
    ]
    assert grammar.expansions() == [(0, 1, 2, 3), (1, 2)]
    assert grammar.rule_uses() == [0, 2, 2]  # R2 once in R0, once in R1
    assert str(grammar) == "R0 -> R1 R2 R1\nR1 -> 0 R2 3\nR2 -> 1 2"


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize(
    ("n", "expected"),
    [
        (1, ["0 1"]),  # one digram: no repeat, no rule
        (2, ["R1 R1", "0 1"]),
        (3, ["R1 R1 R1", "0 1"]),  # `R1 R1 R1`: the two `R1 R1` overlap
        (4, ["R1 R1", "R2 R2", "0 1"]),
        # after eight: B B with B=AA; then `0 1` is A's whole body, so A is reused.
        (5, ["R1 R1 R2", "R2 R2", "0 1"]),
        (8, ["R1 R1", "R2 R2", "R3 R3", "0 1"]),
        (16, ["R1 R1", "R2 R2", "R3 R3", "R4 R4", "0 1"]),
    ],
)
def test_alternating_pair_builds_a_doubling_hierarchy(n, expected, backend):
    grammar = induce([0, 1] * n, backend=backend)
    assert bodies(grammar) == expected
    assert_invariants(grammar, [[0, 1] * n])


@pytest.mark.parametrize("backend", BACKENDS)
def test_long_run_of_one_action_expands_without_recursion(backend):
    """`a` * 2**14 gives a 14-level chain of `Rk -> Rk+1 Rk+1`, expanded iteratively."""
    grammar = induce([0] * 2**14, backend=backend)
    assert bodies(grammar) == ["R1 R1"] + [f"R{k + 1} R{k + 1}" for k in range(1, 13)] + ["0 0"]
    assert grammar.expansions()[0] == (0,) * 2**13
    assert grammar.expand() == [0] * 2**14


# -- rules are never confused with actions ----------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_action_ids_equal_to_rule_ids_stay_actions(backend):
    # 1 1 2 1 1 → A=11: A 2 A; 2 → B=A2: B B, A inlined: B = 1 1 2; twice more → C=BB.
    seq = [1, 1, 2] * 4
    grammar = induce(seq, backend=backend)
    assert grammar.rules == [(RuleRef(1), RuleRef(1)), (RuleRef(2), RuleRef(2)), (1, 1, 2)]
    # Action 1 inside rule 2 is an action, not a reference to rule 1.
    assert grammar.expansions() == [(1, 1, 2, 1, 1, 2), (1, 1, 2)]
    assert_invariants(grammar, [seq])


@pytest.mark.parametrize("backend", BACKENDS)
def test_actions_zero_to_five_with_rules_one_to_five(backend):
    """Each action k < 6 is used as a terminal while rule k exists."""
    seq = [0, 1, 2, 3, 4, 5] * 8 + [5, 4, 3, 2, 1, 0] * 4 + [1, 1, 2, 2] * 3
    grammar = induce(seq, backend=backend)
    assert len(grammar) >= 6
    assert {s for body in grammar.rules[1:] for s in body if not isinstance(s, RuleRef)} == set(
        range(6)
    )
    assert_invariants(grammar, [seq])


@pytest.mark.parametrize("backend", BACKENDS)
def test_large_action_ids(backend):
    big = 2**30 - 1
    grammar = induce([big, big - 1] * 4, backend=backend)
    assert grammar.rules == [(RuleRef(1), RuleRef(1)), (RuleRef(2), RuleRef(2)), (big, big - 1)]
    # Episode separators are encoded above the largest action: still distinct, still no rule.
    episodes = [[big, 0, big, 0, 1]] * 4
    grammar = induce(episodes, backend=backend)
    assert bodies(grammar) == ["R1 | R1 | R1 | R1", "R2 R2 1", f"{big} 0"]
    assert_invariants(grammar, episodes)


# -- episodes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("backend", BACKENDS)
def test_rule_shared_across_episodes(backend):
    # 0 1 2 | 0 1 → A=01; 2 → `A 2` repeats → B=A2, A inlined: B | B.
    grammar = induce([[0, 1, 2], [0, 1, 2]], backend=backend)
    assert grammar.rules == [(RuleRef(1), None, RuleRef(1)), (0, 1, 2)]
    assert grammar.expand() == [[0, 1, 2], [0, 1, 2]]


@pytest.mark.parametrize("backend", BACKENDS)
def test_no_rule_spans_an_episode_boundary(backend):
    """Joined, `0 1 2 0 1 2` would give a rule; split as `0 1 | 2 0 | 1 2` no digram repeats."""
    episodes = [[0, 1], [2, 0], [1, 2]]
    grammar = induce(episodes, backend=backend)
    assert grammar.rules == [(0, 1, None, 2, 0, None, 1, 2)]
    assert grammar.expand() == episodes
    assert bodies(induce([0, 1, 2, 0, 1, 2], backend=backend)) == ["R1 R1", "0 1 2"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_episodes_are_allowed_and_preserved(backend):
    grammar = induce([[0, 1], [], [0, 1], []], backend=backend)
    assert grammar.rules == [(RuleRef(1), None, None, RuleRef(1), None), (0, 1)]
    assert grammar.expand() == [[0, 1], [], [0, 1], []]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("empty", [[], [[]], np.zeros(0, dtype=np.int64)])
def test_empty_input_gives_an_empty_start_rule(empty, backend):
    grammar = induce(empty, backend=backend)
    assert grammar.rules == [()]
    assert grammar.expand() == []
    assert grammar.expansions() == []


def test_a_single_episode_in_a_list_expands_to_a_flat_list():
    """One episode, given as `[[...]]`, reads like the bare sequence (`num_episodes == 1`)."""
    nested, flat = induce([[0, 1, 0, 1]]), induce([0, 1, 0, 1])
    assert nested.rules == flat.rules
    assert nested.expand() == [0, 1, 0, 1]


def test_numpy_inputs_match_lists():
    seq = [3, 1, 3, 1, 2, 3, 1, 2]
    assert induce(np.array(seq, dtype=np.int32)).rules == induce(seq).rules
    assert induce(np.array(seq, dtype=np.uint8)).rules == induce(seq).rules
    # A 2-D array is read row by row as episodes, like a list of lists.
    grid = np.array([[0, 1, 2], [0, 1, 2]])
    assert induce(grid).rules == induce([[0, 1, 2], [0, 1, 2]]).rules
    assert induce([np.array([0, 1]), np.array([0, 1])]).expand() == [[0, 1], [0, 1]]


# -- properties on random inputs --------------------------------------------------------------

sequences = st.integers(1, 6).flatmap(
    lambda k: st.lists(st.integers(0, k - 1), min_size=0, max_size=300)
)
episode_lists = st.integers(1, 6).flatmap(
    lambda k: st.lists(st.lists(st.integers(0, k - 1), max_size=40), min_size=1, max_size=6)
)


@pytest.mark.parametrize("backend", BACKENDS)
@settings(max_examples=150, deadline=None)
@given(seq=sequences)
def test_invariants_on_random_sequences(seq, backend):
    assert_invariants(induce(seq, backend=backend), [seq])


@pytest.mark.parametrize("backend", BACKENDS)
@settings(max_examples=100, deadline=None)
@given(episodes=episode_lists)
def test_invariants_on_random_episodes(episodes, backend):
    assert_invariants(induce(episodes, backend=backend), episodes)


@settings(max_examples=50, deadline=None)
@given(seq=sequences)
def test_same_input_same_grammar(seq):
    first, second = induce(seq), induce(list(seq))
    assert first.rules == second.rules
    if _backend_available("c"):
        assert induce(seq, backend="c").rules == induce(seq, backend="python").rules


@settings(max_examples=50, deadline=None)
@given(seq=st.lists(st.integers(0, 3), max_size=100), offset=st.integers(1, 2**30 - 5))
def test_grammar_does_not_depend_on_action_values(seq, offset):
    """Relabelling the actions (e.g. to ids far above any rule id) relabels the grammar only."""
    grammar, shifted = induce(seq), induce([a + offset for a in seq])
    assert bodies(shifted) == [
        " ".join(repr(s) if isinstance(s, RuleRef) else str(s + offset) for s in body)
        for body in grammar.rules
    ]


@functools.cache
def scikit_sequitur_cases() -> list[tuple[list[int], Counter]]:
    """1,000 seeded random sequences with scikit-sequitur's rule expansions (computed once)."""
    parse = pytest.importorskip("sksequitur").parse
    rng = random.Random(20240601)
    cases = []
    for _ in range(1000):
        k = rng.randint(1, 6)
        seq = [rng.randrange(k) for _ in range(rng.randint(1, 200))]
        expansions = Counter(
            tuple(int(a) for a in expansion)
            for production, expansion in parse(seq).expansions().items()
            if production != 0
        )
        cases.append((seq, expansions))
    return cases


@pytest.mark.parametrize("backend", BACKENDS)
def test_agrees_with_scikit_sequitur(backend):
    """Same multiset of rule expansions as scikit-sequitur on 1,000 random sequences."""
    for seq, theirs in scikit_sequitur_cases():
        grammar = induce(seq, backend=backend)
        assert Counter(grammar.expansions()) == theirs, seq
        assert_invariants(grammar, [seq])


# -- bad input ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("actions", "error", "match"),
    [
        ([0, 0.5, 1], TypeError, "must be integers, got dtype float64"),
        ([0, float("nan")], TypeError, "must be integers"),
        (["a", "b"], TypeError, "must be integers, got dtype <U1"),
        ([True, False], TypeError, "must be integers, got dtype bool"),
        ([[0, 1], [0.5]], TypeError, "must be integers, got dtype float64 in episode 1"),
        ([0, -1, 2], ValueError, "must be non-negative, got -1"),
        ([[0, 1], [2, -3]], ValueError, "must be non-negative, got -3 in episode 1"),
        ([0, 2**30], ValueError, r"below 2\*\*30, got 1073741824"),
        (np.zeros((2, 2, 2), dtype=np.int64), ValueError, r"1-D .* got shape \(2, 2\)"),
        ([[[0, 1]]], ValueError, r"1-D .* got shape \(1, 2\)"),
        (5, ValueError, r"1-D .* got shape \(\)"),
        ("ab", ValueError, r"1-D .* got shape \(\)"),
    ],
)
def test_bad_actions_are_rejected(actions, error, match):
    with pytest.raises(error, match=match):
        induce(actions)


def test_whole_floats_are_accepted_as_actions():
    """`[0.0, 1.0]` (e.g. actions read from a float array) is taken as `[0, 1]`."""
    grammar = induce(np.array([0.0, 1.0, 0.0, 1.0]))
    assert grammar.rules == [(RuleRef(1), RuleRef(1)), (0, 1)]
    assert all(type(a) is int for a in grammar.expand())


def test_unknown_backend_is_rejected():
    with pytest.raises(ValueError, match="backend must be 'auto', 'c' or 'python', got 'java'"):
        induce([0, 1], backend="java")
