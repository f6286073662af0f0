"""Routine discovery (SPEC §2): frequencies, scores, ordering, pruning, the ablation proposers
and `RoutineLibrary`, against hand-worked examples and brute-force references."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from routine_gym.library import RoutineLibrary
from routine_gym.mining import (
    PROPOSERS,
    EnumerationProposer,
    RandomFetch,
    RandomRoutines,
    RepeatProposer,
    SequiturMiner,
    make_proposer,
)
from routine_gym.occurrences import OccurrenceIndex
from routine_gym.sequitur import induce

# -- brute-force references, written independently of the implementation ----------------------


def brute_occurrences(episodes, routine) -> list[tuple[int, int]]:
    """Every (episode, start) where `routine` occurs, overlaps included."""
    routine = list(routine)
    n = len(routine)
    return [
        (e, s)
        for e, episode in enumerate(episodes)
        for s in range(len(episode) - n + 1)
        if list(episode[s : s + n]) == routine
    ]


def levenshtein(a, b) -> int:
    """Textbook dynamic programme (insertions, deletions, substitutions all cost 1)."""
    row = list(range(len(b) + 1))
    for i, x in enumerate(a, 1):
        prev, row[0] = row[0], i
        for j, y in enumerate(b, 1):
            prev, row[j] = row[j], min(row[j] + 1, row[j - 1] + 1, prev + (x != y))
    return row[-1]


def reference_selection(episodes, num_routines, length_weight, alpha, prune_primitives):
    """SPEC §2 read literally: grammar candidates, score, sort, greedy Levenshtein pruning."""
    candidates = set(induce(episodes).expansions())
    primitives = [(a,) for a in sorted({a for e in episodes for a in e})]
    scored = []
    for routine in candidates:
        f = len(brute_occurrences(episodes, routine))
        scored.append((f + length_weight * len(routine), f, routine))
    scored.sort(key=lambda t: (-round(t[0], 9), -len(t[2]), t[2]))
    accepted: list[tuple[float, int, tuple[int, ...]]] = []
    for score, f, routine in scored:
        if len(accepted) == num_routines:
            break
        blockers = [r for _, _, r in accepted] + (primitives if prune_primitives else [])
        if all(levenshtein(routine, r) >= alpha for r in blockers):
            accepted.append((score, f, routine))
    return accepted


def mine_quietly(miner, actions, **kwargs) -> RoutineLibrary:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return miner.mine(actions, **kwargs)


def miner_with_candidates(candidates, **kwargs) -> SequiturMiner:
    """A SequiturMiner whose proposal phase returns `candidates`: tests the selection alone."""
    miner = SequiturMiner(**kwargs)
    miner.candidates = lambda episodes: list(candidates)  # type: ignore[method-assign]
    return miner


# -- frequencies (OccurrenceIndex) ------------------------------------------------------------


def test_overlapping_occurrences_are_counted():
    index = OccurrenceIndex([[0, 0, 0, 0]])
    assert index.count((0,)) == 4
    assert index.count((0, 0)) == 3
    assert index.count((0, 0, 0)) == 2
    assert index.count((0, 0, 0, 0)) == 1
    assert index.count((0, 0, 0, 0, 0)) == 0
    assert index.occurrences((0, 0)) == ((0, 0), (0, 1), (0, 2))


def test_no_occurrence_across_an_episode_boundary():
    index = OccurrenceIndex([[0, 1], [2, 3, 0], [1, 2]])
    assert index.count((1, 2)) == 1  # only inside episode 2, not across 0|1
    assert index.occurrences((1, 2)) == ((2, 0),)
    assert index.count((0, 1)) == 1  # episode 0; `3 0 | 1` does not count
    assert index.count((3, 0, 1)) == 0
    # Longer than max_gram (4): joined, episodes 0 and 1 would contain 0 1 2 3 0.
    assert index.count((0, 1, 2, 3, 0)) == 0


def test_match_ending_on_the_last_action_is_counted():
    index = OccurrenceIndex([[9, 5, 0, 1], [9, 0, 1, 2, 3, 4]])
    assert index.count((0, 1)) == 2
    assert index.occurrences((0, 1)) == ((0, 2), (1, 1))
    assert index.count((0, 1, 2, 3, 4)) == 1  # length 5 > max_gram, ends on the last action
    assert index.occurrences((0, 1, 2, 3, 4)) == ((1, 1),)


def test_long_routines_are_counted_exactly():
    """Length > max_gram: the Q-gram count is only a bound; `count` must be exact."""
    episode = [0, 1, 2, 3, 4, 0, 1, 2, 3, 5, 0, 1, 2, 3, 4, 1, 2, 3, 4]
    index = OccurrenceIndex([episode])
    # (0,1,2,3) occurs 3 times and (1,2,3,4) 3 times, but (0,1,2,3,4) only twice.
    assert index.upper_bound((0, 1, 2, 3, 4)) == 3
    assert index.count((0, 1, 2, 3, 4)) == 2
    assert index.occurrences((0, 1, 2, 3, 4)) == ((0, 0), (0, 10))


def test_absent_actions_count_zero():
    index = OccurrenceIndex([[0, 1, 2]])
    assert index.count((7,)) == 0
    assert index.count((0, 7)) == 0
    assert index.count((0, 1, 2, 7, 0, 1)) == 0
    assert index.occurrences((0, 1, 2, 7, 0, 1)) == ()


@st.composite
def episodes_and_routine(draw):
    k = draw(st.integers(1, 4))
    action = st.integers(0, k - 1)
    episodes = draw(st.lists(st.lists(action, max_size=40), min_size=1, max_size=5))
    n = draw(st.integers(1, 8))
    # Half the routines are slices of the episodes, so that long ones are found at all.
    long_enough = [e for e in episodes if len(e) >= n]
    if long_enough and draw(st.booleans()):
        e = draw(st.sampled_from(long_enough))
        s = draw(st.integers(0, len(e) - n))
        routine = tuple(e[s : s + n])
    else:
        routine = tuple(draw(st.lists(st.integers(0, k), min_size=n, max_size=n)))
    return episodes, routine


@settings(max_examples=200, deadline=None)
@given(case=episodes_and_routine(), max_gram=st.sampled_from([1, 2, 3, 4]))
def test_occurrence_index_matches_brute_force(case, max_gram):
    episodes, routine = case
    index = OccurrenceIndex(episodes, max_gram=max_gram)
    expected = brute_occurrences(episodes, routine)
    assert index.count(routine) == len(expected)
    assert index.upper_bound(routine) >= len(expected)
    assert list(index.occurrences(routine)) == expected


def brute_bound(episodes, routine, max_gram) -> int:
    """`upper_bound`'s definition: the fewest of the windows of |ρ| actions and of the
    occurrences of each of ρ's q-grams, q = min(|ρ|, Q)."""
    n = len(routine)
    q = min(n, max_gram)
    windows = sum(max(len(e) - n + 1, 0) for e in episodes)
    grams = [routine[j : j + q] for j in range(n - q + 1)]
    return min([windows] + [len(brute_occurrences(episodes, g)) for g in grams])


