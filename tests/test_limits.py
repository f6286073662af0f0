"""Small inputs, unbounded cost: every size a demo or a routine claims is bounded and checked.

- a `.npy` header is read before anything is allocated: a 2 KB demo claiming 8 TB of actions
  is refused in one line naming the file, the member and the claimed shape;
- routines are at most `max_length` actions long (default `MAX_ROUTINE_LENGTH` = 64), the
  ablations included, with the bound threaded to `routine-gym mine` and the scripts;
- mining is linear-ish on the most repetitive input there is, a million copies of one action,
  with or without the bound; the block-id machinery behind it is checked against brute force.
"""

from __future__ import annotations

import io
import subprocess
import sys
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from routine_gym import cli
from routine_gym.demo import Demo, shipped_demo_path
from routine_gym.errors import UsageError
from routine_gym.library import MAX_KEPT_OCCURRENCES
from routine_gym.mining import (
    MAX_ROUTINE_LENGTH,
    PROPOSERS,
    SequiturMiner,
    make_proposer,
)
from routine_gym.occurrences import OccurrenceIndex
from routine_gym.plumbing.arguments import check_args
from routine_gym.plumbing.loading import load_routines
from routine_gym.sequitur import induce

REPO = Path(__file__).resolve().parent.parent


def mine_quietly(proposer, actions):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return proposer.mine(actions)


# -- .npy headers checked before allocation ---------------------------------------------------


def small_demo() -> Demo:
    return Demo(actions=np.array([0, 1, 2, 0, 1, 2, 0, 1]), rewards=np.zeros(8),
                terminated=np.array([0] * 7 + [1], bool), truncated=np.zeros(8, bool),
                episode_lengths=np.array([8]), meta={"seeds": [0]})


