"""Benchmark: the speed of each issue-49 mechanism beside RAPL's, on both RAPL scripts.

For `algos/rapl_a2c.py` and `algos/rapl_ppo.py`, each configuration below is one training run
in its own subprocess, the configurations interleaved round by round over `--repeats` rounds (a
change in the machine's load falls on all of them alike):

- ``rapl``: `--mode rapl`, every mechanism off (the paper's method);
- ``intra``: `--intra-coef 1` (a policy term over the routines' inner states: more work per
  update, none per step);
- ``interrupt``: `--interrupt 1` (the policy asked before every inner step of a routine: work
  per step);
- ``first-action``: `--routine-logit first-action` (a routine's logit read from its first
  action's: a gather per forward pass);
- ``steps``: `--rollout-unit steps` (rollouts sized in primitive steps: more, smaller updates).

Every run: `--env-id ENV --demo DEMO --num-envs 16 --total-timesteps STEPS --eval-episodes 0
--checkpoint-every 0 --torch-threads 1 --seed 1`. The figure is the script's own last `SPS`
(primitive agent steps per second since training began: start-up and mining are outside it),
with the run's wall time and, as a check that the runs differ as training runs and not only in
speed, its routine use. Load averages are taken before each run. A mechanism changes what the
agent does (an interrupted routine is a shorter decision; more updates mean more passes), so
this is the cost of the whole method at equal steps, not of its rule alone.

    python bench/bench_mechanisms.py --steps 100000 --repeats 2

Results: `bench/results/mechanisms.md`.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

from common import base_machine_info, children_die_with_me, timed_training_run

REPO = Path(__file__).resolve().parent.parent
SCRIPTS = ("rapl_a2c", "rapl_ppo")
#: name → the flags that turn the mechanism on (``rapl``: none, the paper's method).
CONFIGS = {
    "rapl": [],
    "intra": ["--intra-coef", "1"],
    "interrupt": ["--interrupt", "1"],
    "first-action": ["--routine-logit", "first-action"],
    "steps": ["--rollout-unit", "steps"],
}


def run_one(script: str, flags: list[str], env_id: str, demo: Path, steps: int,
            run_dir: str) -> dict:
    """One training run: its last SPS, wall time and routine use (read from its stdout)."""
    command = [sys.executable, str(REPO / "algos" / f"{script}.py"), "--env-id", env_id,
               "--mode", "rapl", "--demo", str(demo), "--num-envs", "16",
               "--total-timesteps", str(steps), "--eval-episodes", "0",
               "--checkpoint-every", "0", "--torch-threads", "1", "--seed", "1",
               "--run-dir", run_dir, *flags]
    return {**timed_training_run(command, REPO, run_dir),
            "command": " ".join(["python", *command[1:]]).replace(run_dir, "TMP")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env-id", default="MinAtar/Breakout-v1")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--scripts", nargs="+", default=list(SCRIPTS), choices=SCRIPTS)
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS),
                        help="the configurations to run (rapl, the reference, always runs)")
    parser.add_argument("--out", type=Path,
                        default=REPO / "bench" / "results" / "mechanisms.md")
    args = parser.parse_args()
    if args.steps < 1 or args.repeats < 1:
        parser.error("--steps and --repeats must be at least 1")
    demo = REPO / "demos" / f"{args.env_id.replace('/', '-')}.npz"
    configs = ["rapl", *(c for c in args.configs if c != "rapl")]
    results = {(s, c): [] for s in args.scripts for c in configs}
    with tempfile.TemporaryDirectory() as run_dir:
        for round_ in range(args.repeats):
            for script, config in results:
                result = run_one(script, CONFIGS[config], args.env_id, demo, args.steps,
                                 run_dir)
                results[script, config].append(result)
                print(f"round {round_ + 1} {script} {config:>12s}: SPS {result['sps']:>6d}  "
                      f"wall {result['wall']:6.1f} s  load {result['load']}", flush=True)
    lines = [f"# The issue-49 mechanisms' speed beside RAPL's, on {args.env_id}", "",
             f"`python bench/bench_mechanisms.py --env-id {args.env_id} --steps {args.steps} "
             f"--repeats {args.repeats}`", "",
             "Each configuration's command (TMP: a temporary folder):", ""]
    for (script, config), runs in results.items():
        lines.append(f"- {script} `{config}`: `{runs[0]['command']}`")
    lines += ["", "| script | config | SPS per run | median SPS | ÷ rapl (medians) | "
              "wall per run (s) | routine use | load averages before each run |",
              "|---|---|---|---:|---:|---|---|---|"]
    for (script, config), runs in results.items():
        median = statistics.median(r["sps"] for r in runs)
        base = statistics.median(r["sps"] for r in results[script, "rapl"])
        lines.append(f"| {script} | {config} | {', '.join(str(r['sps']) for r in runs)} | "
                     f"{median:,.0f} | {median / base:.2f} | "
                     f"{', '.join(format(r['wall'], '.1f') for r in runs)} | "
                     f"{', '.join(r['routine_use'] for r in runs)} | "
                     f"{'; '.join(r['load'] for r in runs)} |")
    lines += ["", "Machine: " + "; ".join(f"{k}: {v}" for k, v in base_machine_info().items()),
              ""]
    args.out.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    children_die_with_me()
    main()
