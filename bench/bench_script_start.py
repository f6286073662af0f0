"""Benchmark: what `routine_gym.plumbing.eager_optim` saves a script's process.

    python bench/bench_script_start.py --repeats 5 --out bench/results/script_start.md

Each round runs every command twice, in turn: as the scripts run (RMSprop and Adam step
without importing TorchDynamo) and with `ROUTINE_GYM_EAGER_OPTIM=0` (torch's own path, which
imports it at the first optimizer call), and records each process's wall and CPU seconds
(user + system, from `getrusage` of the children). The commands are short runs of the scripts
the test suite starts most (1,000 agent steps, one evaluation episode: a smoke run) and one
of RAPL-A2C at 10^5 steps, so the saving is shown against a run that trains for a while too.
Medians over the rounds; the two sides of a command run back to back, under the same load.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import base_machine_info, children_die_with_me, fail, git_head, load_average

ROOT = Path(__file__).resolve().parent.parent
SWITCH = "ROUTINE_GYM_EAGER_OPTIM"

#: (label, script, its flags): the smoke runs of the two scripts the suite starts most, and a
#: run long enough to train.
COMMANDS = (
    ("A2C, 1,000 steps", "rapl_a2c", ("--mode", "a2c", "--total-timesteps", "1000")),
    ("RAPL-A2C, 1,000 steps", "rapl_a2c", ("--mode", "rapl", "--total-timesteps", "1000")),
    ("PPO, 1,000 steps", "rapl_ppo", ("--mode", "ppo", "--total-timesteps", "1000")),
    ("RAPL-A2C, 100,000 steps", "rapl_a2c", ("--mode", "rapl", "--total-timesteps", "100000")),
)


def timed(words: list[str], switch: str, cwd: str) -> tuple[float, float]:
    """Wall and CPU seconds of one process of `words` with the switch set to `switch`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run(words, capture_output=True, text=True, cwd=cwd,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", SWITCH: switch})
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        fail(f"{' '.join(words)} failed: {proc.stderr.strip().splitlines()[-1:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="rounds (5)")
    parser.add_argument("--long-steps", type=int, default=100_000,
                        help="agent steps of the run that trains for a while (100000)")
    parser.add_argument("--out", type=Path, default=None, help="the markdown report")
    args = parser.parse_args()
    if args.repeats < 1:
        fail(f"--repeats must be at least 1, not {args.repeats}")
    if args.long_steps < 1000:
        fail(f"--long-steps must be at least 1000, not {args.long_steps}")
    commands = [(label.replace("100,000", f"{args.long_steps:,}"), script,
                 tuple(str(args.long_steps) if w == "100000" else w for w in flags))
                for label, script, flags in COMMANDS]
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    load = load_average()
    with tempfile.TemporaryDirectory() as tmp:
        for round_ in range(1, args.repeats + 1):
            for label, script, flags in commands:
                for switch in ("1", "0"):
                    words = [sys.executable, str(ROOT / "algos" / f"{script}.py"), *flags,
                             "--env-id", "MinAtar/Breakout-v1", "--eval-episodes", "1",
                             "--num-envs", "4", "--run-dir", f"{tmp}/r{round_}{switch}",
                             "--torch-threads", "1"]
                    wall, cpu = timed(words, switch, tmp)
                    times.setdefault((label, switch), []).append((wall, cpu))
                    side = "eager" if switch == "1" else "torch's"
                    print(f"round {round_} {label:26s} {side:8s} wall {wall:6.2f} s  "
                          f"cpu {cpu:6.2f} s", flush=True)
    info = base_machine_info()
    rows = ["| command | wall, eager | wall, torch's | saved | CPU, eager | CPU, torch's | "
            "saved |", "|---|---:|---:|---:|---:|---:|---:|"]
    for label, _, _ in commands:
        eager = [statistics.median(x) for x in zip(*times[label, "1"], strict=True)]
        torchs = [statistics.median(x) for x in zip(*times[label, "0"], strict=True)]
        rows.append(f"| {label} | {eager[0]:.2f} s | {torchs[0]:.2f} s | "
                    f"{torchs[0] - eager[0]:.2f} s ({1 - eager[0] / torchs[0]:.0%}) | "
                    f"{eager[1]:.2f} s | {torchs[1]:.2f} s | "
                    f"{torchs[1] - eager[1]:.2f} s ({1 - eager[1] / torchs[1]:.0%}) |")
    text = "\n".join([
        "# A script's start: optimizers without TorchDynamo's import", "",
        f"`python bench/bench_script_start.py --repeats {args.repeats} --long-steps "
        f"{args.long_steps}` ({info['date']}, {info['cpu']}, {info['cores']} cores, load "
        f"before {load}, code {git_head(ROOT, ['routine_gym', 'algos'])}). Medians of "
        f"{args.repeats} rounds of each process's wall and CPU seconds (MinAtar Breakout, 4 "
        "envs, one thread, one evaluation episode): eager, as the scripts run "
        "(`routine_gym.plumbing.eager_optim`), against torch's own path "
        f"(`{SWITCH}=0`), back to back.", "", *rows, ""])
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    children_die_with_me()
    main()
