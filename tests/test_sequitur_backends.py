"""The compiled Sequitur core gives exactly the grammar of the pure-Python reference."""

import threading
import warnings

import numpy as np
import pytest

from routine_gym import _native
from routine_gym.sequitur import Grammar, RuleRef, induce

core = _native.core("sequitur")
if core is None:  # not built, or ROUTINE_GYM_NATIVE turns it off: the Python twin alone
    pytest.skip(f"sequitur: {_native.unavailable('sequitur')}", allow_module_level=True)

R1, R2 = RuleRef(1), RuleRef(2)


def letters(word: str) -> list[int]:
    return [ord(c) - ord("a") for c in word]


def assert_backends_agree(actions) -> Grammar:
    compiled = induce(actions, backend="c")
    reference = induce(actions, backend="python")
    assert compiled.rules == reference.rules, actions
    assert compiled.num_episodes == reference.num_episodes
    return compiled


def assert_sequitur_invariants(grammar: Grammar) -> None:
    """Digram uniqueness, rule utility, bodies of two symbols or more."""
    seen: set[tuple] = set()
    for body in grammar.rules:
        for i in range(len(body) - 1):
            pair = (body[i], body[i + 1])
            if None in pair or (pair[0] == pair[1] and i > 0 and body[i - 1] == pair[0]):
                continue  # separators never repeat; `aaa` holds `aa` twice, overlapping
            assert pair not in seen, pair
            seen.add(pair)
    assert all(uses >= 2 for uses in grammar.rule_uses()[1:])
    assert all(len(body) >= 2 for body in grammar.rules[1:])


@pytest.mark.parametrize(
    ("word", "expected"),
    [
        # Worked by hand: each repeated digram becomes a rule the moment it repeats.
        ("abbbabcbb", [(R1, R2, R1, 2, R2), (0, 1), (1, 1)]),
        ("cdddcdadd", [(R1, R2, R1, 0, R2), (2, 3), (3, 3)]),
        ("aaaaa", [(R1, R1, 0), (0, 0)]),
        ("abcdbcabcd", [(R1, R2, R1), (0, R2, 3), (1, 2)]),
    ],
)
def test_both_backends_give_the_hand_worked_grammar_on_hard_cases(word, expected):
    grammar = assert_backends_agree(letters(word))
    assert grammar.rules == expected


def test_backends_agree_on_1200_random_sequences():
    rng = np.random.default_rng(2024)
    for _ in range(1200):
        alphabet = int(rng.integers(1, 7))
        length = int(rng.integers(0, 300))
        actions = rng.integers(0, alphabet, size=length).tolist()
        grammar = assert_backends_agree(actions)
        assert grammar.expand() == actions


def test_backends_agree_on_random_multi_episode_inputs():
    rng = np.random.default_rng(7)
    for _ in range(300):
        alphabet = int(rng.integers(1, 7))
        episodes = [
            rng.integers(0, alphabet, size=int(rng.integers(0, 80))).tolist()
            for _ in range(int(rng.integers(2, 6)))
        ]
        grammar = assert_backends_agree(episodes)
        assert grammar.expand() == episodes
        assert grammar.rules[0].count(None) == len(episodes) - 1


def assert_core_expansions_are_the_reference_walk(actions) -> None:
    """The core's rule lengths and bounded expansions (what the miner reads) equal the Python
    walk over the same grammar's rule bodies."""
    compiled = induce(actions, backend="c")
    walked = Grammar(compiled.rules, compiled.num_episodes)  # the Python walk
    for max_length in (None, 2, 3, 7, 64):
        assert induce(actions, backend="c").expansions(max_length) == walked.expansions(
            max_length
        ), (actions, max_length)
    assert compiled.expansion_lengths() == walked.expansion_lengths()


def test_core_expansions_equal_the_python_walk_on_random_inputs():
    rng = np.random.default_rng(5)
    for _ in range(300):
        alphabet = int(rng.integers(1, 7))
        episodes = [
            rng.integers(0, alphabet, size=int(rng.integers(0, 150))).tolist()
            for _ in range(int(rng.integers(1, 4)))
        ]
        assert_core_expansions_are_the_reference_walk(episodes)


@pytest.mark.parametrize(
    "actions", [[], [5], [[], []], [0] * 2**12, [0, 1] * 3000, [[2**30 - 1, 0] * 5, [1] * 9]]
)
def test_core_expansions_equal_the_python_walk_on_edge_cases(actions):
    assert_core_expansions_are_the_reference_walk(actions)


def test_core_expansions_reject_rules_that_are_not_a_grammar():
    """The core reads flat rules from Python: a reference past the last rule or a cycle of
    references is refused, not followed."""
    offsets = np.array([0, 1, 2], dtype=np.int64).tobytes()
    with pytest.raises(ValueError, match="refers to no rule"):
        core.expansions(offsets, np.array([5, 0], dtype=np.int64).tobytes(), 0, -1)
    with pytest.raises(ValueError, match="cycle"):
        core.expansions(offsets, np.array([3, 3], dtype=np.int64).tobytes(), 0, -1)


@pytest.mark.parametrize(
    ("actions", "expected"),
    [([], [()]), ([5], [(5,)]), ([[], []], [(None,)]), ([[0], [0], [0]], [(0, None, 0, None, 0)])],
)
def test_both_backends_handle_empty_and_single_action_inputs(actions, expected):
    assert assert_backends_agree(actions).rules == expected


