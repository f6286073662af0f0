"""`bench/bench_wrapper.py` run as a user runs it, on the constant env with a tiny budget: it
writes its tables (the wrapper's step judged against RepeatAction)
and refuses a budget too small to time with a one-line error."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench" / "bench_wrapper.py"
USER_ENV = {"PATH": os.environ["PATH"], "HOME": os.environ.get("HOME", "/tmp")}


def test_a_short_run_writes_the_tables(tmp_path):
    out = tmp_path / "wrapper.md"
    done = subprocess.run([sys.executable, str(BENCH), "--envs", "constant", "--steps", "200",
                           "--repeats", "1", "--out", str(out)], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path, env=USER_ENV)
    assert done.returncode == 0, done.stderr
    report = out.read_text()
    assert "### constant" in report and "### cartpole" not in report
    # One ratio row per L, and the primitive row (overheads are differences of two times,
    # negative now and then on a budget this small).
    rows = re.findall(r"^\| routine \| (\d+) \| -?[\d,]+ \| -?[\d,]+ \| ", report, re.M)
    assert rows == ["1", "3", "5", "10"]
    assert re.search(r"^\| primitive \| 1 \| ", report, re.M)


def test_too_few_steps_is_a_one_line_error(tmp_path):
    done = subprocess.run([sys.executable, str(BENCH), "--envs", "constant", "--steps", "5",
                           "--out", str(tmp_path / "w.md")], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path, env=USER_ENV)
    assert done.returncode == 2
    assert "steps must be ≥ 10" in done.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "w.md").exists()
