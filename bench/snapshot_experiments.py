"""Copy what a sweep folder should keep in the repository: the report, the manifests and every
finished run's config and result (with its binned training curve) and each expert's demo (no
checkpoints, no TensorBoard logs), plus the provenance. The snapshot is itself a sweep folder:
copy it and run the same command with `--out` the copy to continue the sweep where it stopped.

    .venv/bin/python bench/snapshot_experiments.py SWEEP bench/results/experiments/cpu \\
        --command "routine-gym experiment run NAME --budget cpu --out SWEEP --jobs 2"
    .venv/bin/python bench/snapshot_experiments.py SWEEP bench/results/experiments/long \\
        --command "bench/sweep_long.sh SWEEP 2" --beside bench/results/experiments/cpu

Writes DEST/{experiment}.json, DEST/runs/KEY/{config,result}.json (and diverged.json,
demo.npz), DEST/report/ (the figures, CSVs and report.md of `routine-gym experiment report
DEST [--beside OTHER]`, drawn from the copy, so the report names DEST and shows only what was
committed) and DEST/provenance.json (machine, date, commit, command, the `--beside` folder,
runs finished per experiment, and one line per snapshot so far: what ran when).

A snapshot whose report compared two budgets (`budgets_*` files) keeps the comparison: give
`--beside OTHER` (it is noted in provenance.json and reused by the next snapshot); without one
known, the snapshot is refused rather than drop the committed `budgets_*` files.
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
from routine_gym.errors import UsageError, one_line  # noqa: E402
from routine_gym.experiments import json_kind, read_json_object  # noqa: E402
from routine_gym.experiments.registry import EXPERIMENTS  # noqa: E402
from routine_gym.experiments.report import write_report  # noqa: E402
from routine_gym.experiments.results import result_problem  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def finished(folder: Path, key: str) -> bool:
    """Whether run `key` of the sweep folder `folder` finished: its `result.json` parses and has
    the report's shape (a corrupt one is not kept: the sweep reruns that run)."""
    path = folder / "runs" / key / "result.json"
    if not path.is_file():
        return False
    try:
        return result_problem(read_json_object(path), key) is None
    except UsageError:
        return False


def manifest_keys(path: Path) -> list[str]:
    """The run keys a manifest lists (UsageError naming it when it is not a manifest)."""
    runs = read_json_object(path).get("runs")
    if not isinstance(runs, list) or not all(
            isinstance(r, dict) and isinstance(r.get("key"), str) and r["key"]
            and "/" not in r["key"] and r["key"] not in (".", "..") for r in runs):
        raise UsageError(f"{path}: `runs` is not a list of run entries with their keys")
    return [r["key"] for r in runs]


def previous_beside(dest: Path) -> Path | None:
    """The `--beside` folder the last snapshot into `dest` noted (relative to the repository
    when it lies in it), or None."""
    path = dest / "provenance.json"
    if not path.exists():
        return None
    noted = read_json_object(path).get("beside")
    if noted is None:
        return None
    if not isinstance(noted, str) or not noted:
        raise UsageError(f"{path}: `beside` is {json_kind(noted)}, not a folder name")
    return Path(noted) if Path(noted).is_absolute() else REPO / noted


def beside_note(beside: Path) -> str:
    """`beside` as provenance.json notes it: relative to the repository when it lies in it."""
    resolved = beside.resolve()
    try:
        return str(resolved.relative_to(REPO))
    except ValueError:
        return str(resolved)


def main() -> None:
    try:
        snapshot()
    except UsageError as exc:
        sys.exit(f"snapshot_experiments.py: error: {one_line(exc)}")


