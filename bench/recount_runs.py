"""Re-read each finished run's counters from its TensorBoard logs with this checkout's
`counter_record`, for a sweep whose runs finished under older code (a counter it did not keep:
`interruptions` before issue 49's report read it).

    .venv/bin/python bench/recount_runs.py SWEEP

For every run folder of SWEEP with a valid `result.json` and its run's event files, the
`counters` of `result.json` are replaced (atomically) by what `curve_and_counters` reads from
the logs, the way the sweep itself writes them when a run ends; nothing else in the file
changes. A run without its logs (a snapshot) is left as it is. Prints how many runs changed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import UsageError, one_line
from routine_gym.experiments import read_json_object
from routine_gym.experiments.backends import curve_and_counters
from routine_gym.experiments.results import result_problem


def recount(sweep: Path) -> tuple[int, int, int]:
    """(runs read, runs changed, runs without logs) of the sweep folder `sweep`."""
    if not (sweep / "runs").is_dir():
        raise UsageError(f"{sweep}: not a sweep folder (it has no runs/)")
    read = changed = no_logs = 0
    for folder in sorted(p for p in (sweep / "runs").iterdir() if p.is_dir()):
        path = folder / "result.json"
        if not path.is_file() or not (folder / "config.json").is_file():
            continue
        try:
            result = read_json_object(path)
        except UsageError:
            continue
        if result_problem(result, folder.name) is not None:
            continue
        run_dir = folder / str(result.get("run_dir", ""))
        if not result.get("run_dir") or not any(run_dir.glob("events.out.tfevents.*")):
            no_logs += 1
            continue
        _, counters = curve_and_counters(run_dir, read_json_object(folder / "config.json"))
        read += 1
        if counters is not None and counters != result.get("counters"):
            result["counters"] = counters
            atomic_write_text(path, json.dumps(result, indent=2) + "\n")
            changed += 1
    return read, changed, no_logs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep folder (--out of experiment run)")
    args = parser.parse_args()
    try:
        read, changed, no_logs = recount(args.sweep)
    except UsageError as exc:
        sys.exit(f"recount_runs.py: error: {one_line(exc)}")
    print(f"{read} finished run(s) re-read from their logs, {changed} with new counters"
          + (f"; {no_logs} without logs left as they were" if no_logs else ""))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from common import children_die_with_me  # the house rule of bench/ (it starts none)

    children_die_with_me()
    main()
