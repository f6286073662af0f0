"""`bench/recount_runs.py` run as a user runs it: a real `--interrupt` run of `rapl_a2c.py`
whose `result.json` was written before the sweep kept `interruptions` gets its counters re-read
from its TensorBoard logs, and nothing else in the file changes; a second pass changes nothing;
a folder that is no sweep is refused in one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from routine_gym.experiments.run_counters import counter_record
from routine_gym.experiments.training_curves import read_scalars

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "bench" / "recount_runs.py"
STEPS = 1_200


def _run(*words, cwd):
    return subprocess.run([sys.executable, *map(str, words)], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_a_result_without_interruptions_gets_them_from_the_logs(tmp_path):
    folder = tmp_path / "sweep" / "runs" / "abc123def456"
    folder.mkdir(parents=True)
    done = _run(ROOT / "algos" / "rapl_a2c.py", "--env-id", "MinAtar/Breakout-v1", "--mode",
                "rapl", "--interrupt", "0.0", "--num-envs", "4", "--total-timesteps", STEPS,
                "--eval-episodes", "1", "--checkpoint-every", "0", "--scalars-every", "1",
                "--torch-threads", "1", "--run-dir", folder, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    run_dir = next(folder.glob("*/eval.json")).parent
    expected = counter_record(read_scalars(run_dir), STEPS)
    # Margin 0: every inner state where the policy prefers another action stops the routine.
    assert expected["interruptions"] > 0 and 0 < expected["interrupted_share"] <= 1
    old = {k: v for k, v in expected.items() if k not in ("interruptions", "interrupted_share")}
    result = {"key": folder.name, "run_dir": run_dir.name,
              "eval": json.loads((run_dir / "eval.json").read_text()), "counters": old,
              "seconds": 12.5, "finished": "2026-12-07T04:00:00Z"}
    (folder / "result.json").write_text(json.dumps(result, indent=2) + "\n")
    (folder / "config.json").write_text(json.dumps(
        {"key": folder.name, "steps": STEPS, "flags": {"mode": "rapl", "interrupt": 0.0}}))
    # A run folder without logs (as in a snapshot) is left alone.
    bare = tmp_path / "sweep" / "runs" / "000000000000"
    bare.mkdir()
    (bare / "config.json").write_text(json.dumps({"steps": STEPS, "flags": {}}))
    (bare / "result.json").write_text(json.dumps({"eval": result["eval"], "run_dir": "gone"}))

    done = _run(SCRIPT, tmp_path / "sweep", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == ("1 finished run(s) re-read from their logs, 1 with new "
                                   "counters; 1 without logs left as they were")
    after = json.loads((folder / "result.json").read_text())
    assert after["counters"] == expected
    assert {k: v for k, v in after.items() if k != "counters"} == \
        {k: v for k, v in result.items() if k != "counters"}
    again = _run(SCRIPT, tmp_path / "sweep", cwd=tmp_path)
    assert "1 finished run(s) re-read from their logs, 0 with new counters" in again.stdout


def test_a_folder_that_is_no_sweep_is_refused(tmp_path):
    done = _run(SCRIPT, tmp_path, cwd=tmp_path)
    assert done.returncode == 1
    assert done.stderr.strip() == f"recount_runs.py: error: {tmp_path}: not a sweep folder " \
                                  "(it has no runs/)"
