"""`bench/bench_a2c_speed.py` run as a user runs it, on MinAtar with a tiny budget: the
network-only bound and `rapl_a2c.py --mode a2c` side by side, each row with its speed, its CPU
time over the timed steps (read at the first and the last timed progress line only) and the
ratio to the bound."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench" / "bench_a2c_speed.py"
USER_ENV = {"PATH": os.environ["PATH"], "HOME": os.environ.get("HOME", "/tmp")}


def test_a_short_minatar_run_reports_the_script_against_the_bound(tmp_path):
    out = tmp_path / "speed.md"
    done = subprocess.run(
        [sys.executable, str(BENCH), "--env-id", "MinAtar/Breakout-v1", "--configs", "net-t1",
         "a2c-t1", "--warmup", "160", "--steps", "800", "--log-every", "160", "--out",
         str(out)], capture_output=True, text=True, timeout=300, cwd=tmp_path, env=USER_ENV)
    assert done.returncode == 0, done.stderr
    report = out.read_text()
    rows = {m[0]: m[1:] for m in re.findall(
        r"^\| (net-t1|a2c-t1) \| 1 \| 1 \| [^|]+ \| ([\d,]+) \| [\d.]+ \| \*\*([\d,]+)\*\* "
        r"\| [^|]+ \| ([\d.]+) \| ", report, re.M)}
    assert set(rows) == {"net-t1", "a2c-t1"}
    assert rows["a2c-t1"][0] == "800"  # the timed steps: from the line at 160 to that at 960
    raw = json.loads(out.with_suffix(".json").read_text())
    ours = next(r for r in raw["results"] if r["config"] == "a2c-t1")
    assert ours["cpu_seconds"] > 0 and ours["returncode"] == 0
    assert re.search(r"a2c, --torch-threads 1: [\d,]+ SPS = [\d.]+× the network-only bound",
                     report)
    # The one repeat against the bound of its own repeat: the same figure here.
    paired = re.search(r"Per repeat, ÷ the bound of the same repeat: ([\d.]+)× \(median "
                       r"([\d.]+)×\)", report)
    net = next(r for r in raw["results"] if r["config"] == "net-t1")
    assert paired and float(paired[1]) == float(paired[2]) == round(ours["sps"] / net["sps"], 2)