@settings(max_examples=100, deadline=None)
@given(cases=st.lists(episodes_and_routine(), min_size=1, max_size=6),
       max_gram=st.sampled_from([1, 2, 3, 4]))
def test_bounds_and_counts_of_many_routines_at_once_match_brute_force(cases, max_gram):
    """The miner bounds and counts its candidates in one batch: routines of every length,
    absent actions included, against each one's bound and count worked out alone."""
    episodes = cases[0][0]
    routines = [routine for _, routine in cases]
    index = OccurrenceIndex(episodes, max_gram=max_gram)
    assert index.upper_bounds(routines).tolist() == [
        brute_bound(episodes, r, index.max_gram) for r in routines
    ]
    assert index.counts(routines) == [len(brute_occurrences(episodes, r)) for r in routines]


def test_bounds_of_no_routines_are_empty():
    assert OccurrenceIndex([[0, 1, 0]]).upper_bounds([]).tolist() == []


def test_large_alphabet_lowers_the_gram_size_but_not_the_counts():
    """65,536 distinct actions: 4-gram codes would overflow int64, so Q drops to 3."""
    rng = np.random.default_rng(0)
    episode = rng.permutation(2**16).tolist()
    episode += episode[100:106] + [7] + episode[100:106]
    index = OccurrenceIndex([episode])
    assert index.max_gram == 3
    assert index.count(tuple(episode[100:106])) == 3
    assert index.count(tuple(episode[100:103])) == 3


