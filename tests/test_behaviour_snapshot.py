"""`bench/behaviour_snapshot.py compare` run as a user runs it, on small records made by hand in
the layout `record` writes (`NAME.json` per run: its scalars as `[step, float32 bits]` rows and
its evaluation returns; `report/*.csv`): a pair that differs only where compare looks away (the
wall-clock tags, a tag only the second has, a sparser logging interval) exits 0, a change of a
scalar's bits, of a CSV, or a run or CSV on one side only exits 1 naming it; a folder that is no
record is refused with a one-line error. (`record` trains every script: too slow for a test.)"""

from __future__ import annotations

import copy
import json
import struct
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "bench" / "behaviour_snapshot.py"


def bits(value: float) -> str:
    """A scalar as `record` keeps it: its float32 bits in hex."""
    return struct.pack("<f", value).hex()


#: Two runs of `RUNS`: a2c logged at steps 80, 160, 240, 320; bc at 2 and 4.
RECORD = {
    "rapl_a2c-a2c": {
        "scalars": {"losses/value_loss": [[80 * k, bits(1 / k)] for k in (1, 2, 3, 4)],
                    "charts/SPS": [[80, bits(1234.0)]]},
        "eval_returns": [1.0, 2.0],
    },
    "bc": {"scalars": {"losses/loss": [[2, bits(0.5)], [4, bits(0.25)]]},
           "eval_returns": [75.0, 75.0]},
}
CSVS = {"summary.csv": "run,return\na2c,1.5\n", "budgets.csv": "budget,steps\nquick,4000\n"}


def write_record(folder: Path, runs: dict, csvs: dict) -> Path:
    (folder / "report").mkdir(parents=True)
    for name, kept in runs.items():
        (folder / f"{name}.json").write_text(json.dumps(kept, indent=1, sort_keys=True))
    for name, text in csvs.items():
        (folder / "report" / name).write_text(text)
    (folder / "report" / "report.md").write_text("# not compared\n")
    return folder


def compare(before: Path, after: Path, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), "compare", str(before), str(after)],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def verdicts(stdout: str) -> dict[str, str]:
    """Each printed line as name -> the rest of its words."""
    return {line.split()[0]: " ".join(line.split()[1:]) for line in stdout.splitlines()}


def test_records_alike_but_where_compare_looks_away_are_identical(tmp_path):
    before = write_record(tmp_path / "before", RECORD, CSVS)
    after_runs = copy.deepcopy(RECORD)
    a2c = after_runs["rapl_a2c-a2c"]["scalars"]
    a2c["charts/SPS"] = [[80, bits(999.0)]]  # wall clock: never compared
    a2c["counters/interruptions"] = [[80, bits(0.0)]]  # a new counter: listed, not compared
    # bc logged every step after the change: the same bits at the two steps before has.
    after_runs["bc"]["scalars"]["losses/loss"] = [[1, bits(0.7)], [2, bits(0.5)],
                                                  [3, bits(0.4)], [4, bits(0.25)]]
    after = write_record(tmp_path / "after", after_runs, CSVS)
    done = compare(before, after, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    seen = verdicts(done.stdout)
    assert seen["rapl_a2c-a2c"] == "scalars identical (and 1 new tags: counters/interruptions)"
    assert seen["bc"] == ("scalars identical at all 2 values the sparser record holds "
                          "(the logging interval aside)")
    assert seen["summary.csv"] == seen["budgets.csv"] == "identical"
    # Every other run of RUNS is one the hand-made record lacks: said, not failed.
    assert seen["rapl_ppo-ppo"] == f"not in {before} (recorded before the run was added)"
    assert not any("DIFFER" in line for line in done.stdout.splitlines())


def test_a_change_exits_1_and_names_what_differs(tmp_path):
    before = write_record(tmp_path / "before", RECORD, CSVS)
    after_runs = copy.deepcopy(RECORD)
    # One bit of one value: 0.25 and the next float32 up are "within tolerance", not identical.
    next_up = struct.unpack("<f", struct.pack("<I", struct.unpack("<I", struct.pack(
        "<f", 0.25))[0] + 1))[0]
    after_runs["bc"]["scalars"]["losses/loss"][1][1] = bits(next_up)
    after_runs["rapl_a2c-a2c"]["eval_returns"] = [1.0, 3.0]
    csvs = {**CSVS, "summary.csv": "run,return\na2c,1.6\n", "extra.csv": "x\n1\n"}
    after = write_record(tmp_path / "after", after_runs, csvs)
    done = compare(before, after, tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    seen = verdicts(done.stdout)
    assert seen["bc"] == seen["rapl_a2c-a2c"] == "scalars DIFFER"
    assert seen["summary.csv"] == "DIFFER" and seen["budgets.csv"] == "identical"
    assert seen["extra.csv"] == "only after"


def test_a_run_only_before_has_is_a_difference_not_a_crash(tmp_path):
    before = write_record(tmp_path / "before", RECORD, CSVS)
    after = write_record(tmp_path / "after", {"bc": RECORD["bc"]}, CSVS)
    done = compare(before, after, tmp_path)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Traceback" not in done.stderr
    seen = verdicts(done.stdout)
    assert seen["rapl_a2c-a2c"] == f"not in {after}" and seen["bc"] == "scalars identical"


def test_a_folder_that_is_no_record_is_refused_in_one_line(tmp_path):
    record = write_record(tmp_path / "record", RECORD, CSVS)
    missing = tmp_path / "missing"
    for before, after, wrong in [(missing, record, f"before {missing}"),
                                 (record, tmp_path, f"after {tmp_path}")]:
        done = compare(before, after, tmp_path)
        assert done.returncode == 2, done.stdout
        assert "Traceback" not in done.stderr
        assert done.stderr.strip().splitlines()[-1] == (
            f"behaviour_snapshot.py: error: {wrong} is not a record of "
            "`behaviour_snapshot.py record` (it has no run's .json)")
