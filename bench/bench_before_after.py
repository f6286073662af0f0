"""Benchmark: whole training runs of `algos/rapl_a2c.py` from two checkouts, in turn.

    python bench/bench_before_after.py BEFORE_DIR AFTER_DIR --out bench/results/before_after.md

Each checkout runs its own `algos/rapl_a2c.py` with `PYTHONPATH` set to it (its own package
and compiled cores, which the caller builds in place first), the same flags and the same demo:
`--mode a2c` and `--mode rapl` on MinAtar Breakout (200,000 agent steps) and ALE Qbert (20,000),
16 envs, one torch thread, no evaluation, no checkpoints. The two checkouts alternate (before,
after, before, after, …) so that a drift of the machine's speed reaches both alike. Per run:
the whole process's wall time and CPU time (`os.wait4`), and the script's own SPS on its last
progress line (the training loop alone: start-up and mining left out). The table gives the
median of each and after ÷ before; a speed change within 5 % is what issue 48 asks of a
change of structure. Needs a quiet machine: anything else running shows as noise.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import base_machine_info, children_die_with_me, load_average

REPO = Path(__file__).resolve().parent.parent
#: The first protocol's Breakout demo (the demo both checkouts had as their default).
BREAKOUT_DEMO = str(REPO / "demos" / "first" / "MinAtar-Breakout-v1.npz")
#: (name, flags): the runs timed, each from both checkouts.
RUNS = [
    ("MinAtar Breakout a2c", ["--env-id", "MinAtar/Breakout-v1", "--mode", "a2c",
                              "--total-timesteps", "200000"]),
    ("MinAtar Breakout rapl", ["--env-id", "MinAtar/Breakout-v1", "--mode", "rapl",
                               "--total-timesteps", "200000",
                               "--demo", BREAKOUT_DEMO]),
    ("ALE Qbert a2c", ["--env-id", "ALE/Qbert-v5", "--mode", "a2c", "--total-timesteps", "20000"]),
    ("ALE Qbert rapl", ["--env-id", "ALE/Qbert-v5", "--mode", "rapl", "--total-timesteps",
                        "20000", "--demo", str(REPO / "demos" / "ALE-Qbert-v5.npz")]),
]
COMMON = ["--num-envs", "16", "--torch-threads", "1", "--eval-episodes", "0",
          "--checkpoint-every", "0", "--log-every", "10000", "--seed", "1"]
DEFAULT_OUT = REPO / "bench" / "results" / "before_after.md"
SPS = re.compile(r"SPS\s+(\d+)")


def timed_run(checkout: Path, flags: list[str], run_dir: str) -> tuple[float, float, int]:
    """Wall seconds, CPU seconds (the process and its children) and the last SPS printed."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    words = [sys.executable, str(checkout / "algos" / "rapl_a2c.py"), *flags, *COMMON,
             "--run-dir", run_dir]
    start = time.perf_counter()
    proc = subprocess.Popen(words, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    out = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"{checkout}: {' '.join(flags)} failed:\n{out[-2000:]}")
    rates = SPS.findall(out)
    return wall, usage.ru_utime + usage.ru_stime, int(rates[-1]) if rates else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--repeats", type=int, default=4)
    parser.add_argument("--runs", nargs="+", default=[name for name, _ in RUNS],
                        choices=[name for name, _ in RUNS])
    parser.add_argument("--steps", type=int, default=None,
                        help="agent steps of every run instead of each run's own (a quick check)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, not {args.repeats}")
    if args.steps is not None and args.steps < 1:
        parser.error(f"--steps must be at least 1, not {args.steps}")
    for side in ("before", "after"):
        if not (getattr(args, side) / "algos" / "rapl_a2c.py").is_file():
            parser.error(f"{side} {getattr(args, side)} is not a routine-gym checkout "
                         "(it has no algos/rapl_a2c.py)")
    rows = []
    loads = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, flags in RUNS:
            if name not in args.runs:
                continue
            if args.steps is not None:
                at = flags.index("--total-timesteps") + 1
                flags = [*flags[:at], str(args.steps), *flags[at + 1:]]
            got: dict[str, list[tuple[float, float, int]]] = {"before": [], "after": []}
            for repeat in range(args.repeats + 1):  # the first pair warms caches: not counted
                for side in ("before", "after"):
                    loads.append(load_average())
                    result = timed_run(getattr(args, side), flags, f"{tmp}/{side}{repeat}")
                    if repeat:
                        got[side].append(result)
                    print(f"{name} {side} #{repeat}: wall {result[0]:.2f} s, cpu "
                          f"{result[1]:.2f} s, SPS {result[2]}", flush=True)
            med = {side: [statistics.median(r[i] for r in got[side]) for i in range(3)]
                   for side in got}
            # Pair by pair (a run and the one after it): a drift of the machine's speed that
            # outlasts a pair cancels in its ratio, not in the ratio of the medians.
            pairs = sorted(a[0] / b[0] for b, a in zip(got["before"], got["after"], strict=True))
            rows.append((name, med["before"], med["after"], pairs))
    lines = [f"# {__doc__.splitlines()[0]}", "",
             f"`python bench/bench_before_after.py {args.before} {args.after} --repeats "
             f"{args.repeats}"
             + ("" if len(args.runs) == len(RUNS) else " --runs " + " ".join(
                 f"'{r}'" for r in args.runs))
             + ("" if args.steps is None else f" --steps {args.steps}")
             + ("" if args.out == DEFAULT_OUT else f" --out {args.out}") + "`", "",
             f"before: `{args.before}`; after: `{args.after}`; {args.repeats} counted runs of "
             "each side, alternating, after one pair not counted. Medians:", "",
             "| run | wall before (s) | wall after (s) | after ÷ before | SPS before | "
             "SPS after | after ÷ before | CPU s before | CPU s after | wall after ÷ before, "
             "pair by pair: median (range) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name, b, a, pairs in rows:
        lines.append(f"| {name} | {b[0]:.2f} | {a[0]:.2f} | {a[0] / b[0]:.3f} | {b[2]:,.0f} | "
                     f"{a[2]:,.0f} | {a[2] / b[2]:.3f} | {b[1]:.2f} | {a[1]:.2f} | "
                     f"{statistics.median(pairs):.3f} ({pairs[0]:.3f}–{pairs[-1]:.3f}) |")
    machine = base_machine_info()
    lines += ["", "Machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()),
              f"Load averages before each run: {', '.join(loads)}", ""]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    children_die_with_me()
    sys.exit(main())
