"""Benchmark: do the paper's two option baselines learn? A2C, OptionCritic and CompILE on MinAtar.

For every game, method and seed this runs the method's script in its own subprocess,

    A2C            python algos/rapl_a2c.py      --mode a2c
    OptionCritic   python algos/option_critic.py
    CompILE        python algos/compile_a2c.py   (options from the game's shipped demo)

each with `--env-id G --seed S --total-timesteps N --eval-episodes E --checkpoint-every C
--torch-threads 1 --run-dir DIR/G/METHOD/seedS`, and reads back its `eval.json`. A run that
has its `eval.json` is skipped and one that has a checkpoint is resumed (`--resume`), so the
same command continues after a kill. The table gives the mean ± sample standard deviation over
seeds of the per-run mean evaluation return, every seed's, and the uniformly random policy's
score over the same number of episodes (`routine_gym.plumbing.evaluation.random_policy_scores`).

Usage:
    python bench/bench_baselines.py                                   # 2 games, 3 seeds, 1M steps
    python bench/bench_baselines.py --games Breakout --steps 100000 --seeds 1
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import base_machine_info, load_average  # noqa: E402

import routine_gym  # noqa: E402
from routine_gym.atomic import atomic_write_text  # noqa: E402
from routine_gym.plumbing.evaluation import random_policy_scores  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: method -> (script, extra arguments)
METHODS: dict[str, tuple[str, list[str]]] = {
    "A2C": ("rapl_a2c", ["--mode", "a2c"]),
    "OptionCritic": ("option_critic", []),
    "CompILE": ("compile_a2c", []),
}


def run_one(env_id: str, method: str, seed: int, args, root: Path) -> dict:
    """One run (skipped when done, resumed when killed); its eval.json and how it went."""
    script, extra = METHODS[method]
    run_dir = root / env_id.replace("/", "-") / method / f"seed{seed}"
    done = sorted(run_dir.glob("*/eval.json"))
    record = {"env_id": env_id, "method": method, "seed": seed}
    if done:
        return {**json.loads(done[-1].read_text()), **record, "skipped": True}
    if args.report_only:
        return {**record, "error": "not run yet (the sweep was stopped before it)"}
    checkpoints = sorted(run_dir.glob("*/checkpoint.pt"))
    if checkpoints:
        cmd = [sys.executable, str(REPO / "algos" / f"{script}.py"), "--resume",
               str(checkpoints[-1].parent)]
    else:
        cmd = [sys.executable, str(REPO / "algos" / f"{script}.py"), "--env-id", env_id,
               "--seed", str(seed), "--total-timesteps", str(args.steps),
               "--eval-episodes", str(args.eval_episodes), "--checkpoint-every",
               str(args.checkpoint_every), "--torch-threads", "1", "--log-every",
               str(max(args.steps // 10, 1)), "--run-dir", str(run_dir), *extra]
    start = time.time()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    record.update(command=shlex.join(cmd), seconds=time.time() - start)
    done = sorted(run_dir.glob("*/eval.json"))
    if proc.returncode != 0 or not done:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {**record, "error": last}
    return {**json.loads(done[-1].read_text()), **record}


def render(records: list[dict], randoms: dict[str, dict], args, command: str,
           info: dict[str, str]) -> str:
    lines = [
        "# Option baselines: A2C, OptionCritic and CompILE on MinAtar",
        "",
        f"Produced by `{command}` (`bench/bench_baselines.py`). Each run trains for "
        f"{args.steps:,} agent steps with the A2C settings of `rapl_a2c.py` (16 envs × 5 steps, "
        f"RMSprop 7e-4) and is evaluated on {args.eval_episodes} full episodes; a cell is the "
        "mean ± sample standard deviation over seeds of the per-run mean return. The random "
        f"policy's score is over {args.eval_episodes} episodes.",
        "",
        "| game | method | eval return | per seed | random policy | wall per run |",
        "|---|---|---|---|---|---|",
    ]
    for env_id in args.env_ids:
        for method in args.methods:
            rows = [r for r in records if r["env_id"] == env_id and r["method"] == method]
            good = [r for r in rows if "error" not in r]
            returns = [r["mean_return"] for r in good]
            cell = (f"{np.mean(returns):.2f} ± {np.std(returns, ddof=1):.2f}"
                    if len(returns) > 1 else f"{returns[0]:.2f}" if returns else "not run")
            if 0 < len(returns) < len(rows):
                cell += f" ({len(returns)} of {len(rows)} seeds)"
            seeds = ", ".join(f"{r['mean_return']:.2f}" if "error" not in r else "–"
                              for r in rows)
            walls = [r["seconds"] for r in good if "seconds" in r]
            wall = f"{np.mean(walls):.0f} s" if walls else "–"
            random = randoms[env_id]
            lines.append(f"| `{env_id}` | {method} | {cell} | {seeds} | "
                         f"{random['mean']:.2f} ± {random['std']:.2f} | {wall} |")
    failures = [r for r in records if "error" in r]
    if failures:
        lines += ["", "Runs without a result:", ""]
        lines += [f"- {r['env_id']} {r['method']} seed {r['seed']}: {r['error']}"
                  for r in failures]
    lines += ["", "## Machine", ""] + [f"- {k}: {v}" for k, v in info.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--games", nargs="+", default=["Breakout", "SpaceInvaders"])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--eval-episodes", type=int, default=30)
    parser.add_argument("--checkpoint-every", type=int, default=100_000)
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time")
    parser.add_argument("--report-only", action="store_true",
                        help="run nothing: report the runs that have finished")
    parser.add_argument("--run-dir", type=Path, default=Path("runs/bench_baselines"))
    parser.add_argument("--out", type=Path,
                        default=REPO / "bench" / "results" / "baselines_minatar.md")
    args = parser.parse_args(argv)
    for name in ("steps", "eval_episodes", "jobs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, "
                         f"not {getattr(args, name)}")
    if args.checkpoint_every < 0:
        parser.error(f"--checkpoint-every must be at least 0, not {args.checkpoint_every}")
    if len(set(args.seeds)) < len(args.seeds):
        parser.error(f"--seeds names a seed twice: {' '.join(map(str, args.seeds))}")
    args.env_ids = [f"MinAtar/{g}-v1" for g in args.games]
    routine_gym.register_envs()
    import gymnasium

    known = sorted(e[len("MinAtar/"):-len("-v1")] for e in gymnasium.registry
                   if e.startswith("MinAtar/") and e.endswith("-v1"))
    unknown = [g for g in args.games if g not in known]
    if unknown:
        parser.error(f"--games {' '.join(unknown)}: no such MinAtar game "
                     f"(choose from {', '.join(known)})")
    command = "python bench/bench_baselines.py " + shlex.join(sys.argv[1:] if argv is None
                                                               else argv)
    print(f"# {command}\n# load average at start: {load_average()}", flush=True)
    jobs = [(e, m, s) for e in args.env_ids for m in args.methods for s in args.seeds]
    records: list[dict] = []
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for record in pool.map(lambda job: run_one(*job, args, args.run_dir.resolve()), jobs):
            records.append(record)
            status = record.get("error") or f"eval return {record['mean_return']:.2f}"
            print(f"{record['env_id']} {record['method']} seed {record['seed']}: {status}",
                  flush=True)
    randoms = {e: random_policy_scores(e, args.eval_episodes, 0) for e in args.env_ids}
    info = {**base_machine_info(), "load_average_at_end": load_average()}
    atomic_write_text(args.out, render(records, randoms, args, command, info))
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(
        {"records": records, "random": randoms, "machine": info}, indent=2))
    print(f"written to {args.out}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
