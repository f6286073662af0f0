"""`bench/bench_script_start.py` run as a user runs it, one round of the shortest runs: a row
per command with both sides' medians and the saving worked out from them; bad input refused in
one line."""

from __future__ import annotations

import re
from functools import partial

from bench_runner import run_bench

run = partial(run_bench, "bench_script_start.py")  # the script as a user runs it


def test_one_round_reports_both_sides_of_every_command(tmp_path):
    out = tmp_path / "start.md"
    done = run("--repeats", 1, "--long-steps", 1000, "--out", out, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert len(re.findall(r"^round 1 .* (eager|torch's) +wall", done.stdout, re.M)) == 8
    report = out.read_text()
    assert "`python bench/bench_script_start.py --repeats 1 --long-steps 1000`" in report
    rows = [line for line in report.splitlines() if line.startswith("| ") and " s |" in line]
    assert [row.split(" | ")[0] for row in rows] == [
        "| A2C, 1,000 steps", "| RAPL-A2C, 1,000 steps", "| PPO, 1,000 steps",
        "| RAPL-A2C, 1,000 steps"]
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        eager, torchs = float(cells[1].removesuffix(" s")), float(cells[2].removesuffix(" s"))
        saved = float(cells[3].split(" s")[0])
        assert abs(saved - (torchs - eager)) <= 0.011, row
        # CPU seconds, less sensitive to load than wall: the import is about 1.4 s of 3.5
        cpu_eager, cpu_torchs = (float(cells[i].removesuffix(" s")) for i in (4, 5))
        assert cpu_eager < cpu_torchs, row


def test_bad_input_is_refused_in_one_line(tmp_path):
    for words, message in (((("--repeats", 0)), "--repeats must be at least 1, not 0"),
                           ((("--long-steps", 10)), "--long-steps must be at least 1000")):
        done = run(*words, cwd=tmp_path)
        assert done.returncode == 2
        assert done.stderr.strip().splitlines() == [
            f"bench_script_start.py: error: {message}" + (", not 10" if "long" in message
                                                          else "")]
