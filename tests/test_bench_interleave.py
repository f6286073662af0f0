"""`bench/bench_interleave.py` run as a user runs it, with a tiny budget: it writes a report
with a row per kind of work between acting passes and the slowdown line, and refuses a budget
of zero passes with a one-line error."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench" / "bench_interleave.py"


def test_the_benchmark_writes_its_report(tmp_path):
    out = tmp_path / "interleave.md"
    done = subprocess.run([sys.executable, str(BENCH), "--passes", "20", "--repeats", "1",
                           "--num-envs", "4", "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    report = out.read_text()
    for row in ("| nothing |", "| env |", "| memory sweep |", "| python loop |",
                "| game states |", "| (env alone, no acting) |"):
        assert row in report
    assert "Taking turns, the acting pass is" in report and "per agent step" in report
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    assert [r["between"] for r in rows][:2] == ["nothing", "env"]
    # Every timing is a positive number of microseconds; `env alone` has no acting pass.
    assert all(r["between_us"] > 0 for r in rows if r["between"] != "nothing")
    assert all(r["acting_us"] > 0 for r in rows if r["between"] != "env alone")
    assert rows[-1] == {**rows[-1], "between": "env alone", "acting_us": None}


def test_zero_passes_is_refused():
    done = subprocess.run([sys.executable, str(BENCH), "--passes", "0"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert "--passes and --repeats need to be at least 1" in done.stderr
