"""Benchmark: what `--interrupt` costs `algos/rapl_a2c.py --mode rapl`, and that off costs nothing.

Three configurations, each run as its own subprocess, interleaved over `--repeats` rounds (so a
change in the machine's load falls on all of them alike):

- ``before``: the code before interruption existed (`--before`, a checkout of the parent
  commit; `PYTHONPATH` set to it), `--mode rapl`;
- ``off``: this checkout, `--mode rapl` (no `--interrupt`: routines run to their end);
- ``on``: this checkout, `--mode rapl --interrupt MARGIN`: before each inner step of a routine
  the env asks the policy (one batched forward pass over the envs still inside one).

Each runs `python algos/rapl_a2c.py --env-id ENV --mode rapl --num-envs 16 --total-timesteps
STEPS --eval-episodes 0 --checkpoint-every 0 --torch-threads 1 --seed 1` with its demo; the
figure is the script's own last `SPS` (primitive agent steps per second since the start of
training: env creation and mining are outside it) and the wall time of the whole process.
The load averages are taken before each run. Then the vector env's step alone (`ENV_STEP`),
`before` against `off` over `--env-step-rounds` rounds, the one place where `off` adds work.
Results: `bench/results/interrupt.md`.

    python bench/bench_interrupt.py --before /work/frozen3
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import base_machine_info, children_die_with_me, timed_training_run

REPO = Path(__file__).resolve().parent.parent


def run_one(code: Path, env_id: str, demo: Path, steps: int, interrupt: float | None,
            run_dir: str) -> dict:
    """One training run of `code`'s rapl_a2c.py: its last SPS, wall time, and for `on` the
    routine use and recent return of its last progress line (read from its stdout)."""
    command = [sys.executable, str(code / "algos" / "rapl_a2c.py"), "--env-id", env_id,
               "--mode", "rapl", "--demo", str(demo), "--num-envs", "16",
               "--total-timesteps", str(steps), "--eval-episodes", "0",
               "--checkpoint-every", "0", "--torch-threads", "1", "--seed", "1",
               "--run-dir", run_dir]
    if interrupt is not None:
        command += ["--interrupt", str(interrupt)]
    return {**timed_training_run(command, code, run_dir), "command": " ".join(command[1:])}


#: The vector env's step alone (the one place `off` adds work: a test of `_stop_rule`), timed
#: in a subprocess of each checkout: 16 Breakout games, routines of the shipped demo's length,
#: random actions drawn before timing; microseconds per step, the best of 5 blocks.
ENV_STEP = """
import time, numpy as np, routine_gym
routine_gym.register_envs()
from routine_gym.envs.minatar_vector import MinAtarVectorEnv
envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 16, routines=[[0, 0, 0, 0], [0, 0, 2],
                        [0] * 6], record_observations=True)
envs.reset(seed=1)
actions = np.random.default_rng(0).integers(0, 6, (5, 4000, 16))
best = float("inf")
for block in actions:
    start = time.perf_counter()
    for a in block:
        envs.step(a)
    best = min(best, (time.perf_counter() - start) / len(block))