def test_episode_separators_stop_rules_at_the_boundary():
    grammar = assert_backends_agree([[0, 1, 0, 1], [0, 1, 2]])
    assert grammar.rules == [(R1, R1, None, R1, 2), (0, 1)]


@pytest.mark.parametrize("pattern", [[0], [0, 1], [0, 1, 2]])
def test_backends_agree_on_long_periodic_runs(pattern):
    actions = pattern * (100_000 // len(pattern))
    grammar = assert_backends_agree(actions)
    assert grammar.expand() == actions
    # A periodic run folds into a doubling hierarchy: about log2(10**5) = 17 rules, not 10**4.
    assert len(grammar) <= 20


@pytest.mark.parametrize("pattern", [[0], [0, 1]])
def test_compiled_core_survives_million_action_runs(pattern):
    # The reference recurses as deep as the grammar; the core must not touch the C stack.
    actions = np.array(pattern * (1_000_000 // len(pattern)), dtype=np.int64)
    grammar = induce(actions, backend="c")
    assert np.array_equal(grammar.expand(), actions)
    assert_sequitur_invariants(grammar)


def test_backends_agree_on_action_ids_up_to_2_pow_30():
    top = 2**30 - 1
    rng = np.random.default_rng(3)
    # Ids next to rule numbers (1, 2, 3) and at the top of the range, where 2a + 1 or a
    # separator above the largest action would overflow 32 bits.
    ids = np.array([0, 1, 2, 3, 2**29, top - 1, top])
    for _ in range(200):
        actions = ids[rng.integers(0, len(ids), size=int(rng.integers(0, 120)))].tolist()
        assert assert_backends_agree(actions).expand() == actions
    episodes = [[top, 0, top, 0], [top, 0, 1], [1, top, 0]]
    grammar = assert_backends_agree(episodes)
    assert grammar.expand() == episodes
    assert grammar.rules[1] == (top, 0)


def test_backends_agree_on_a_structured_sequence_of_100k_actions():
    rng = np.random.default_rng(11)
    motifs = [rng.integers(0, 6, size=int(rng.integers(2, 8))).tolist() for _ in range(20)]
    actions: list[int] = []
    while len(actions) < 100_000:
        if rng.random() < 0.7:
            actions.extend(motifs[int(rng.integers(20))])
        else:
            actions.extend(rng.integers(0, 6, size=3).tolist())
    grammar = assert_backends_agree(actions)
    assert grammar.expand() == actions
    assert_sequitur_invariants(grammar)


def test_core_reads_bytes_and_arrays_alike():
    encoded = 2 * np.array(letters("abcdbcabcd"), dtype=np.int64)
    offsets, codes = core.induce(encoded)
    assert core.induce(encoded.tobytes()) == (offsets, codes)
    # R0 -> R1 R2 R1, R1 -> 0 R2 3, R2 -> 1 2: references to rule k are 2k + 1, actions 2a
    assert np.frombuffer(offsets, dtype=np.int64).tolist() == [0, 3, 6, 8]
    assert np.frombuffer(codes, dtype=np.int64).tolist() == [3, 5, 3, 0, 5, 6, 2, 4]


def test_core_rejects_a_buffer_that_is_not_int64():
    with pytest.raises(TypeError, match="int64"):
        core.induce(np.zeros(4, dtype=np.int32))


def test_compiled_core_is_safe_to_run_from_several_threads():
    rng = np.random.default_rng(5)
    inputs = [rng.integers(0, 4, size=20_000) for _ in range(4)]
    expected = [induce(x, backend="c").rules for x in inputs]
    results: dict[int, list] = {}

    def work(i: int) -> None:
        results[i] = induce(inputs[i], backend="c").rules

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [results[i] for i in range(4)] == expected


def test_auto_backend_uses_the_compiled_core_without_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert induce([0, 1, 0, 1], backend="auto").rules == [(R1, R1), (0, 1)]


def _not_built(monkeypatch) -> None:
    """The loader as it is where the core was not built (its import failed)."""
    monkeypatch.setattr(_native, "_loaded", {"sequitur": "no module named _sequitur"})
    monkeypatch.setattr(_native, "_warned", set())


def test_auto_backend_falls_back_to_python_and_warns_once(monkeypatch):
    _not_built(monkeypatch)
    with pytest.warns(RuntimeWarning, match="no module named _sequitur"):
        assert induce([0, 1, 0, 1]).rules == [(R1, R1), (0, 1)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        induce([0, 1, 0, 1])


def test_turned_off_the_auto_backend_runs_python_without_a_warning(monkeypatch):
    monkeypatch.setenv("ROUTINE_GYM_NATIVE", "0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert induce([0, 1, 0, 1]).rules == [(R1, R1), (0, 1)]
    with pytest.raises(ImportError, match="ROUTINE_GYM_NATIVE=0 turns it off"):
        induce([0, 1], backend="c")


def test_c_backend_without_the_core_raises_import_error(monkeypatch):
    _not_built(monkeypatch)
    with pytest.raises(ImportError, match="no module named _sequitur; use backend='python'"):
        induce([0, 1], backend="c")


def test_unknown_backend_is_rejected_by_name():
    with pytest.raises(ValueError, match="'cpp'"):
        induce([0, 1], backend="cpp")