# -- score, ordering, pruning -----------------------------------------------------------------

# The worked example of SPEC §2. Sequitur, by hand: `2 2` repeats → A; `A 3` repeats → B=223
# (A inlined); `4 4` → C; `C 1` → D=441 (C inlined); `2 2 3` again is B; then `D B` repeats →
# F=D B (D inlined). Grammar: R0 -> B 5 F 0 F; F -> 4 4 1 B; B -> 2 2 3.
# Candidates: (2,2,3) at 0, 7, 14 → f=3, score 3 + 0.1·3 = 3.3;
#             (4,4,1,2,2,3) at 4, 11 → f=2, score 2 + 0.1·6 = 2.6.
# Levenshtein between them is 3 ≥ α=2 and both are longer than 2: both kept.
WORKED = [2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3]


def test_worked_example_grammar():
    # Rules are numbered by first appearance in R0: B is R1, F is R2.
    assert str(induce(WORKED)) == "R0 -> R1 5 R2 0 R2\nR1 -> 2 2 3\nR2 -> 4 4 1 R1"
    assert induce(WORKED).expansions() == [(2, 2, 3), (4, 4, 1, 2, 2, 3)]


def test_worked_example_library():
    with pytest.warns(UserWarning, match="only 2 routine"):
        library = SequiturMiner().mine(WORKED)  # K=3, but there are two candidates
    assert library.routines == ((2, 2, 3), (4, 4, 1, 2, 2, 3))
    assert library.frequencies == (3, 2)
    assert library.scores == pytest.approx((3.3, 2.6))
    assert library.occurrences == (((0, 0), (0, 7), (0, 14)), ((0, 4), (0, 11)))
    assert library.params == {
        "proposer": "full",
        "num_routines": 3,
        "length_weight": 0.1,
        "alpha": 2,
        "prune_primitives": True,
        "max_length": 64,
        "min_length": 2,
    }


@pytest.mark.parametrize(
    ("length_weight", "routines", "scores"),
    [
        (0.0, ((2, 2, 3), (4, 4, 1, 2, 2, 3)), (3.0, 2.0)),
        # λ=1: 3 + 3 = 6 against 2 + 6 = 8, so the long routine now ranks first.
        (1.0, ((4, 4, 1, 2, 2, 3), (2, 2, 3)), (8.0, 6.0)),
    ],
)
def test_length_weight_changes_scores_and_order(length_weight, routines, scores):
    library = SequiturMiner(num_routines=2, length_weight=length_weight).mine(WORKED)
    assert library.routines == routines
    assert library.scores == pytest.approx(scores)


def test_max_length_drops_long_candidates():
    library = mine_quietly(SequiturMiner(max_length=5), WORKED)
    assert library.routines == ((2, 2, 3),)


@pytest.mark.parametrize(("min_length", "routines"), [
    (3, ((2, 2, 3), (4, 4, 1, 2, 2, 3))),  # 3 is the shortest candidate here: nothing dropped
    (4, ((4, 4, 1, 2, 2, 3),)),
    (6, ((4, 4, 1, 2, 2, 3),)),
    (7, ()),  # the grammar's longest expansion has 6 actions
])
def test_min_length_drops_short_candidates(min_length, routines):
    assert mine_quietly(SequiturMiner(min_length=min_length), WORKED).routines == routines


def test_ablations_copy_the_lengths_of_the_full_model_with_min_length():
    library = mine_quietly(make_proposer("random", min_length=4, seed=1), WORKED)
    assert library.lengths == (6,)
    assert library.params["min_length"] == 4


def test_score_ties_go_to_the_longer_routine():
    """With λ=0.6, 5 + 0.6·4 and 2 + 0.6·9 are both 7.4, though not in floating point
    (7.4 against 7.3999999999999995): the tie must still go to the longer routine."""
    short, long = [0, 1, 2, 3], list(range(10, 19))
    demo = [*short, 30, *long, 31, *short, 32, *short, 33, *long, 34, *short, 35, *short]
    library = SequiturMiner(num_routines=2, length_weight=0.6).mine(demo)
    assert library.routines == (tuple(long), tuple(short))
    assert library.frequencies == (2, 5)
    assert library.scores == pytest.approx((7.4, 7.4))


