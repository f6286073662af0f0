"""`bench/bench_before_after.py` run as a user runs it, with a tiny budget: both sides are this
checkout, so its report has one row whose medians and pair-by-pair ratios are real numbers;
bad input is refused with a one-line error."""

from __future__ import annotations

import re
from functools import partial
from pathlib import Path

from bench_runner import run_bench

ROOT = Path(__file__).resolve().parent.parent

run = partial(run_bench, "bench_before_after.py")  # the script as a user runs it


def test_the_benchmark_writes_one_row_per_run_asked_for(tmp_path):
    out = tmp_path / "before_after.md"
    done = run(ROOT, ROOT, "--runs", "MinAtar Breakout a2c", "--repeats", "1", "--steps", "512",
               "--out", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    # One warm-up pair and one counted pair: four runs, each printed.
    assert len(re.findall(r"^MinAtar Breakout a2c (before|after) #\d", done.stdout, re.M)) == 4
    report = out.read_text()
    assert f"--repeats 1 --runs 'MinAtar Breakout a2c' --steps 512 --out {out}`" in report
    rows = [line for line in report.splitlines() if line.startswith("| MinAtar")]
    assert len(rows) == 1 and "Qbert" not in report
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    wall_before, wall_after, ratio = map(float, cells[1:4])
    assert wall_before > 0 and wall_after > 0
    # The ratio is taken before the walls are rounded to 0.01 s for the table.
    assert abs(ratio - wall_after / wall_before) < 0.01 * ratio + 1e-3
    # With one counted pair, the pair-by-pair median is that pair's ratio and its range is it.
    pair = re.fullmatch(r"([\d.]+) \(([\d.]+)–([\d.]+)\)", cells[-1])
    assert pair and pair[1] == pair[2] == pair[3]


def test_bad_input_is_refused_in_one_line(tmp_path):
    for words, message in [
        ((ROOT, ROOT, "--repeats", "0"), "--repeats must be at least 1, not 0"),
        ((ROOT, ROOT, "--steps", "-5"), "--steps must be at least 1, not -5"),
        ((tmp_path, ROOT), f"before {tmp_path} is not a routine-gym checkout"),
    ]:
        done = run(*words)
        assert done.returncode == 2
        assert message in done.stderr.strip().splitlines()[-1]