def snapshot() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep folder (--out of experiment run)")
    parser.add_argument("dest", type=Path, help="where the snapshot goes")
    parser.add_argument("--command", action="append", default=[],
                        help="the command that ran the sweep (repeatable)")
    parser.add_argument("--beside", type=Path, default=None, metavar="OTHER_SWEEP",
                        help="draw the report with `--beside OTHER_SWEEP` (the rl experiment "
                        "at two budgets; default: the one the last snapshot noted)")
    args = parser.parse_args()

    dest = args.dest
    # The sweep folder is the truth and the snapshot mirrors it; a result only the snapshot has
    # means the sweep did not start from it, and copying would throw that result away.
    lost = sorted(p.parent.name for p in dest.glob("runs/*/result.json")
                  if finished(dest, p.parent.name) and not finished(args.sweep, p.parent.name))
    if lost:
        sys.exit(f"{dest} holds {len(lost)} finished run(s) that {args.sweep} lacks (first: "
                 f"{lost[0]}); continue the sweep from the snapshot (cp -r {dest} SWEEP) "
                 "before snapshotting it")
    manifests = {name: args.sweep / f"{name}.json" for name in EXPERIMENTS
                 if (args.sweep / f"{name}.json").exists()}
    if not manifests:
        raise UsageError(f"{args.sweep}: not a sweep folder: none of "
                         f"{', '.join(n + '.json' for n in EXPERIMENTS)} is there")
    keys_of = {name: manifest_keys(path) for name, path in manifests.items()}
    history = []
    if (dest / "provenance.json").exists():
        history = read_json_object(dest / "provenance.json").get("snapshots", [])
        if not isinstance(history, list):
            raise UsageError(f"{dest / 'provenance.json'}: `snapshots` is {json_kind(history)}, "
                             "not a list")
    beside = args.beside if args.beside is not None else previous_beside(dest)
    if beside is None and (dest / "report" / "budgets_fig2.csv").exists():
        raise UsageError(f"{dest / 'report'} compares two budgets (budgets_*); give --beside "
                         "OTHER_SWEEP (e.g. bench/results/experiments/cpu) to keep the "
                         "comparison, or delete its budgets_* files to drop it")
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{dest}: cannot make the folder ({exc.strerror})") from None
    counts: dict[str, dict[str, int]] = {}
    listed: set[str] = set()
    for name, manifest in manifests.items():
        shutil.copy2(manifest, dest / manifest.name)
        keys = keys_of[name]
        done = 0
        for key in keys:
            ok = finished(args.sweep, key)
            # diverged.json: a grid point that diverged, an answer the report shows
            for file in ("config.json", "result.json", "diverged.json", "demo.npz"):
                source = args.sweep / "runs" / key / file
                if source.is_file() and (file != "result.json" or ok):
                    (dest / "runs" / key).mkdir(parents=True, exist_ok=True)
                    shutil.copy2(source, dest / "runs" / key / file)
            if not ok:
                (dest / "runs" / key / "result.json").unlink(missing_ok=True)
            done += ok
        counts[name] = {"runs": len(set(keys)), "finished": done}
        listed.update(keys)
    for name in EXPERIMENTS:
        if name not in counts:
            (dest / f"{name}.json").unlink(missing_ok=True)
    for folder in dest.glob("runs/*"):
        if folder.name not in listed:
            shutil.rmtree(folder)
    # The report is drawn afresh, so none of an earlier snapshot's figures is left over; the
    # random policy's scores are measured once per game and cached, so reuse the sweep's.
    if (dest / "report").is_dir():
        shutil.rmtree(dest / "report")
    elif (dest / "report").exists():
        (dest / "report").unlink()
    cached = args.sweep / "report" / "reference_scores.json"
    if cached.exists():
        (dest / "report").mkdir()
        shutil.copy2(cached, dest / "report" / cached.name)
    write_report(dest, beside=beside)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    history.append({"date": date, "commit": commit,
                    "finished": sum(c["finished"] for c in counts.values())})
    provenance = {"date": date, "commit": commit, "commands": args.command,
                  **({"beside": beside_note(beside)} if beside is not None else {}),
                  "experiments": counts, "snapshots": history,
                  "machine": {**base_machine_info(), "load_average": load_average()}}
    atomic_write_text(dest / "provenance.json", json.dumps(provenance, indent=2) + "\n")
    for name, count in counts.items():
        print(f"{name:12s} {count['finished']}/{count['runs']} runs finished")
    print(f"snapshot in {dest}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