def test_score_and_length_ties_go_lexicographically():
    # (3,4,5) comes first in the demo, but (0,1,2) sorts first; both f=2, score 2.3.
    demo = [3, 4, 5, 9, 0, 1, 2, 8, 3, 4, 5, 7, 0, 1, 2]
    library = SequiturMiner(num_routines=2).mine(demo)
    assert library.routines == ((0, 1, 2), (3, 4, 5))
    assert library.scores == pytest.approx((2.3, 2.3))


# A = (0,1,2,3): f=3, score 3.4. B = (0,1,2,5): f=1, score 1.4, one edit from A.
# C = (0,1,4,5): f=1, score 1.4, two edits from A (one from B). B sorts before C.
PRUNE_DEMO = [0, 1, 2, 3, 9, 0, 1, 2, 3, 9, 0, 1, 2, 3, 8, 0, 1, 2, 5, 8, 0, 1, 4, 5]
A, B, C = (0, 1, 2, 3), (0, 1, 2, 5), (0, 1, 4, 5)


@pytest.mark.parametrize(
    ("alpha", "expected"),
    [
        (1, (A, B, C)),  # distinct routines are ≥ 1 apart: nothing pruned
        (2, (A, C)),  # B is 1 edit from A (< 2): dropped; C is 2 from A: kept
        (3, (A,)),  # C is 2 edits from A (< 3): dropped too
    ],
)
def test_levenshtein_pruning(alpha, expected):
    miner = miner_with_candidates([C, B, A], num_routines=3, alpha=alpha)
    library = mine_quietly(miner, PRUNE_DEMO)
    assert library.routines == expected
    scores = {A: 3.4, B: 1.4, C: 1.4}
    assert library.scores == pytest.approx(tuple(scores[r] for r in expected))


def test_pruning_compares_only_with_accepted_routines():
    """C is 1 edit from B, but B was dropped, so B does not block C."""
    assert levenshtein(B, C) == 1 and levenshtein(A, C) == 2
    library = mine_quietly(miner_with_candidates([A, B, C], alpha=2), PRUNE_DEMO)
    assert C in library.routines


# Grammar: R0 -> A 5 A 6 A 7 C 8 C with A = 0 1 (f=3, 3.2) and C = 2 3 4 (f=2, 2.3).
PRIMITIVE_DEMO = [0, 1, 5, 0, 1, 6, 0, 1, 7, 2, 3, 4, 8, 2, 3, 4]


def test_prune_primitives_removes_length_two_routines():
    with pytest.warns(UserWarning, match="only 1 routine"):
        library = SequiturMiner(num_routines=2).mine(PRIMITIVE_DEMO)
    assert library.routines == ((2, 3, 4),)


def test_without_prune_primitives_length_two_routines_are_kept():
    library = SequiturMiner(num_routines=2, prune_primitives=False).mine(PRIMITIVE_DEMO)
    assert library.routines == ((0, 1), (2, 3, 4))
    assert library.scores == pytest.approx((3.2, 2.3))


def test_prune_primitives_at_alpha_three_removes_length_three():
    miner = miner_with_candidates([(0, 1), (2, 3, 4), A], alpha=3)
    assert mine_quietly(miner, PRIMITIVE_DEMO + PRUNE_DEMO).routines == (A,)


# A demo with many candidates, used for K and the ablations.
STRUCTURED = WORKED * 3 + [0, 1, 5] * 2 + [3] * 4 + [0, 1, 5, 2] + [3] * 4 + [6, 6, 1] * 2


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_num_routines_is_respected_and_greedy(k):
    full = SequiturMiner(num_routines=5).mine(STRUCTURED)
    assert len(full) == 5
    library = SequiturMiner(num_routines=k).mine(STRUCTURED)
    assert len(library) == k
    assert library.routines == full.routines[:k]  # a greedy selection: K=k is a prefix


