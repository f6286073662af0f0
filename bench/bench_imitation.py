"""Benchmark: the paper's imitation table (SPEC §6.1) — BC, GAIL, SQIL and RAPL-SQIL.

For every env, method and seed this runs the method's script in its own subprocess,

    BC         python algos/bc.py        --gradient-steps BC_STEPS
    GAIL       python algos/gail.py      --total-timesteps GAIL_STEPS
    SQIL       python algos/rapl_sqil.py --total-timesteps SQIL_STEPS --num-routines 0
    RAPL-SQIL  python algos/rapl_sqil.py --total-timesteps SQIL_STEPS --num-routines 3

each with `--seed S --eval-episodes N --run-dir TMP/...`, and reads back its `eval.json`: the
mean over N evaluation episodes of the alignment score of the policy's primitive actions with
the demo's, of the return and (Atari) of the human-normalised score. The table gives, per
method, the mean ± sample standard deviation over seeds of those per-seed means, every seed's
alignment, and the paper's numbers (Atari, so only a reference for MiniQbert). With
`--temperatures 1.0 0.1`, SQIL and RAPL-SQIL also run at the other soft-Q temperatures α.

The MiniQbert part uses the shipped demo (the scripted expert, 39 actions, score 1050). The
Atari part (`--atari-steps N > 0`) uses `demos/ALE-Qbert-v5.npz`, or `--atari-demo PATH`, or
else a random-policy demo recorded first (as `bench_a2c_speed.py` does).

Usage:
    python bench/bench_imitation.py                                  # MiniQbert, 3 seeds
    python bench/bench_imitation.py --temperatures 1.0 0.1 --jobs 2
    python bench/bench_imitation.py --steps 0 --atari-steps 20000    # Atari only
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_a2c_speed import (  # noqa: E402  (a sibling script, not a package)
    REPO,
    load_average,
    machine_info,
    other_processes,
    qbert_demo,
)

#: method -> (script, extra arguments)
METHODS: dict[str, tuple[str, list[str]]] = {
    "BC": ("bc", []),
    "GAIL": ("gail", []),
    "SQIL": ("rapl_sqil", ["--num-routines", "0"]),
    "RAPL-SQIL": ("rapl_sqil", ["--num-routines", "3"]),
}
#: The paper's Table (Atari): alignment and human-normalised score.
PAPER = {"BC": (0.18, 0.183), "GAIL": (0.16, 0.264), "SQIL": (0.28, 0.294),
         "RAPL-SQIL": (0.34, 0.361)}


def mean_std(values: list[float], fmt: str = ".3f") -> str:
    """`mean ± sample std` (just the mean for one value)."""
    if not values:
        return "n/a"
    if len(values) == 1:
        return f"{values[0]:{fmt}}"
    return f"{np.mean(values):{fmt}} ± {np.std(values, ddof=1):{fmt}}"


def run_one(env_id: str, label: str, method: str, temperature: float, seed: int,
            budget: dict, demo: str | None, root: Path) -> dict:
    """One script run in a subprocess; its eval.json summary plus the command and wall time."""
    script, extra = METHODS[method]
    steps = budget[{"bc": "bc_steps", "gail": "gail_steps"}.get(script, "sqil_steps")]
    run_dir = root / env_id.replace("/", "-") / label.replace(" ", "_") / f"seed{seed}"
    cmd = [sys.executable, str(REPO / "algos" / f"{script}.py"), "--env-id", env_id,
           "--seed", str(seed), "--gradient-steps" if script == "bc" else "--total-timesteps",
           str(steps),
           "--eval-episodes", str(budget["eval_episodes"]), "--run-dir", str(run_dir), *extra]
    if budget.get("eval_max_steps"):
        cmd += ["--eval-max-steps", str(budget["eval_max_steps"])]
    if script == "rapl_sqil":
        cmd += ["--temperature", str(temperature)]
    if demo:
        cmd += ["--demo", demo]
    record = {"env_id": env_id, "label": label, "method": method, "seed": seed,
              "steps": steps, "command": shlex.join(cmd), "load_before": load_average()}
    start = time.time()
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    record["wall_s"] = time.time() - start
    found = list(run_dir.glob("*/eval.json"))
    if proc.returncode != 0 or len(found) != 1:
        tail = (proc.stderr.strip() or proc.stdout.strip()).splitlines()[-1:] or ["?"]
        record["error"] = f"exit {proc.returncode}: {tail[0]}"
        return record
    summary = json.loads(found[0].read_text())
    record.update(alignment=summary["mean_alignment"], score=summary["mean_return"],
                  hns=summary.get("human_normalized_score"),
                  episode_length=float(np.mean(summary["lengths"])),
                  demo_score=summary["demo_score"], demo_length=summary["demo_length"])
    return record


def render_env(env_id: str, records: list[dict], budget: dict, demo_note: str) -> list[str]:
    atari = env_id.startswith("ALE/")
    ok = [r for r in records if "error" not in r]
    demo = f"score {ok[0]['demo_score']:g}, {ok[0]['demo_length']} actions" if ok else "?"
    lines = [f"## {env_id}", "",
             f"Demo: {demo_note} ({demo}). Budgets: BC {budget['bc_steps']:,} gradient steps, "
             f"GAIL {budget['gail_steps']:,} env steps, SQIL/RAPL-SQIL {budget['sqil_steps']:,} "
             f"env steps; {budget['eval_episodes']} evaluation episodes per run"
             + (f" (at most {budget['eval_max_steps']:,} steps each)"
                if budget.get("eval_max_steps") else "") + ".", ""]
    header = "| Method | Alignment | Score | Episode length |"
    rule = "|---|---|---|---|"
    if atari:
        header += " Human-normalised |"
        rule += "---|"
    header += " Paper (Atari): alignment / HN score | Alignment per seed | Wall per run |"
    rule += "---|---|---|"
    lines += [header, rule]
    for label in dict.fromkeys(r["label"] for r in records):
        rows = [r for r in records if r["label"] == label]
        good = [r for r in rows if "error" not in r]
        method = rows[0]["method"]
        cells = [label, mean_std([r["alignment"] for r in good]),
                 mean_std([r["score"] for r in good], ".1f"),
                 mean_std([r["episode_length"] for r in good], ".0f")]
        if atari:
            hns = [r["hns"] for r in good if r["hns"] is not None]
            cells.append(mean_std([100 * h for h in hns], ".1f") + " %" if hns else "n/a")
        paper = PAPER.get(method)
        cells.append(f"{paper[0]:.2f} / {100 * paper[1]:.1f} %" if label == method and paper
                     else "")
        cells.append(", ".join(f"{r['alignment']:.3f}" if "error" not in r else "FAILED"
                               for r in rows))
        cells.append(f"{np.mean([r['wall_s'] for r in rows]):.0f} s")
        lines.append("| " + " | ".join(cells) + " |")
    failed = [r for r in records if "error" in r]
    lines += [""] + [f"- FAILED {r['label']} seed {r['seed']}: {r['error']}" for r in failed]
    lines += ["Command of each method's first run:", ""]
    for label in dict.fromkeys(r["label"] for r in records):
        first = next(r for r in records if r["label"] == label)
        shown = first["command"].replace(sys.executable, "python").replace(f"{REPO}/", "")
        lines.append(f"- {label}: `{shown}`")
    return lines + [""]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="MiniQbert-v0", help="the small env")
    parser.add_argument("--steps", type=int, default=20_000,
                        help="SQIL/RAPL-SQIL env steps on --env-id (0 skips the env)")
    parser.add_argument("--gail-steps", type=int, default=50_000)
    parser.add_argument("--bc-steps", type=int, default=2_000, help="BC gradient steps")
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--atari-env-id", default="ALE/Qbert-v5")
    parser.add_argument("--atari-steps", type=int, default=0,
                        help="SQIL/RAPL-SQIL env steps on the Atari env (0, the default, skips it)")
    parser.add_argument("--atari-gail-steps", type=int, default=50_000)
    parser.add_argument("--atari-bc-steps", type=int, default=2_000)
    parser.add_argument("--atari-eval-episodes", type=int, default=10)
    parser.add_argument("--atari-eval-max-steps", type=int, default=5_000,
                        help="cap on the primitive steps of an Atari evaluation episode")
    parser.add_argument("--atari-demo", default=None,
                        help="the Atari demo (default: demos/ALE-Qbert-v5.npz, else a "
                             "random-policy demo recorded first)")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--temperatures", nargs="+", type=float, default=[1.0],
                        help="soft-Q temperatures α of SQIL and RAPL-SQIL (the first is the "
                             "main row)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="keep the runs here (default: a temporary folder, deleted)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "imitation.md",
                        help="markdown report; the raw numbers go beside it as .json")
    args = parser.parse_args(argv)
    for name in ("steps", "atari_steps"):  # 0 skips the env
        if getattr(args, name) < 0:
            parser.error(f"--{name.replace('_', '-')} needs to be ≥ 0, "
                         f"actual value: {getattr(args, name)}")
    # The scripts take no run of 0 steps: every BC or GAIL run would fail.
    for name in ("gail_steps", "bc_steps", "atari_gail_steps", "atari_bc_steps",
                 "eval_episodes", "atari_eval_episodes", "jobs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} needs to be ≥ 1, "
                         f"actual value: {getattr(args, name)}")
    if any(t <= 0 for t in args.temperatures):
        parser.error(f"--temperatures need to be > 0, actual value: {args.temperatures}")
    if args.steps == 0 and args.atari_steps == 0:
        parser.error("nothing to run: --steps and --atari-steps are both 0")
    if len(set(args.seeds)) < len(args.seeds):
        parser.error(f"--seeds names a seed twice: {' '.join(map(str, args.seeds))}")
    # A run reads back the one eval.json of its folder: an earlier run's would make it fail.
    if args.run_dir is not None and next(args.run_dir.glob("**/eval.json"), None):
        parser.error(f"--run-dir {args.run_dir} already holds runs (eval.json): "
                     "give an empty or new folder")

    from routine_gym.atomic import atomic_write_text

    command = "python " + shlex.join([os.path.relpath(__file__, REPO), *sys.argv[1:]])
    info = machine_info()
    info["busiest processes at start"] = other_processes()
    print(f"# {command}\n# load average at start: {load_average()}", flush=True)

    labels = []
    for method in args.methods:
        if METHODS[method][0] != "rapl_sqil":
            labels.append((method, method, args.temperatures[0]))
            continue
        for i, t in enumerate(args.temperatures):
            labels.append((method if i == 0 else f"{method} (α={t:g})", method, t))

    start = time.time()
    with tempfile.TemporaryDirectory(prefix="bench_imitation_") as tmp:
        root = args.run_dir or Path(tmp)
        envs = []
        if args.steps > 0:
            envs.append((args.env_id, None, "the shipped demo", {
                "sqil_steps": args.steps, "gail_steps": args.gail_steps,
                "bc_steps": args.bc_steps, "eval_episodes": args.eval_episodes}))
        if args.atari_steps > 0:
            demo, note = qbert_demo(args.atari_env_id, args.atari_demo, Path(tmp))
            envs.append((args.atari_env_id, demo, note, {
                "sqil_steps": args.atari_steps, "gail_steps": args.atari_gail_steps,
                "bc_steps": args.atari_bc_steps, "eval_episodes": args.atari_eval_episodes,
                "eval_max_steps": args.atari_eval_max_steps}))
        plan = [(env_id, label, method, t, seed, budget, demo)
                for env_id, demo, _, budget in envs for label, method, t in labels
                for seed in args.seeds]

        def job(item):
            env_id, label, method, t, seed, budget, demo = item
            record = run_one(env_id, label, method, t, seed, budget, demo, root)
            status = (f"FAILED {record['error']}" if "error" in record else
                      f"alignment {record['alignment']:.3f}, score {record['score']:.1f}")
            print(f"{env_id} {label} seed {seed}: {status} ({record['wall_s']:.0f} s, "
                  f"load {record['load_before']})", flush=True)
            return record

        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            records = list(pool.map(job, plan))
    wall = time.time() - start

    info["load average at end"] = load_average()
    info["busiest processes at end"] = other_processes()
    lines = [
        "# Imitation from one demonstration: BC, GAIL, SQIL, RAPL-SQIL",
        "",
        "Produced by `bench/bench_imitation.py`. Alignment: `1 − Levenshtein(ι_d, ι_t)/|ι_d|` "
        "of each evaluation episode's primitive action trajectory (routines expanded) with the "
        "demo's; score: the episode's return. Each cell is the mean ± sample standard "
        "deviation over seeds of the per-run means. The paper's column is its Atari table, "
        "for reference.",
        "",
    ]
    for env_id, _, note, budget in envs:
        lines += render_env(env_id, [r for r in records if r["env_id"] == env_id], budget, note)
    lines += ["## Setup", "", f"- Command: `{command}`",
              f"- Total wall time: {wall / 60:.1f} min with {args.jobs} runs at a time",
              "", "## Machine", ""] + [f"- {k}: {v}" for k, v in info.items()]
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, text)
    raw = {"command": command, "machine": info, "wall_s": wall, "runs": records}
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(raw, indent=2) + "\n")
    print(f"written to {args.out} and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
