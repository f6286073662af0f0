"""bench/bench_report.py as a user runs it: the report of a committed sweep written with
rliable's per-resample functions and with the report's own, timed, and found the same."""

from __future__ import annotations

import re
from functools import partial
from pathlib import Path

from bench_runner import run_bench

run = partial(run_bench, "bench_report.py")
LONG = Path(__file__).resolve().parent.parent / "bench" / "results" / "experiments" / "long"


def test_both_reports_of_a_committed_sweep_are_the_same_and_timed(tmp_path):
    before = {p.name: p.stat().st_mtime_ns for p in (LONG / "report").iterdir()}
    out = tmp_path / "speed.md"
    done = run(LONG, "--reps", "50", "--out", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    text = out.read_text()
    assert re.search(r"\| rliable's \(scipy `trim_mean`, `mannwhitneyu`\) \| \d+\.\d s \|", text)
    assert re.search(r"\| the report's own \| \d+\.\d s \| \d+\.\d× faster \|", text)
    assert "differing: none; report.md the same (the folder's name aside): yes." in text
    # The committed snapshot's own report is left as it was.
    assert {p.name: p.stat().st_mtime_ns for p in (LONG / "report").iterdir()} == before


def test_bad_input_is_refused_in_one_line(tmp_path):
    for words, message in [((tmp_path / "nothing",), "no such sweep folder"),
                           ((LONG, "--reps", "0"), "--reps must be at least 1, not 0"),
                           ((tmp_path,), "not a sweep folder")]:
        done = run(*words, cwd=tmp_path)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("bench_report.py: error: "), lines
        assert message in lines[0], lines