def test_fewer_candidates_than_k_warns_and_returns_them():
    with pytest.warns(UserWarning, match="only 1 routine.*fewer than the 5 asked for"):
        library = SequiturMiner(num_routines=5).mine([0, 1, 2, 0, 1, 2])
    assert library.routines == ((0, 1, 2),)


def test_no_candidate_at_all_gives_an_empty_library_with_a_warning():
    with pytest.warns(UserWarning, match="only 0 routine"):
        library = SequiturMiner().mine([0, 1, 2, 3])
    assert len(library) == 0


def test_mining_is_deterministic():
    first = SequiturMiner(num_routines=4).mine(STRUCTURED)
    second = SequiturMiner(num_routines=4).mine(list(STRUCTURED))
    assert first == second
    assert first.to_dict() == second.to_dict()


def test_mining_is_deterministic_across_processes():
    code = (
        "import json, sys; from routine_gym.mining import SequiturMiner; "
        f"print(json.dumps(SequiturMiner(num_routines=4).mine({STRUCTURED}).to_dict()))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    here = json.loads(json.dumps(SequiturMiner(num_routines=4).mine(STRUCTURED).to_dict()))
    assert json.loads(out) == here


def test_episodes_are_mined_without_crossing_boundaries():
    # Joined, 0 1 2 would occur three times; split, only `0 1` repeats (twice).
    episodes = [[0, 1, 2, 7], [0, 1], [2, 0, 1, 2]]
    library = SequiturMiner(num_routines=1).mine(episodes)
    assert library.routines == ((0, 1, 2),)
    assert library.frequencies == (2,)
    assert library.occurrences == (((0, 0), (2, 1)),)


# -- the full miner against a literal reading of SPEC §2 --------------------------------------

demos = st.integers(1, 4).flatmap(
    lambda k: st.lists(st.lists(st.integers(0, k - 1), max_size=60), min_size=1, max_size=4)
)


@settings(max_examples=120, deadline=None)
@given(
    episodes=demos,
    k=st.integers(1, 4),
    alpha=st.integers(1, 3),
    length_weight=st.sampled_from([0.0, 0.1, 0.3, 0.6, 1.0]),
    prune_primitives=st.booleans(),
)
def test_miner_properties(episodes, k, alpha, length_weight, prune_primitives):
    assume(max(len(e) for e in episodes) >= 2)
    miner = SequiturMiner(
        num_routines=k, length_weight=length_weight, alpha=alpha, prune_primitives=prune_primitives
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        library = miner.mine(episodes)
    assert (len(library) < k) == any(issubclass(w.category, UserWarning) for w in caught)

    assert len(library) <= k
    for routine, score, f, occ in zip(
        library.routines, library.scores, library.frequencies, library.occurrences, strict=True
    ):
        expected = brute_occurrences(episodes, routine)
        assert expected, f"{routine} is not a contiguous slice of any episode"
        assert f == len(expected)
        assert list(occ) == expected
        assert score == pytest.approx(f + length_weight * len(routine))
        if prune_primitives:
            assert len(routine) >= alpha + 1
    assert all(a >= b - 1e-9 for a, b in pairwise(library.scores))
    for i, r in enumerate(library.routines):
        for s in library.routines[:i]:
            assert levenshtein(r, s) >= alpha

    reference = reference_selection(episodes, k, length_weight, alpha, prune_primitives)
    assert library.routines == tuple(r for _, _, r in reference)
    assert library.frequencies == tuple(f for _, f, _ in reference)


# -- ablation proposers -----------------------------------------------------------------------

# Grammar: R0 -> A A A 7 C C with A = 0 1 2 (f=3, 3.3) and C = 3 4 5 (f=2, 2.3): the full
# model with K=2 gives ((0,1,2), (3,4,5)), lengths (3, 3).
SMALL = [0, 1, 2, 0, 1, 2, 0, 1, 2, 7, 3, 4, 5, 3, 4, 5]


def test_make_proposer_builds_each_kind():
    assert type(make_proposer("full")) is SequiturMiner
    assert type(make_proposer("random")) is RandomRoutines
    assert type(make_proposer("enumerate")) is EnumerationProposer
    assert type(make_proposer("random-fetch")) is RandomFetch
    assert type(make_proposer("repeat")) is RepeatProposer
    assert set(PROPOSERS) == {"full", "random", "enumerate", "random-fetch", "repeat"}
    proposer = make_proposer("random", num_routines=4, alpha=3, seed=7, prune_primitives=False)
    assert proposer.params() == {
        "proposer": "random",
        "num_routines": 4,
        "length_weight": 0.1,
        "alpha": 3,
        "prune_primitives": False,
        "seed": 7,
        "min_length": 2,
        "max_length": 64,
    }


def test_unknown_proposer_name():
    with pytest.raises(ValueError, match="unknown proposer 'sequitur'; choose from full, random"):
        make_proposer("sequitur")


@pytest.mark.parametrize("name", ["random", "enumerate", "random-fetch", "repeat"])
def test_ablations_use_the_full_models_k_and_lengths(name):
    full = SequiturMiner(num_routines=4).mine(STRUCTURED)
    library = make_proposer(name, num_routines=4, seed=3).mine(STRUCTURED)
    assert library.lengths == full.lengths
    assert library.params["proposer"] == name
    index = OccurrenceIndex([STRUCTURED])
    # Frequencies and scores are computed the same way as the full model's.
    assert library.frequencies == tuple(index.count(r) for r in library.routines)
    assert library.scores == pytest.approx(
        tuple(f + 0.1 * len(r) for r, f in zip(library.routines, library.frequencies, strict=True))
    )


@pytest.mark.parametrize("name", ["random", "random-fetch"])
def test_random_ablations_are_seeded(name):
    runs = [make_proposer(name, num_routines=4, seed=s).mine(STRUCTURED) for s in range(8)]
    again = make_proposer(name, num_routines=4, seed=5).mine(STRUCTURED)
    assert again == runs[5]
    assert len({r.routines for r in runs}) > 1


def test_random_routines_use_only_demo_actions():
    present = set(STRUCTURED)
    for seed in range(10):
        library = make_proposer("random", num_routines=4, seed=seed).mine(STRUCTURED)
        assert {a for r in library.routines for a in r} <= present


def test_random_fetch_routines_are_slices_of_the_demo():
    episodes = [STRUCTURED[:30], STRUCTURED[30:]]
    for seed in range(10):
        library = make_proposer("random-fetch", num_routines=4, seed=seed).mine(episodes)
        for routine in library.routines:
            assert brute_occurrences(episodes, routine)


def test_random_fetch_can_fetch_every_slice():
    # The full model gives (0,1,2), so RF fetches length-3 slices: there are four, three distinct.
    demo = [0, 1, 2, 0, 1, 2]
    fetched = {
        make_proposer("random-fetch", num_routines=1, seed=seed).mine(demo).routines[0]
        for seed in range(40)
    }
    assert fetched == {(0, 1, 2), (1, 2, 0), (2, 0, 1)}


def test_repeat_proposer_repeats_the_most_frequent_actions():
    # Counts in SMALL: 0, 1, 2 three times each; 3, 4, 5 twice; 7 once. Ties go to the lower id.
    library = make_proposer("repeat", num_routines=2).mine(SMALL)
    assert library.routines == ((0, 0, 0), (1, 1, 1))
    assert library.frequencies == (0, 0)
    assert library.scores == pytest.approx((0.3, 0.3))


def test_enumeration_picks_the_most_frequent_window_subject_to_pruning():
    # Length-3 windows of SMALL: 012 ×3; 120 ×2, 201 ×2, 345 ×2; the others once.
    # First: (0,1,2), 3.3. Second: 120, 201 and 345 tie at 2.3; (1,2,0) is 2 edits from
    # (0,1,2), so not pruned at α=2, and sorts first. The full model gives (3,4,5) instead.
    library = make_proposer("enumerate", num_routines=2).mine(SMALL)
    assert library.routines == ((0, 1, 2), (1, 2, 0))
    assert library.frequencies == (3, 2)
    assert library.scores == pytest.approx((3.3, 2.3))
    # At α=3 (primitives not pruned, or every length-3 window would be), (1,2,0) and (2,0,1)
    # are 2 edits from (0,1,2): pruned, so (3,4,5) wins. The full model's lengths stay (3, 3):
    # (0,1,2) and (3,4,5) are 3 edits apart.
    proposer = make_proposer("enumerate", num_routines=2, alpha=3, prune_primitives=False)
    library = proposer.mine(SMALL)
    assert library.routines == ((0, 1, 2), (3, 4, 5))


# -- bad input --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("actions", "error", "match"),
    [
        ([], ValueError, "the demonstration is empty"),
        ([[]], ValueError, "the demonstration is empty"),
        ([[], []], ValueError, "the demonstration is empty"),
        ([3], ValueError, "no episode of two or more actions"),
        ([[3], [4]], ValueError, "no episode of two or more actions"),
        ([0, 1.5, 2], TypeError, "actions must be integers"),
        (["UP", "DOWN"], TypeError, "actions must be integers"),
        ([0, -2, 1], ValueError, "actions must be non-negative, got -2"),
    ],
)
@pytest.mark.parametrize("name", ["full", "random", "enumerate", "random-fetch", "repeat"])
def test_bad_demonstrations_are_rejected(name, actions, error, match):
    with pytest.raises(error, match=match):
        make_proposer(name).mine(actions)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"num_routines": 0}, ValueError, "num_routines needs to be ≥ 1, actual value: 0"),
        ({"num_routines": -3}, ValueError, "num_routines needs to be ≥ 1, actual value: -3"),
        ({"num_routines": 2.0}, TypeError, "num_routines must be an int, got float"),
        ({"num_routines": True}, TypeError, "num_routines must be an int, got bool"),
        ({"alpha": 0}, ValueError, "alpha .* needs to be ≥ 1, got 0"),
        ({"length_weight": -0.1}, ValueError, "finite number ≥ 0, got -0.1"),
        ({"length_weight": float("nan")}, ValueError, "length_weight needs to be a finite number"),
        ({"max_length": 1}, ValueError, "max_length needs to be ≥ 2 or None, got 1"),
        ({"min_length": 1}, ValueError, "min_length needs to be an integer ≥ 2, got 1"),
        ({"min_length": 5, "max_length": 4}, ValueError, "min_length 5 is above max_length 4"),
    ],
)
def test_bad_miner_parameters_are_rejected(kwargs, error, match):
    with pytest.raises(error, match=match):
        SequiturMiner(**kwargs)