def npy_member(header: dict, data: bytes) -> bytes:
    """A `.npy` file of `data` under a hand-written header (which may lie about the shape)."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue() + data


def demo_with_member(tmp_path: Path, name: str, member: bytes) -> Path:
    """A real saved demo whose member `name` is `member` (replaced or added), recompressed."""
    saved = tmp_path / "saved.npz"
    small_demo().save(saved)
    path = tmp_path / "crafted.npz"
    with zipfile.ZipFile(saved) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as out:
        for info in src.infolist():
            if info.filename != f"{name}.npy":
                out.writestr(info.filename, src.read(info))
        out.writestr(f"{name}.npy", member)
    return path


def test_an_array_header_claiming_a_huge_shape_is_refused_before_allocation(tmp_path, capsys):
    data = np.arange(8, dtype="<i8").tobytes()
    header = {"descr": "<i8", "fortran_order": False, "shape": (10**12,)}
    path = demo_with_member(tmp_path, "actions", npy_member(header, data))
    assert path.stat().st_size < 2500  # a 2 KB file that would ask np.load for 8 TB
    with pytest.raises(UsageError) as err:
        Demo.load(path)
    message = str(err.value)
    assert "\n" not in message
    assert str(path) in message
    assert "'actions' claims shape (1000000000000,)" in message
    assert "over the limit of 100,000,000 steps" in message
    # The command line says the same in one line, exit code 2, and no MemoryError.
    with pytest.raises(SystemExit) as exit_:
        cli.main(["show", str(path)])
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "claims shape (1000000000000,)" in lines[0]


def test_an_array_header_that_disagrees_with_the_member_size_is_refused(tmp_path):
    data = np.arange(8, dtype="<i8").tobytes()
    header = {"descr": "<i8", "fortran_order": False, "shape": (1000,)}
    path = demo_with_member(tmp_path, "actions", npy_member(header, data))
    with pytest.raises(UsageError, match=r"'actions' claims shape \(1000,\) of int64, 8,000 "
                                         r"bytes, but holds 64 bytes of data"):
        Demo.load(path)


def test_an_object_dtype_header_is_refused_without_unpickling(tmp_path):
    header = {"descr": "|O", "fortran_order": False, "shape": (8,)}
    path = demo_with_member(tmp_path, "rewards", npy_member(header, b"\x80\x04N." * 2))
    with pytest.raises(UsageError, match="'rewards' holds pickled Python objects"):
        Demo.load(path)


def test_a_huge_observation_header_is_refused_under_its_own_limit(tmp_path):
    header = {"descr": "|u1", "fortran_order": False, "shape": (10**6, 2**16, 2**10)}
    path = demo_with_member(tmp_path, "observations", npy_member(header, b""))
    with pytest.raises(UsageError, match=r"'observations' claims shape \(1000000, 65536, 1024\)"
                                         r" of uint8, .* over the limit of 16 GiB"):
        Demo.load(path)


def test_every_shipped_demo_passes_the_header_checks():
    for path in sorted((REPO / "demos").glob("*.npz")):
        Demo.load(path)


# -- the bound on routine length --------------------------------------------------------------


#: 30 episodes each holding a motif of 100 actions twice (a 100-action rule), and 5 each
#: holding a motif of 3 actions twice.
LONG_MOTIF = [list(range(100)) + [200 + i] + list(range(100)) for i in range(30)] + [
    [500, 501, 502, 600 + i, 500, 501, 502] for i in range(5)
]


def test_max_length_defaults_to_64_and_bounds_every_routine():
    assert SequiturMiner().max_length == MAX_ROUTINE_LENGTH == 64
    unbounded = mine_quietly(SequiturMiner(max_length=None), LONG_MOTIF)
    assert 100 in unbounded.lengths
    bounded = mine_quietly(SequiturMiner(), LONG_MOTIF)
    assert bounded.lengths and max(bounded.lengths) <= 64
    assert bounded.params["max_length"] == 64


@pytest.mark.parametrize("name", sorted(set(PROPOSERS) - {"full"}))
def test_ablations_respect_the_same_bound(name):
    assert 100 in mine_quietly(make_proposer(name, seed=1, max_length=None), LONG_MOTIF).lengths
    library = mine_quietly(make_proposer(name, seed=1, max_length=20), LONG_MOTIF)
    assert library.lengths and max(library.lengths) <= 20
    assert library.params["max_length"] == 20
    assert PROPOSERS[name]().max_length == 64


def test_min_length_above_max_length_is_one_line_naming_both_flags():
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"))
    with pytest.raises(UsageError) as err:
        load_routines("MiniQbert-v0", 3, demo=demo, min_length=10, max_length=5)
    assert str(err.value) == ("--min-routine-length 10 is above --max-routine-length 5: no "
                              "candidate could be kept")


def test_the_scripts_take_max_routine_length_with_its_domain():
    sys.path.insert(0, str(REPO / "algos"))
    try:
        import rapl_a2c
        import rapl_sqil
    finally:
        sys.path.remove(str(REPO / "algos"))
    for module in (rapl_a2c, rapl_sqil):
        args = module.Args()
        assert args.max_routine_length == 64
        args.max_routine_length = 1
        with pytest.raises(UsageError, match="--max-routine-length needs to be ≥ 2, actual "
                                             "value: 1"):
            check_args(args)


def test_rapl_a2c_refuses_min_above_max_before_any_work(tmp_path):
    proc = subprocess.run(
        [sys.executable, str(REPO / "algos" / "rapl_a2c.py"), "--env-id", "MiniQbert-v0",
         "--min-routine-length", "10", "--max-routine-length", "5"],
        capture_output=True, text=True, cwd=tmp_path, timeout=180,
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert len(lines) == 1 and "--min-routine-length needs to be ≤ --max-routine-length (5)" \
        in lines[0], lines
    assert not (tmp_path / "runs").exists()


def test_routine_gym_mine_takes_max_routine_length(capsys):
    demo = str(shipped_demo_path("MinAtar/Freeway-v1"))
    assert cli.main(["mine", demo, "-k", "6", "--max-routine-length", "4"]) == 0
    out = capsys.readouterr().out
    lengths = [int(line.split("len=")[1].split()[0]) for line in out.splitlines()
               if "len=" in line]
    assert lengths and max(lengths) <= 4 and "max_length=4" in out
    with pytest.raises(SystemExit) as exit_:
        cli.main(["mine", demo, "--max-routine-length", "1"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "max" in err and "needs to be ≥ 2" in err, err


# -- linear-ish mining on repetitive input ----------------------------------------------------


def test_a_million_copies_of_one_action_mine_fast_and_sanely():
    actions = np.zeros(10**6, dtype=np.int64)
    start = time.perf_counter()
    library = SequiturMiner().mine(actions)
    seconds = time.perf_counter() - start
    # f(0^L) = 10^6 - L + 1; the score favours the shortest, and 0 0 is pruned (α = 2).
    assert library.routines == ((0,) * 4, (0,) * 8, (0,) * 16)
    assert library.frequencies == (999_997, 999_993, 999_985)
    # The first MAX_KEPT_OCCURRENCES occurrences are kept: 0^16 starts at every step.
    assert library.occurrences[2][-1] == (0, MAX_KEPT_OCCURRENCES - 1)
    assert not library.occurrences_complete
    # Over 2 minutes before the fix, ~1.3 s now (random actions: ~1 s; bench/bench_mining.py
    # --repetitive compares the two); the bound is loose so a loaded machine does not fail it.
    assert seconds < 30, seconds


@pytest.mark.parametrize("pattern", [[0], [0, 1], [0, 1, 2, 2]])
def test_periodic_input_without_a_bound_is_fast_and_exact(pattern):
    actions = np.tile(pattern, 10**5 // len(pattern))
    start = time.perf_counter()
    library = mine_quietly(SequiturMiner(num_routines=6, max_length=None), actions)
    # A guard against quadratic blow-up (minutes), not a speed figure: about 1 s compiled and
    # 2-6 s with the Python twin on a loaded two-core machine (it failed at 3 s so).
    assert time.perf_counter() - start < 30
    assert len(library) == 6
    for routine, f in zip(library.routines, library.frequencies, strict=True):
        windows = np.lib.stride_tricks.sliding_window_view(actions, len(routine))
        assert f == int((windows == np.array(routine)).all(axis=1).sum())


def brute_positions(episodes, routine):
    out, offset = [], 0
    for e in episodes:
        for s in range(len(e) - len(routine) + 1):
            if list(e[s : s + len(routine)]) == list(routine):
                out.append(offset + s)
        offset += len(e)
    return out


@st.composite
def repetitive_episodes_and_routine(draw):
    """Few actions and long routines, so that the block path and its edge cases are hit."""
    k = draw(st.integers(1, 3))
    episodes = draw(st.lists(st.lists(st.integers(0, k - 1), max_size=60), min_size=1,
                             max_size=4))
    n = draw(st.integers(1, 40))
    long_enough = [e for e in episodes if len(e) >= n]
    if long_enough and draw(st.booleans()):
        e = draw(st.sampled_from(long_enough))
        s = draw(st.integers(0, len(e) - n))
        return episodes, tuple(e[s : s + n])
    return episodes, tuple(draw(st.lists(st.integers(0, k), min_size=n, max_size=n)))


@settings(max_examples=200, deadline=None)
@given(case=repetitive_episodes_and_routine(), max_gram=st.sampled_from([1, 2, 4]),
       blocks=st.booleans())
def test_counts_bounds_and_block_ids_match_brute_force(case, max_gram, blocks):
    episodes, routine = case
    index = OccurrenceIndex(episodes, max_gram=max_gram)
    if blocks:
        index._FILTER_BUDGET = -1  # every routine longer than Q goes through the block ids
    expected = brute_positions(episodes, routine)
    assert index.positions(routine).tolist() == expected
    assert index.count(routine) == len(expected)
    assert index.upper_bound(routine) >= index.refined_bound(routine) >= len(expected)


@settings(max_examples=100, deadline=None)
@given(case=repetitive_episodes_and_routine())
def test_distinct_windows_match_brute_force(case):
    episodes, routine = case
    n = len(routine)
    index = OccurrenceIndex(episodes)
    windows = index.distinct_windows(n)
    expected = {tuple(e[s : s + n]) for e in episodes for s in range(len(e) - n + 1)}
    assert len(windows) == len(set(windows)) and set(windows) == expected


@settings(max_examples=100, deadline=None)
@given(episodes=st.lists(st.lists(st.integers(0, 2), max_size=80), min_size=1, max_size=3),
       max_length=st.integers(2, 20))
def test_bounded_expansions_are_the_short_expansions(episodes, max_length):
    grammar = induce(episodes)
    everything = grammar.expansions()
    assert grammar.expansion_lengths()[1:] == [len(x) for x in everything]
    assert induce(episodes).expansions(max_length) == [
        x for x in everything if len(x) <= max_length
    ]
