"""`bench/bench_mechanisms.py` as a user runs it: a short run of two configurations writes its
table, RAPL's row the reference of its own ratio."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_a_short_run_writes_each_configurations_sps_beside_rapls(tmp_path):
    out = tmp_path / "mechanisms.md"
    proc = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bench_mechanisms.py"), "--steps", "400",
         "--repeats", "1", "--scripts", "rapl_a2c", "--configs", "intra", "--out", str(out)],
        capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [line for line in out.read_text().splitlines() if line.startswith("| rapl_a2c")]
    assert [row.split("|")[2].strip() for row in rows] == ["rapl", "intra"]
    assert rows[0].split("|")[5].strip() == "1.00"  # rapl ÷ rapl
    assert all(re.fullmatch(r"\d+", row.split("|")[3].strip()) for row in rows)  # one SPS each


def test_a_bad_budget_is_a_one_line_error(tmp_path):
    proc = subprocess.run(
        [sys.executable, str(REPO / "bench" / "bench_mechanisms.py"), "--steps", "0"],
        capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].endswith(
        "--steps and --repeats must be at least 1")