@pytest.mark.parametrize("name", ["random", "enumerate", "random-fetch", "repeat"])
def test_bad_ablation_parameters_are_rejected(name):
    with pytest.raises(ValueError, match="num_routines needs to be ≥ 1, actual value: 0"):
        make_proposer(name, num_routines=0)
    with pytest.raises(ValueError, match="alpha"):
        make_proposer(name, alpha=0)


# -- mining a Demo ----------------------------------------------------------------------------

MEANINGS = ("NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN")


class FakeDemo:
    """Stands in for routine_gym.demo.Demo: `decision_segments()` and a `meta` dict."""

    def __init__(self, episodes, meta):
        self._episodes = episodes
        self.meta = meta

    def decision_segments(self):
        return ([np.asarray(e, dtype=np.int64) for e in self._episodes],
                [(i, 0) for i in range(len(self._episodes))])


def test_mining_a_demo_carries_meanings_and_provenance():
    demo = FakeDemo(
        [WORKED[:10], WORKED[10:]],
        {
            "env_id": "ALE/Qbert-v5",
            "action_meanings": list(MEANINGS),
            "seeds": [11, 12],
            "env_kwargs": {"frameskip": 4},  # not provenance the library keeps
        },
    )
    library = SequiturMiner(num_routines=1).mine(demo, source={"path": "demos/q.npz"})
    assert library.routines == ((2, 2, 3),)
    assert library.occurrences == (((0, 0), (0, 7), (1, 4)),)
    assert library.action_meanings == MEANINGS
    assert library.source == {"env_id": "ALE/Qbert-v5", "seeds": [11, 12], "path": "demos/q.npz"}
    assert library.name(0) == "UP UP RIGHT"
    # Explicit meanings win over the demo's.
    library = SequiturMiner(num_routines=1).mine(demo, action_meanings=list("abcdef"))
    assert library.name(0) == "c c d"


