"""The `bpe` proposer (issue 29): byte-pair encoding of the demonstrator's decisions
(`routine_gym.bpe.encode`) and `BPEMiner`, which selects among its merged tokens with Sequitur's
own scoring, pruning and top-K. Merges worked out by hand; a naive BPE as the reference on
random inputs; `routine-gym mine DEMO --proposer bpe` as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys
import typing
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from routine_gym.bpe import encode
from routine_gym.demo import Demo, shipped_demo_path
from routine_gym.mining import (
    OTHER_PROPOSERS,
    BPEMiner,
    SequiturMiner,
    _episodes_of,
    _Selector,
    make_proposer,
)
from routine_gym.occurrences import OccurrenceIndex

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent  # the venv a user installs into


def mine_quietly(miner, actions):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return miner.mine(actions)


# -- merges worked out by hand ----------------------------------------------------------------


@pytest.mark.parametrize(("actions", "merges", "segments", "counts"), [
    # [0,1,0,1,2,0,1]: (0,1) ×3, the rest once → (0,1) becomes 3: [3,3,2,3]; then (3,3),
    # (3,2), (2,3) once each → stop.
    ([0, 1, 0, 1, 2, 0, 1], [(0, 1)], [[3, 3, 2, 3]], [3]),
    # [0,1,2]×3 + [3]: (0,1) ×3 and (1,2) ×3 tie; (0,1) starts first (position 0) → 4:
    # [4,2,4,2,4,2,3]; (4,2) ×3 → 5: [5,5,5,3]; (5,5) occurs twice overlapping but once
    # non-overlapping, (5,3) once → stop.
    ([0, 1, 2, 0, 1, 2, 0, 1, 2, 3], [(0, 1), (4, 2)], [[5, 5, 5, 3]], [3, 3]),
    # [0]×5: (0,0) non-overlapping ×2 (positions 0 and 2; 4 overlaps nothing but has no
    # partner) → 1: [1,1,0]; (1,1), (1,0) once → stop.
    ([0, 0, 0, 0, 0], [(0, 0)], [[1, 1, 0]], [2]),
    # [0]×8: (0,0) ×4 → 1: [1,1,1,1]; (1,1) ×2 → 2: [2,2]; (2,2) once → stop.
    ([0] * 8, [(0, 0), (1, 1)], [[2, 2]], [4, 2]),
    # The docstring example of BPEMiner: (2,2) ×3 and (2,3) ×3 tie, (2,2) first → 6:
    # [6,3,5,4,4,1,6,3,0,4,4,1,6,3]; (6,3) ×3 → 7: [7,5,4,4,1,7,0,4,4,1,7]; (4,4), (4,1),
    # (1,7) ×2, (4,4) first → 8: [7,5,8,1,7,0,8,1,7]; (8,1), (1,7) ×2, (8,1) first → 9:
    # [7,5,9,7,0,9,7]; (9,7) ×2 → 10: [7,5,10,0,10]; nothing twice → stop.
    ([2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3],
     [(2, 2), (6, 3), (4, 4), (8, 1), (9, 7)], [[7, 5, 10, 0, 10]], [3, 3, 2, 2, 2]),
    # Nothing occurs twice: no merge.
    ([0, 1, 2, 3], [], [[0, 1, 2, 3]], []),
])
def test_hand_worked_merges(actions, merges, segments, counts):
    encoding = encode(actions)
    assert encoding.merges == tuple(merges)
    assert encoding.segments == tuple(tuple(s) for s in segments)
    assert encoding.counts == tuple(counts)
    assert encoding.num_actions == max(actions) + 1
    assert encoding.expand() == [list(actions)]


def test_expansions_of_the_hand_worked_example_are_the_candidates_in_merge_order():
    encoding = encode([2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3])
    assert encoding.expansions() == [(2, 2), (2, 2, 3), (4, 4), (4, 4, 1), (4, 4, 1, 2, 2, 3)]
    assert encoding.expansions(max_length=3) == [(2, 2), (2, 2, 3), (4, 4), (4, 4, 1)]
    assert encoding.expansion(10) == (4, 4, 1, 2, 2, 3) and encoding.length(10) == 6
    assert encoding.expansion(5) == (5,)
    with pytest.raises(ValueError, match="token 11 is neither an action nor a merge"):
        encoding.expansion(11)


def test_large_action_ids_cost_nothing_and_merged_tokens_follow_the_largest():
    # Action ids up to 2**30 are allowed: the first merged token is the largest id + 1.
    big = 2**30 - 1
    encoding = encode([big, 5, big, 5, 7])
    assert encoding.merges == ((big, 5),) and encoding.num_actions == 2**30
    assert encoding.segments == ((2**30, 2**30, 7),)
    assert encoding.expansions() == [(big, 5)]


def test_ties_go_to_the_pair_whose_leftmost_occurrence_comes_first():
    # [2,3,0,1,0,1,2,3]: (2,3) and (0,1) both ×2; (2,3) starts at 0, (0,1) at 2, so (2,3)
    # is merged first although (0,1) is the smaller pair → 4: [4,0,1,0,1,4]; (0,1) ×2 → 5:
    # [4,5,5,4]; nothing twice → stop.
    encoding = encode([2, 3, 0, 1, 0, 1, 2, 3])
    assert encoding.merges == ((2, 3), (0, 1))
    assert encoding.segments == ((4, 5, 5, 4),)
    # Mirrored, (0,1) comes first: [0,1,2,3,2,3,0,1] → (0,1) → 4: [4,2,3,2,3,4] → (2,3).
    assert encode([0, 1, 2, 3, 2, 3, 0, 1]).merges == ((0, 1), (2, 3))
    # The first occurrence is over the episodes in the order given: (1,2) in the first.
    assert encode([[1, 2, 1, 2], [0, 3, 0, 3]]).merges == ((1, 2), (0, 3))
    assert encode([[0, 3, 0, 3], [1, 2, 1, 2]]).merges == ((0, 3), (1, 2))


def test_no_pair_spans_an_episode_boundary():
    # Concatenated, [0,1,0,1,0,1] would merge (0,1) ×3 and then (3,3)... Split as
    # [0,1,0] | [1,0,1]: (0,1) ×2 (positions 0 and 4) and (1,0) ×2 tie, (0,1) first → 2:
    # [2,0] | [1,2]; nothing twice → stop.
    encoding = encode([[0, 1, 0], [1, 0, 1]])
    assert encoding.merges == ((0, 1),)
    assert encoding.segments == ((2, 0), (1, 2))
    # [0] | [1,0] | [1]: the pair (0,1) exists only across boundaries → no merge at all.
    assert encode([[0], [1, 0], [1]]).merges == ()
    # Empty episodes stay in their place.
    assert encode([[], [0, 0], []]).segments == ((), (0, 0), ())


def _demo_with_injected_steps() -> Demo:
    # One episode: 0 1 2 | 3 injected | 0 1 2 | 3 injected | 0 1 2.
    actions = np.array([0, 1, 2, 3, 0, 1, 2, 3, 0, 1, 2])
    decided = np.array([1, 1, 1, 0, 1, 1, 1, 0, 1, 1, 1], bool)
    return Demo(actions=actions, rewards=np.zeros(11),
                terminated=np.array([0] * 10 + [1], bool), truncated=np.zeros(11, bool),
                episode_lengths=np.array([11]), decisions=decided, meta={"seeds": [0]})


def test_no_routine_spans_an_injected_step():
    demo = _demo_with_injected_steps()
    # The whole sequence would merge (0,1) → 4: [4,2,3,4,2,3,4,2], (4,2) → 5: [5,3,5,3,5],
    # (5,3) → 6, i.e. [0,1,2,3] across the injected 3: [6,6,5]. The decision segments
    # [0,1,2] ×3 (actions 0..2, so the first token is 3) only (0,1) → 3 and (3,2) → 4.
    assert encode(demo.actions).merges == ((0, 1), (4, 2), (5, 3))
    segments, _ = demo.decision_segments()
    assert encode(segments).merges == ((0, 1), (3, 2))
    assert encode(segments).segments == ((4,), (4,), (4,))
    library = mine_quietly(BPEMiner(), demo)
    assert library.routines == ((0, 1, 2),)  # (0, 1) is within α of a primitive
    assert library.frequencies == (3,)
    assert library.occurrences == (((0, 0), (0, 4), (0, 8)),)  # steps of the demo


def test_max_merges_stops_early_and_is_checked():
    assert encode([0] * 8, max_merges=1).merges == ((0, 0),)
    assert encode([0] * 8, max_merges=1).segments == ((1, 1, 1, 1),)
    library = mine_quietly(BPEMiner(max_merges=1), [0, 1, 2] * 3)
    assert library.routines == () and library.params["max_merges"] == 1
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=f"max_merges needs to be an integer ≥ 1 or None, "
                                             f"got {bad!r}"):
            BPEMiner(max_merges=bad)
        with pytest.raises(ValueError, match="max_merges needs to be an integer ≥ 1"):
            encode([0, 0], max_merges=bad)


# -- the miner --------------------------------------------------------------------------------


def test_bpe_miner_scores_prunes_and_picks_like_sequitur():
    # Candidates (hand-worked above): (2,2) (2,2,3) (4,4) (4,4,1) (4,4,1,2,2,3). Length-2 ones
    # are within α = 2 of a primitive; scores f + 0.1·len: (2,2,3) 3 + 0.3 = 3.3,
    # (4,4,1,2,2,3) 2 + 0.6 = 2.6, (4,4,1) 2 + 0.3 = 2.3.
    actions = [2, 2, 3, 5, 4, 4, 1, 2, 2, 3, 0, 4, 4, 1, 2, 2, 3]
    library = BPEMiner(num_routines=3).mine(actions)
    assert library.routines == ((2, 2, 3), (4, 4, 1, 2, 2, 3), (4, 4, 1))
    assert library.scores == (3.3, 2.6, 2.3)
    assert library.frequencies == (3, 2, 2)
    # The same selection code as Sequitur's, on BPE's candidates.
    miner = BPEMiner(num_routines=3)
    episodes = _episodes_of(actions).episodes
    selector = _Selector(OccurrenceIndex(episodes), 0.1, 2, True)
    assert [r for r, _, _ in selector.select(miner.candidates(episodes), 3)] == list(
        library.routines)
    # max_length and min_length bound the candidates as they bound the grammar's rules.
    assert BPEMiner(max_length=3).candidates(episodes) == [(2, 2), (2, 2, 3), (4, 4), (4, 4, 1)]
    assert BPEMiner(min_length=4).candidates(episodes) == [(4, 4, 1, 2, 2, 3)]
    # The authors' selection takes merge order for rule order, and their count misses the
    # match ending on the last action: (2,2,3) f 2 kept; (4,4,1) f 2 kept (3 edits from
    # (2,2,3), neither contains the other); (4,4,1,2,2,3) f 1 contains (2,2,3), its first
    # conflict, and is not above it: dropped. Ranked by f, ties in the order kept.
    authors = mine_quietly(BPEMiner(num_routines=3, selection="authors"), actions)
    assert authors.routines == ((2, 2, 3), (4, 4, 1))
    assert authors.params["selection"] == "authors"


def test_make_proposer_builds_the_bpe_miner_and_the_library_records_it():
    miner = make_proposer("bpe", num_routines=2, alpha=3, max_length=20)
    assert type(miner) is BPEMiner and OTHER_PROPOSERS == {"bpe": BPEMiner}
    assert miner.params() == {"proposer": "bpe", "num_routines": 2, "length_weight": 0.1,
                              "alpha": 3, "prune_primitives": True, "max_length": 20,
                              "min_length": 2, "max_merges": None}
    assert type(make_proposer("bpe", selection="authors")) is BPEMiner
    assert SequiturMiner().params()["proposer"] == "full"  # Sequitur's params as before
    with pytest.raises(ValueError, match="unknown proposer 'bytes'; choose from full, random, "
                                         "enumerate, random-fetch, repeat, bpe"):
        make_proposer("bytes")
    with pytest.raises(ValueError, match="is the full and bpe proposers' only; the 'repeat'"):
        make_proposer("repeat", selection="authors")


@pytest.mark.parametrize(("actions", "error", "match"), [
    ([], ValueError, "the demonstration is empty"),
    ([[3], [4]], ValueError, "no episode of two or more actions"),
    ([0, 1.5, 2], TypeError, "actions must be integers"),
    ([0, -2, 1], ValueError, "actions must be non-negative, got -2"),
])
def test_bad_demonstrations_are_rejected(actions, error, match):
    with pytest.raises(error, match=match):
        BPEMiner().mine(actions)


def test_the_scripts_take_proposer_bpe():
    sys.path.insert(0, str(REPO / "algos"))
    try:
        import rapl_a2c
        import rapl_sqil
    finally:
        sys.path.remove(str(REPO / "algos"))
    for module in (rapl_a2c, rapl_sqil):
        hints = typing.get_type_hints(module.Args)
        assert "bpe" in typing.get_args(hints["proposer"]), module.__name__


# -- properties on random inputs --------------------------------------------------------------


def naive_bpe(episodes: list[list[int]]) -> tuple[list[tuple[int, int]], list[list[int]]]:
    """BPE written the slow, obvious way: recount every pair each round."""
    segments = [list(e) for e in episodes]
    token = max((a for e in episodes for a in e), default=-1) + 1
    merges = []
    while True:
        counts: dict[tuple[int, int], int] = {}
        first: dict[tuple[int, int], tuple[int, int]] = {}
        for s, seg in enumerate(segments):
            free_from: dict[tuple[int, int], int] = {}  # non-overlapping, left to right
            for i in range(len(seg) - 1):
                pair = (seg[i], seg[i + 1])
                first.setdefault(pair, (s, i))
                if i >= free_from.get(pair, 0):
                    counts[pair] = counts.get(pair, 0) + 1
                    free_from[pair] = i + 2
        if not counts or max(counts.values()) < 2:
            return merges, segments
        best = min(counts, key=lambda p: (-counts[p], first[p]))
        for s, seg in enumerate(segments):
            out, i = [], 0
            while i < len(seg):
                if i + 1 < len(seg) and (seg[i], seg[i + 1]) == best:
                    out.append(token)
                    i += 2
                else:
                    out.append(seg[i])
                    i += 1
            segments[s] = out
        merges.append(best)
        token += 1


EPISODES = st.lists(st.lists(st.integers(0, 3), max_size=40), min_size=1, max_size=4).filter(
    lambda es: any(es))


@settings(max_examples=300, deadline=None)
@given(EPISODES)
def test_encode_agrees_with_a_naive_bpe_and_expands_back_to_the_input(episodes):
    encoding = encode(episodes)
    merges, segments = naive_bpe(episodes)
    assert list(encoding.merges) == merges
    assert [list(s) for s in encoding.segments] == segments
    assert encoding.expand() == episodes
    assert all(c >= 2 for c in encoding.counts)


@settings(max_examples=200, deadline=None)
@given(EPISODES)
def test_every_candidate_occurs_in_the_decisions_at_least_twice(episodes):
    candidates = BPEMiner(min_length=2, max_length=None).candidates(
        [np.asarray(e, dtype=np.int64) for e in episodes])
    index = OccurrenceIndex([np.asarray(e, dtype=np.int64) for e in episodes])
    assert all(index.count(c) >= 2 for c in candidates)
    assert len(set(candidates)) == len(candidates)


@settings(max_examples=100, deadline=None)
@given(EPISODES.filter(lambda es: max(map(len, es)) >= 2))
def test_the_same_input_gives_the_same_library(episodes):
    one = mine_quietly(BPEMiner(num_routines=3, prune_primitives=False), episodes)
    two = mine_quietly(BPEMiner(num_routines=3, prune_primitives=False),
                       [np.asarray(e, dtype=np.int64) for e in episodes])
    assert one == two
    assert all(f >= 2 for f in one.frequencies)


# -- as a user --------------------------------------------------------------------------------


def test_routine_gym_mine_proposer_bpe_on_a_shipped_demo(tmp_path):
    demo = shipped_demo_path("MiniQbert-v0")
    out = tmp_path / "bpe.json"
    proc = subprocess.run([str(BIN / "routine-gym"), "mine", demo, "--proposer", "bpe",
                           "--out", str(out)], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "proposer=bpe" in proc.stdout
    saved = json.loads(out.read_text())
    assert saved["params"]["proposer"] == "bpe" and saved["params"]["max_merges"] is None
    expected = mine_quietly(BPEMiner(), Demo.load(demo))
    assert [tuple(r) for r in saved["routines"]] == list(expected.routines)
    assert saved["frequencies"] == list(expected.frequencies)
