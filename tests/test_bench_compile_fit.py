"""`bench/bench_compile_fit.py` run as a user runs it, with a 5-step fit on the shipped Breakout
demo: it writes its report and JSON, times the torch-loop peer beside ours, says the target is
not judged on a shortened fit, and refuses a fit of zero steps with a one-line error."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "bench" / "bench_compile_fit.py"


def test_a_short_fit_writes_its_report_and_is_not_judged(tmp_path):
    out = tmp_path / "compile_fit.md"
    done = subprocess.run([sys.executable, str(BENCH), "--envs", "MinAtar/Breakout-v1",
                           "--iterations", "5", "--no-peer", "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    report = out.read_text()
    assert "compile_iterations 5 (default 1000)" in report
    assert "not judged (--iterations 5, the script's default is 1000)" in report
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["settings"]["compile_iterations"] == 5 and data["target_seconds"] == 60.0
    row, torch_loop = data["results"]
    assert row["env_id"] == "MinAtar/Breakout-v1" and row["kind"] == "ours"
    # avx2 or portable; the torch loop where the core is not built (an install without C++)
    from routine_gym import _native

    built = _native.core("masked_gru") is not None
    assert row["gru"].startswith("compiled loops (") if built else row["gru"] == "torch loop"
    assert torch_loop["kind"] == "torch-loop" and torch_loop["gru"] == "torch loop"
    assert torch_loop["command"].startswith("ROUTINE_GYM_COMPILE_GRU=torch ")
    assert torch_loop["returncode"] == 0 and torch_loop["decisions"] == 286
    assert "| torch loop total s | ×ours |" in report
    assert row["returncode"] == 0 and row["error"] == ""
    assert row["decisions"] == 286  # the shipped demo's decisions (286 steps, all decided)
    # The phases add up to the total (rounding aside) and each took some time.
    phases = row["states_s"] + row["train_s"] + row["segment_s"] + row["options_s"]
    assert 0 < phases <= row["total_s"] + 1e-6
    assert row["train_s"] > 0 and row["options_s"] > 0
    # At most one code per option (num_options 3): a 5-iteration fit of the current Breakout
    # demo uses 2 of them (compile_a2c warns of it too), the first set's used all 3.
    assert 1 <= len(row["codes"]) <= 3


def test_a_fit_of_zero_steps_is_refused():
    done = subprocess.run([sys.executable, str(BENCH), "--iterations", "0"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        "bench_compile_fit.py: error: --iterations needs to be ≥ 1, actual value: 0")