print(f"{best * 1e6:.2f}")
"""


def env_step_us(code: Path) -> float:
    """`ENV_STEP` in a subprocess with `code` on PYTHONPATH: µs per vector step."""
    proc = subprocess.run([sys.executable, "-c", ENV_STEP], capture_output=True, text=True,
                          env={"PYTHONPATH": str(code), "PATH": "/usr/bin:/bin"}, check=True)
    return float(proc.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True,
                        help="a checkout of the code before interruption (e.g. /work/frozen3)")
    parser.add_argument("--env-id", default="MinAtar/Breakout-v1")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--margin", type=float, default=1.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--env-step-rounds", type=int, default=3,
                        help="interleaved rounds of the vector env's step alone (0: none)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "interrupt.md")
    args = parser.parse_args()
    if args.steps < 1:
        parser.error(f"--steps must be at least 1, not {args.steps}")
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, not {args.repeats}")
    if args.env_step_rounds < 0:
        parser.error(f"--env-step-rounds must be at least 0, not {args.env_step_rounds}")
    if args.margin < 0:
        parser.error(f"--margin must be at least 0 (nats), not {args.margin:g}")
    if not (args.before / "algos" / "rapl_a2c.py").is_file():
        parser.error(f"--before {args.before} is not a routine-gym checkout "
                     "(it has no algos/rapl_a2c.py)")
    demo = REPO / "demos" / f"{args.env_id.replace('/', '-')}.npz"
    if not demo.is_file():
        parser.error(f"--env-id {args.env_id} has no demo {demo}")
    configs = {"before": (args.before, None), "off": (REPO, None), "on": (REPO, args.margin)}
    results: dict[str, list[dict]] = {name: [] for name in configs}
    with tempfile.TemporaryDirectory() as run_dir:
        for round_ in range(args.repeats):
            for name, (code, margin) in configs.items():
                result = run_one(code, args.env_id, demo, args.steps, margin, run_dir)
                results[name].append(result)
                print(f"round {round_ + 1} {name:>6s}: SPS {result['sps']:>6d}  wall "
                      f"{result['wall']:6.1f} s  load {result['load']}", flush=True)
    lines = [f"# `--interrupt` speed: rapl_a2c.py --mode rapl on {args.env_id}", "",
             f"`python bench/bench_interrupt.py --before {args.before} --steps {args.steps} "
             f"--env-id {args.env_id} --margin {args.margin} --repeats {args.repeats} "
             f"--env-step-rounds {args.env_step_rounds} --out {args.out}`", "",
             "Each configuration's command (run from a temporary folder; `before` with "
             f"PYTHONPATH={args.before}, the others with this checkout):", ""]
    for name in configs:
        lines.append(f"- `{name}`: `python {results[name][0]['command']}`")
    lines += ["", "| config | SPS per run | best SPS | wall per run (s) | routine use | "
              "return (last 20) | load averages before each run |", "|---|---|---|---|---|---|---|"]
    for name, runs in results.items():
        lines.append(f"| {name} | {', '.join(str(r['sps']) for r in runs)} | "
                     f"{max(r['sps'] for r in runs)} | "
                     f"{', '.join(format(r['wall'], '.1f') for r in runs)} | "
                     f"{', '.join(r['routine_use'] for r in runs)} | "
                     f"{', '.join(r['return'] for r in runs)} | "
                     f"{'; '.join(r['load'] for r in runs)} |")
    best = {name: max(r["sps"] for r in runs) for name, runs in results.items()}
    mean = {name: statistics.mean(r["sps"] for r in runs) for name, runs in results.items()}
    median = {name: statistics.median(r["sps"] for r in runs) for name, runs in results.items()}
    lines += ["", f"off / before: {best['off'] / best['before']:.3f} (best runs), "
              f"{mean['off'] / mean['before']:.3f} (means), "
              f"{median['off'] / median['before']:.3f} (medians); on / off: "
              f"{best['on'] / best['off']:.3f} (best), {mean['on'] / mean['off']:.3f} (means).",
              "",
              "Machine: " + "; ".join(f"{k}: {v}" for k, v in base_machine_info().items()), ""]
    steps_us: dict[str, list[float]] = {"before": [], "off": []}
    for _ in range(args.env_step_rounds):
        for name in steps_us:
            steps_us[name].append(env_step_us(configs[name][0]))
    if args.env_step_rounds:
        lines += ["The vector env's step alone (`ENV_STEP` in this file: 16 Breakout games with "
                  "routines, record_observations, no stop rule), µs per step, best of 5 blocks "
                  f"of 4,000, {args.env_step_rounds} interleaved rounds:", ""]
        for name, times in steps_us.items():
            lines.append(f"- `{name}`: {', '.join(f'{t:.2f}' for t in times)} (best "
                         f"{min(times):.2f})")
        lines.append("")
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    children_die_with_me()
    main()
