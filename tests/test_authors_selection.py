"""`SequiturMiner(selection="authors")`: the selection of the authors' released code (SPEC §5b,
`make_demo_discover_rt/sq_rt_proposal.py` at 7192f0b), on hand-worked sequences where it and
the paper's selection give different libraries. Every expected library is worked out in the
comments: the grammar (checked first), each candidate's frequency f, then both selections with
K = 3 and α = 2. `bench/results/authors_selection.md` checks the same code against theirs.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from one_line import assert_one_line_error

from routine_gym.demo import Demo
from routine_gym.library import RoutineLibrary
from routine_gym.mining import SequiturMiner, make_proposer
from routine_gym.plumbing.errors import UsageError
from routine_gym.plumbing.loading import load_routines

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent


def mine(actions, selection: str, k: int = 3) -> RoutineLibrary:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "fewer than K survive" is expected on toy inputs
        return SequiturMiner(num_routines=k, selection=selection).mine(actions)


def candidates(actions) -> list[tuple[int, ...]]:
    return SequiturMiner().candidates([np.asarray(actions)])


def test_no_length_term_and_ties_kept_in_rule_order():
    #  index: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14
    actions = [0, 1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0]
    # R0 -> R1 R2 R2 R1 0, R1 -> R3 1, R2 -> 0 0 R3, R3 -> 0 1: rules in order of appearance.
    assert candidates(actions) == [(0, 1, 1), (0, 0, 0, 1), (0, 1)]
    # f: (0,1,1) at 0 and 11 -> 2; (0,0,0,1) at 3 and 7 -> 2; (0,1) at 0, 5, 9, 11 -> 4.
    # Paper: 2 + 0.3 = 2.3, 2 + 0.4 = 2.4, (0,1) is within α of a primitive. (0,0,0,1) first;
    # (0,1,1) is at Levenshtein 2 from it and neither contains the other: both kept.
    paper = mine(actions, "paper")
    assert paper.routines == ((0, 0, 0, 1), (0, 1, 1))
    assert paper.scores == (2.4, 2.3)
    # Authors: score f / mean f, mean = (2 + 2 + 4) / 3 = 8/3, so both score 2 / (8/3) = 0.75.
    # Pass in rule order: (0,1,1) kept, (0,0,0,1) kept (no conflict), (0,1) near a primitive.
    # The stable sort keeps the tie in the order kept: (0,1,1) first, the shorter one.
    authors = mine(actions, "authors")
    assert authors.routines == ((0, 1, 1), (0, 0, 0, 1))
    assert authors.frequencies == (2, 2)
    assert authors.scores == (0.75, 0.75)


def test_a_candidate_containing_a_kept_routine_is_pruned():
    #  index: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17
    actions = [0, 1, 2, 0, 1, 2, 3, 0, 1, 2, 3, 4, 0, 1, 2, 3, 4, 5]
    # R1 -> 0 1 2, R2 -> R1 3, R3 -> R2 4.
    assert candidates(actions) == [(0, 1, 2), (0, 1, 2, 3), (0, 1, 2, 3, 4)]
    # f: (0,1,2) at 0, 3, 7, 12 -> 4; (0,1,2,3) at 3, 7, 12 -> 3; (0,1,2,3,4) at 7, 12 -> 2.
    # Paper: 4.3, 3.4, 2.5. (0,1,2) kept; (0,1,2,3) at Levenshtein 1: pruned; (0,1,2,3,4) at
    # distance 2 from (0,1,2): kept.
    paper = mine(actions, "paper")
    assert paper.routines == ((0, 1, 2), (0, 1, 2, 3, 4))
    # Authors: mean f = 3. (0,1,2) kept; (0,1,2,3) conflicts with it (distance 1, and contains
    # it), 3 > 4 is false: dropped; (0,1,2,3,4) contains (0,1,2), 2 > 4 false: dropped.
    authors = mine(actions, "authors")
    assert authors.routines == ((0, 1, 2),)
    assert authors.frequencies == (4,)
    assert authors.scores == (4 / 3,)


def test_a_better_candidate_replaces_only_the_first_kept_routine_it_conflicts_with():
    #  index: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17
    actions = [1, 0, 1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 1, 0, 1, 0]
    # R0 -> R1 R2 R2 R3 R1 0, R1 -> R4 1, R2 -> R3 0, R3 -> R4 0, R4 -> 1 0.
    assert candidates(actions) == [(1, 0, 1), (1, 0, 0, 0), (1, 0, 0), (1, 0)]
    # f: (1,0,1) at 0, 14 -> 2; (1,0,0,0) at 3, 7 -> 2; (1,0,0) at 3, 7, 11 -> 3;
    # (1,0) at 0, 3, 7, 11, 14, 16 -> 6.
    # Paper: 2.3, 2.4, 3.3 ((1,0) is near a primitive). (1,0,0) kept; (1,0,0,0) and (1,0,1)
    # are each at Levenshtein 1 from it: pruned. One routine.
    paper = mine(actions, "paper")
    assert paper.routines == ((1, 0, 0),)
    # Authors: (1,0) ends on the last action, which their count misses: f = 5, so the mean is
    # (2 + 2 + 3 + 5) / 4 = 3. Pass in rule order: (1,0,1) kept; (1,0,0,0) at distance 2 from
    # it, no containment: kept; (1,0,0) conflicts first with (1,0,1) (distance 1) and 3 > 2,
    # so it replaces it, without a look at (1,0,0,0), which contains it; (1,0) near a
    # primitive. Kept [(1,0,0,0), (1,0,0)], sorted by f: (1,0,0) 3/3 = 1, (1,0,0,0) 2/3.
    authors = mine(actions, "authors")
    assert authors.routines == ((1, 0, 0), (1, 0, 0, 0))
    assert authors.frequencies == (3, 2)
    assert authors.scores == (1.0, 2 / 3)


def test_an_occurrence_ending_on_the_last_action_is_missed():
    #  index: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19
    actions = [1, 2, 3, 1, 2, 3, 1, 2, 3, 4, 4, 4, 5, 4, 4, 4, 5, 1, 2, 3]
    assert candidates(actions) == [(1, 2, 3), (4, 4, 4, 5)]
    # (1,2,3) at 0, 3, 6, 17: the paper counts 4; the authors' count misses the one ending on
    # action 19, the last: 3. (4,4,4,5) at 9, 13 -> 2. Mean (3 + 2) / 2 = 2.5.
    paper = mine(actions, "paper")
    assert paper.routines == ((1, 2, 3), (4, 4, 4, 5))
    assert paper.frequencies == (4, 2)
    authors = mine(actions, "authors")
    assert authors.routines == ((1, 2, 3), (4, 4, 4, 5))
    assert authors.frequencies == (3, 2)
    assert authors.scores == (3 / 2.5, 2 / 2.5)
    # Only the end of the last episode: a second episode moves it off (1,2,3).
    two = mine([actions, [0, 0, 0, 0]], "authors")
    assert two.frequencies[0] == 4


def test_params_record_selection_only_when_authors(tmp_path):
    assert "selection" not in SequiturMiner().params()
    assert SequiturMiner(selection="authors").params()["selection"] == "authors"
    library = mine([0, 1, 2, 0, 1, 2, 3, 0, 1, 2, 3], "authors")
    library.save(tmp_path / "lib.json")
    assert RoutineLibrary.load(tmp_path / "lib.json").params["selection"] == "authors"


def test_a_bad_selection_is_a_one_line_error_naming_the_choices():
    with pytest.raises(ValueError, match="paper, authors") as info:
        SequiturMiner(selection="greedy")
    assert "\n" not in str(info.value) and "'greedy'" in str(info.value)
    with pytest.raises(ValueError, match="paper, authors"):
        make_proposer("full", selection="greedy")
    with pytest.raises(ValueError, match="'random' ablation"):
        make_proposer("random", selection="authors")


def test_load_routines_threads_selection():
    demo = Demo.load(REPO / "demos" / "first" / "MinAtar-Freeway-v1.npz")
    library = load_routines("MinAtar/Freeway-v1", 3, demo=demo, selection="authors")
    # The library the authors' own code selects from our candidates (bench/results/
    # authors_selection.md); the paper's is (1,1,1), (1,1,1,1,1), (1,1,1,1,1,1,1,1).
    assert library.routines == ((1, 1, 1), (0, 0, 0, 0), (1, 0, 0))
    assert library.frequencies == (996, 177, 140)
    assert load_routines("MinAtar/Freeway-v1", 3, demo=demo).routines == (
        (1, 1, 1), (1, 1, 1, 1, 1), (1, 1, 1, 1, 1, 1, 1, 1))
    with pytest.raises(UsageError, match="--selection needs to be one of paper, authors"):
        load_routines("MinAtar/Freeway-v1", 3, demo=demo, selection="greedy")


def user(*words: str | Path, cwd: Path) -> subprocess.CompletedProcess:
    """As tests/test_as_a_user.py: the venv's routine-gym, PATH, HOME and LANG only."""
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    return subprocess.run([str(BIN / "routine-gym"), *map(str, words)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)


def test_mine_with_the_authors_selection_as_a_user(tmp_path):
    demo = REPO / "demos" / "first" / "MinAtar-SpaceInvaders-v1.npz"
    proc = user("mine", demo, "--selection", "authors", "--out", "lib.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "selection=authors" in proc.stdout
    library = json.loads((tmp_path / "lib.json").read_text())
    assert library["routines"] == [[3, 3, 3], [1, 3, 3], [2, 3, 3, 3]]
    assert library["frequencies"] == [512, 67, 61]
    assert library["params"]["selection"] == "authors"
    proc = user("mine", demo, "--selection", "greedy", cwd=tmp_path)
    assert_one_line_error(proc, "--selection", "paper or authors", "greedy",
                          prefix="routine-gym: error:")