@pytest.mark.parametrize("name", ["random", "enumerate", "random-fetch", "repeat"])
def test_ablations_mine_a_demo_too(name):
    meanings = [*MEANINGS, "UPRIGHT", "UPLEFT"]  # SMALL uses 8 actions
    demo = FakeDemo([SMALL], {"env_id": "MiniQbert-v0", "action_meanings": meanings})
    library = make_proposer(name, num_routines=2).mine(demo)
    assert library.source == {"env_id": "MiniQbert-v0"}
    assert library.action_meanings == tuple(meanings)


# -- RoutineLibrary ---------------------------------------------------------------------------


def test_library_json_round_trip(tmp_path):
    library = SequiturMiner(num_routines=2).mine(
        WORKED, action_meanings=MEANINGS, source={"env_id": "ALE/Qbert-v5", "seed": 3}
    )
    path = tmp_path / "library.json"
    library.save(path)
    loaded = RoutineLibrary.load(path)
    for field in (
        "routines",
        "scores",
        "frequencies",
        "occurrences",
        "params",
        "source",
        "action_meanings",
    ):
        assert getattr(loaded, field) == getattr(library, field), field
    assert loaded == library
    data = json.loads(path.read_text())
    assert (data["format"], data["version"]) == ("routine-gym/library", 1)
    assert data["routines"] == [[2, 2, 3], [4, 4, 1, 2, 2, 3]]


