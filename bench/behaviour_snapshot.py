"""What a change of structure must not change: the scripts' scalars and the report's CSVs.

    python bench/behaviour_snapshot.py record BEFORE      # on the commit before the change
    python bench/behaviour_snapshot.py record AFTER       # after it
    python bench/behaviour_snapshot.py compare BEFORE AFTER

`record` trains every script (every mode of `rapl_a2c.py` and `rapl_ppo.py`) for a short, seeded
MiniQbert run, and `rapl_a2c.py` (every mode), `option_critic.py` and RAPL-PPO on
MinAtar/Breakout-v1 (its batched vector env), with one torch thread and keeps every TensorBoard
scalar but the wall-clock ones (`charts/SPS`), each as its exact float32 bits (`--scalars-every
1` where a script has the flag: every update's scalars, as before it); then it copies the
committed cpu sweep (`bench/results/experiments/cpu`), runs `routine-gym experiment report` on
the copy and keeps its CSVs. `compare` says, per script and per CSV, whether the two are
identical, and exits 1 when one is not; tags only the second record has (a new counter) are
listed, not compared.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SNAPSHOT = REPO / "bench" / "results" / "experiments" / "cpu"
DEMO = str(REPO / "demos" / "MiniQbert-v0.npz")
COMMON = ["--seed", "3", "--torch-threads", "1", "--eval-episodes", "2",
          "--checkpoint-every", "0"]
#: The env of a run whose flags name none.
DEFAULT_ENV = ["--env-id", "MiniQbert-v0"]
#: MiniQbert's profile learns at reward scale 0.01 unless told; the snapshot's runs keep the
#: scale 1 they were recorded at, so a snapshot of a commit before that default and one after
#: it compare the same training.
SCALE_1 = ["--reward-scale", "1"]
MINATAR = ["--env-id", "MinAtar/Breakout-v1", "--num-envs", "16", "--total-timesteps", "8000"]
# The first protocol's demo: a change's snapshot mines the same routines before and after.
MINATAR_DEMO = str(REPO / "demos" / "first" / "MinAtar-Breakout-v1.npz")
#: (name, script, flags): every script and mode, a few hundred updates each.
RUNS = [
    ("rapl_a2c-a2c", "rapl_a2c", ["--mode", "a2c", *SCALE_1, "--num-envs", "4",
                                  "--total-timesteps", "4000"]),
    ("rapl_a2c-rapl", "rapl_a2c", ["--mode", "rapl", *SCALE_1, "--num-envs", "4",
                                   "--total-timesteps", "4000"]),
    ("rapl_a2c-macro", "rapl_a2c", ["--mode", "macro", *SCALE_1, "--num-envs", "4",
                                    "--total-timesteps", "4000"]),
    ("rapl_sqil", "rapl_sqil", ["--demo", DEMO, "--total-timesteps", "1500",
                                "--learning-starts", "200", "--eval-max-steps", "200"]),
    ("rapl_sqil-k0", "rapl_sqil", ["--demo", DEMO, "--num-routines", "0",
                                   "--total-timesteps", "1500", "--learning-starts", "200",
                                   "--eval-max-steps", "200"]),
    ("bc", "bc", ["--demo", DEMO, "--gradient-steps", "300", "--eval-max-steps", "200"]),
    ("gail", "gail", ["--demo", DEMO, "--num-envs", "2", "--total-timesteps", "2048",
                      "--eval-max-steps", "200"]),
    ("option_critic", "option_critic", [*SCALE_1, "--num-envs", "4", "--total-timesteps", "4000"]),
    ("compile_a2c", "compile_a2c", [*SCALE_1, "--demo", DEMO, "--num-envs", "4",
                                    "--total-timesteps", "4000", "--compile-iterations", "50"]),
    ("rapl_ppo-ppo", "rapl_ppo", ["--mode", "ppo", *SCALE_1, "--num-envs", "4",
                                  "--total-timesteps", "4000"]),
    ("rapl_ppo-rapl", "rapl_ppo", ["--mode", "rapl", *SCALE_1, "--num-envs", "4",
                                   "--total-timesteps", "4000"]),
    ("rapl_ppo-macro", "rapl_ppo", ["--mode", "macro", *SCALE_1, "--num-envs", "4",
                                    "--total-timesteps", "4000"]),
    # MinAtar: the batched vector env (routine_gym.envs.minatar_vector) of the speed work.
    ("minatar-a2c", "rapl_a2c", [*MINATAR, "--mode", "a2c"]),
    ("minatar-rapl", "rapl_a2c", [*MINATAR, "--mode", "rapl", "--demo", MINATAR_DEMO]),
    ("minatar-macro", "rapl_a2c", [*MINATAR, "--mode", "macro", "--demo", MINATAR_DEMO]),
    ("minatar-authors", "rapl_a2c", [*MINATAR, "--authors", "--demo", MINATAR_DEMO]),
    ("minatar-option_critic", "option_critic", [*MINATAR]),
    ("minatar-ppo-rapl", "rapl_ppo", [*MINATAR, "--mode", "rapl", "--demo", MINATAR_DEMO]),
]
WALL_CLOCK = {"charts/SPS", "charts/decisions_per_second"}


def _scalars(folder: Path) -> dict[str, list[list]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out: dict[str, list[list]] = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        for tag in events.Tags()["scalars"]:
            if tag in WALL_CLOCK:
                continue
            # float32 bits: "identical" means bit for bit, not within a tolerance.
            out.setdefault(tag, []).extend(
                [e.step, struct.pack("<f", e.value).hex()] for e in events.Scalars(tag))
    return out


def record(dest: Path) -> None:
    dest.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, script, flags in RUNS:
            run_dir = Path(tmp) / name
            env = [] if "--env-id" in flags else DEFAULT_ENV
            # Every update's scalars where a script writes them every --scalars-every updates
            # (issue 48), so that a record compares with one made before the flag existed.
            every = ["--scalars-every", "1"] if "scalars_every:" in (
                REPO / "algos" / f"{script}.py").read_text() else []
            words = [sys.executable, str(REPO / "algos" / f"{script}.py"), *env, *COMMON, *flags,
                     *every, "--run-dir", str(run_dir)]
            proc = subprocess.run(words, capture_output=True, text=True)
            if proc.returncode != 0:
                sys.exit(f"{name} failed: {proc.stderr.strip().splitlines()[-1:]}")
            (run,) = run_dir.iterdir()
            scalars = _scalars(run)
            evaluation = json.loads((run / "eval.json").read_text())
            kept = {"scalars": scalars, "eval_returns": evaluation.get("returns")}
            (dest / f"{name}.json").write_text(json.dumps(kept, indent=1, sort_keys=True))
            print(f"{name}: {sum(len(v) for v in scalars.values())} scalars, "
                  f"{len(scalars)} tags", flush=True)
        sweep = Path(tmp) / "sweep"
        shutil.copytree(SNAPSHOT, sweep, ignore=shutil.ignore_patterns("report"))
        proc = subprocess.run([sys.executable, "-m", "routine_gym.cli", "experiment", "report",
                               str(sweep)], capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"report failed: {proc.stderr.strip()}")
        (dest / "report").mkdir(exist_ok=True)
        for csv in sorted((sweep / "report").glob("*.csv")):
            shutil.copy(csv, dest / "report" / csv.name)
        shutil.copy(sweep / "report" / "report.md", dest / "report" / "report.md")
        print(f"report: {len(list((dest / 'report').glob('*.csv')))} CSVs", flush=True)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _same_scalars(a: dict, b: dict) -> tuple[bool, int]:
    """Whether two records hold the same evaluation and scalars, and, where one record's
    script logged every `--scalars-every` updates and the other's every update (issue 48),
    at how many steps of the sparser one the two were compared (0: every step)."""
    if a == b:
        return True, 0
    if a["eval_returns"] != b["eval_returns"] or set(a["scalars"]) != set(b["scalars"]):
        return False, 0
    compared = 0
    for tag, rows in a["scalars"].items():
        theirs = b["scalars"][tag]
        if rows == theirs:
            continue
        sparse, dense = (rows, theirs) if len(rows) < len(theirs) else (theirs, rows)
        by_step = {step: bits for step, bits in dense}
        if any(by_step.get(step) != bits for step, bits in sparse):
            return False, 0
        compared += len(sparse)
    return True, compared


def compare(before: Path, after: Path) -> int:
    differ = 0
    for name, _, _ in RUNS:
        if not (before / f"{name}.json").is_file():
            print(f"{name:16s} not in {before} (recorded before the run was added)")
            continue
        if not (after / f"{name}.json").is_file():
            differ += 1
            print(f"{name:16s} not in {after}")
            continue
        a, b = (json.loads((d / f"{name}.json").read_text()) for d in (before, after))
        for kept in (a, b):  # a record made with fewer wall-clock tags left out
            kept["scalars"] = {t: v for t, v in kept["scalars"].items() if t not in WALL_CLOCK}
        # A tag the change adds (a new counter) is not a change of training: it is listed.
        added = sorted(set(b["scalars"]) - set(a["scalars"]))
        b["scalars"] = {t: v for t, v in b["scalars"].items() if t not in added}
        same, sparser = _same_scalars(a, b)
        differ += not same
        print(f"{name:16s} scalars {'identical' if same else 'DIFFER'}"
              + (f" at all {sparser} values the sparser record holds (the logging interval aside)"
                 if sparser else "")
              + (f" (and {len(added)} new tags: {', '.join(added)})" if added else ""))
    for csv in sorted((before / "report").glob("*.csv")):
        other = after / "report" / csv.name
        same = other.is_file() and _digest(csv) == _digest(other)
        differ += not same
        print(f"{csv.name:28s} {'identical' if same else 'DIFFER'}")
    extra = {p.name for p in (after / "report").glob("*.csv")} - {
        p.name for p in (before / "report").glob("*.csv")}
    for name in sorted(extra):
        differ += 1
        print(f"{name:28s} only after")
    return 1 if differ else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="action", required=True)
    r = sub.add_parser("record")
    r.add_argument("dest", type=Path)
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.action == "compare":
        for side in ("before", "after"):
            folder = getattr(args, side)
            if not any((folder / f"{name}.json").is_file() for name, _, _ in RUNS):
                parser.error(f"{side} {folder} is not a record of `behaviour_snapshot.py record` "
                             "(it has no run's .json)")
    if args.action == "record":
        record(args.dest)
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    sys.exit(main())
