"""Copy what a sweep folder should keep in the repository: the report, the manifests and every
finished run's config and result (with its binned training curve) and each expert's demo (no
checkpoints, no TensorBoard logs), plus the provenance. The snapshot is itself a sweep folder:
copy it and run the same command with `--out` the copy to continue the sweep where it stopped.

    python bench/snapshot_experiments.py SWEEP bench/results/experiments/cpu \\
        --command "routine-gym experiment run NAME --budget cpu --out SWEEP --jobs 2"

Writes DEST/{experiment}.json, DEST/runs/KEY/{config,result}.json (and
demo.npz), DEST/report/ (the figures, CSVs and report.md of `routine-gym experiment report
DEST`, drawn from the copy, so the report names DEST and shows only what was committed) and
DEST/provenance.json (machine, date, commit, command, runs finished per experiment, and one
line per snapshot so far: what ran when).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import base_machine_info, load_average  # noqa: E402

from routine_gym.atomic import atomic_write_text  # noqa: E402
from routine_gym.experiments.report import write_report  # noqa: E402
from routine_gym.experiments.specs import EXPERIMENTS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep folder (--out of experiment run)")
    parser.add_argument("dest", type=Path, help="where the snapshot goes")
    parser.add_argument("--command", action="append", default=[],
                        help="the command that ran the sweep (repeatable)")
    args = parser.parse_args()

    dest = args.dest
    # The sweep folder is the truth and the snapshot mirrors it; a result only the snapshot has
    # means the sweep did not start from it, and copying would throw that result away.
    lost = sorted(p.parent.name for p in dest.glob("runs/*/result.json")
                  if not (args.sweep / "runs" / p.parent.name / "result.json").exists())
    if lost:
        sys.exit(f"{dest} holds {len(lost)} finished run(s) that {args.sweep} lacks (first: "
                 f"{lost[0]}); continue the sweep from the snapshot (cp -r {dest} SWEEP) "
                 "before snapshotting it")
    dest.mkdir(parents=True, exist_ok=True)
    finished: dict[str, dict[str, int]] = {}
    listed: set[str] = set()
    for name in EXPERIMENTS:
        manifest = args.sweep / f"{name}.json"
        if not manifest.exists():
            continue
        shutil.copy2(manifest, dest / manifest.name)
        keys = [r["key"] for r in json.loads(manifest.read_text())["runs"]]
        done = 0
        for key in keys:
            for file in ("config.json", "result.json", "demo.npz"):
                source = args.sweep / "runs" / key / file
                if source.exists():
                    (dest / "runs" / key).mkdir(parents=True, exist_ok=True)
                    shutil.copy2(source, dest / "runs" / key / file)
            done += (args.sweep / "runs" / key / "result.json").exists()
        finished[name] = {"runs": len(set(keys)), "finished": done}
        listed.update(keys)
    for name in EXPERIMENTS:
        if name not in finished:
            (dest / f"{name}.json").unlink(missing_ok=True)
    for folder in dest.glob("runs/*"):
        if folder.name not in listed:
            shutil.rmtree(folder)
    # The report is drawn afresh, so none of an earlier snapshot's figures is left over; the
    # random policy's scores are measured once per game and cached, so reuse the sweep's.
    if (dest / "report").exists():
        shutil.rmtree(dest / "report")
    cached = args.sweep / "report" / "reference_scores.json"
    if cached.exists():
        (dest / "report").mkdir()
        shutil.copy2(cached, dest / "report" / cached.name)
    write_report(dest)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    history = []
    if (dest / "provenance.json").exists():
        history = json.loads((dest / "provenance.json").read_text()).get("snapshots", [])
    history.append({"date": date, "commit": commit,
                    "finished": sum(c["finished"] for c in finished.values())})
    provenance = {"date": date, "commit": commit, "commands": args.command,
                  "experiments": finished, "snapshots": history,
                  "machine": {**base_machine_info(), "load_average": load_average()}}
    atomic_write_text(dest / "provenance.json", json.dumps(provenance, indent=2) + "\n")
    for name, counts in finished.items():
        print(f"{name:12s} {counts['finished']}/{counts['runs']} runs finished")
    print(f"snapshot in {dest}")


if __name__ == "__main__":
    main()