def test_library_without_meanings_round_trips(tmp_path):
    library = RoutineLibrary(routines=((1, 2), (3, 3, 3)))
    library.save(tmp_path / "l.json")
    assert RoutineLibrary.load(tmp_path / "l.json") == library


def test_describe_shows_action_names():
    library = SequiturMiner(num_routines=2).mine(WORKED, action_meanings=MEANINGS)
    text = library.describe()
    assert str(library) == text
    lines = text.splitlines()
    assert lines[0].startswith("RoutineLibrary: 2 routines (proposer=full, num_routines=2")
    assert lines[1].endswith("UP UP RIGHT")
    assert "score=3.30" in lines[1] and "freq=3" in lines[1]
    assert lines[2].endswith("LEFT LEFT FIRE UP UP RIGHT")
    # Without meanings, the ids; an action beyond the meanings is refused, not shown as "?9".
    assert RoutineLibrary(routines=((2, 2, 3),)).describe().endswith("2 2 3")
    with pytest.raises(ValueError, match=r"routine 0 \[2, 9\] uses action 9, outside"):
        RoutineLibrary(routines=((2, 9),), action_meanings=MEANINGS)


@pytest.mark.parametrize("action", [2.7, "2", True, None])
def test_a_routine_action_must_be_an_integer(action):
    # 2.7 would otherwise be truncated into action 2, a different routine.
    with pytest.raises(ValueError, match="routine 0 has a (non-integer|boolean) action"):
        RoutineLibrary(routines=((1, action),))
    assert RoutineLibrary(routines=((1, 2.0),)).routines == ((1, 2),)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ('{"format": "routine-gym/demo", "version": 1}', "not a routine library"),
        ("[1, 2, 3]", "not a routine library"),
        ('{"format": "routine-gym/library", "version": 99, "routines": []}', "version 99"),
        ('{"format": "routine-gym/library", "version": 1, "routines": [[2, 2', "not valid JSON"),
        ('{"format": "routine-gym/library", "version": 1}', "malformed routine library"),
        (
            '{"format": "routine-gym/library", "version": 1, "routines": [[1, 2]], '
            '"scores": [1.0, 2.0]}',
            "scores has 2 entries for 1 routines",
        ),
    ],
)
def test_loading_a_bad_file_names_the_problem(tmp_path, content, match):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        RoutineLibrary.load(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"routines": ((1, 2), (3, 4)), "scores": (1.0,)}, "scores has 1 entries for 2"),
        ({"routines": ((1, 2),), "frequencies": (1, 2)}, "frequencies has 2 entries for 1"),
        ({"routines": ((1, 2),), "occurrences": ((), ())}, "occurrences has 2 entries for 1"),
        ({"routines": ((1, 2), ())}, "routine 1 is empty"),
        ({"routines": ((1, -2),)}, "routine 0 contains a negative action"),
    ],
)
def test_inconsistent_library_is_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RoutineLibrary(**kwargs)
