"""Benchmark: how fast `algos/rapl_a2c.py` learns in its three modes (`a2c`, `rapl`, `macro`).

SPEC §5–6 target checked here: on `MiniQbert-v0`, RAPL-A2C reaches the expert's return (the
shipped demo's score, 1050) in fewer environment steps than plain A2C.

For every env, mode and seed this runs `python algos/rapl_a2c.py --env-id ENV --mode MODE
--seed S --total-timesteps N --eval-episodes 10 --run-dir TMP/...` in its own subprocess
(RAPL and MacroAction mine their routines from the env's shipped demo, or from `--atari-demo`)
and reads back:

- the final evaluation from the run's `eval.json` (mean return over `--eval-episodes` full
  episodes of the trained policy);
- the training curve from the run's TensorBoard scalar `charts/episodic_return` (one point per
  finished training episode, at the primitive step it finished): its rolling mean over
  `--window` consecutive episodes, the first environment step at which that mean reaches each
  `--fractions` × the expert's return ("not reached" if it never does; the window must be full),
  and its value at 25/50/75/100 % of the budget;
- the routine usage (`routines/usage_k`), policy entropy and SPS at the end of training.

Per mode the table gives mean ± sample standard deviation over seeds, and every seed's value.
The Atari part (`--atari-env-id`, default `ALE/Qbert-v5`) runs only with `--atari-steps N`
> 0; its routines come from `demos/ALE-Qbert-v5.npz` when it exists, else from a random-policy
demo recorded first (as in `bench_a2c_speed.py`). Runs go to a temporary folder unless
`--run-dir` is given (then they are kept). The raw numbers go beside the report as JSON;
`--from-json` writes one report from several such files (e.g. a MiniQbert and a later Atari
invocation) without running anything.

Usage:
    python bench/bench_learning.py                                # MiniQbert, 200k steps, 3 seeds
    python bench/bench_learning.py --steps 300000 --seeds 1 2 3 4 5
    python bench/bench_learning.py --steps 0 --atari-steps 100000  # Atari only
    python bench/bench_learning.py --script-args "--learning-rate 1e-3"
    python bench/bench_learning.py --from-json mini.json atari.json --out bench/results/learning.md
"""

from __future__ import annotations

import argparse
import json
import math
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
    SCRIPT,
    load_average,
    machine_info,
    other_processes,
    qbert_demo,
)

MODES = ("a2c", "rapl", "macro")
CURVE_POINTS = (0.25, 0.5, 0.75, 1.0)
DEFAULT_WINDOW = 100
ATARI_WINDOW = 20


def expert_return(env_id: str) -> float | None:
    """The score of the env's shipped demo (the expert the routines come from), if any."""
    from routine_gym.demo import Demo, shipped_demo_path

    path = shipped_demo_path(env_id)
    return float(Demo.load(path, env_id=env_id).score) if path else None


def read_scalars(run_path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every TensorBoard scalar of a run as (steps, values), all points kept, in logged order."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_path), size_guidance={"scalars": 0})
    acc.Reload()
    out = {}
    for tag in acc.Tags()["scalars"]:
        events = acc.Scalars(tag)
        out[tag] = (np.array([e.step for e in events], dtype=np.int64),
                    np.array([e.value for e in events], dtype=np.float64))
    return out


def rolling_mean(values: np.ndarray, window: int) -> np.ndarray:
    """`out[i]` = mean of `values[i - window + 1 : i + 1]`, defined from `i = window - 1` on."""
    if len(values) < window:
        return np.zeros(0)
    csum = np.concatenate([[0.0], np.cumsum(values)])
    return (csum[window:] - csum[:-window]) / window


def first_step_reaching(steps: np.ndarray, values: np.ndarray, window: int,
                        threshold: float) -> int | None:
    """First step at which the full-window rolling mean of `values` is ≥ `threshold`."""
    means = rolling_mean(values, window)
    hits = np.flatnonzero(means >= threshold)
    return int(steps[hits[0] + window - 1]) if len(hits) else None


def curve_summary(steps: np.ndarray, values: np.ndarray, window: int, budget: int,
                  points: int = 50) -> dict:
    """The rolling mean at the `CURVE_POINTS` fractions of the budget, and a thinned curve."""
    means = rolling_mean(values, window)
    mean_steps = steps[window - 1:] if len(means) else np.zeros(0, dtype=np.int64)

    def at(step: float) -> float | None:
        idx = np.searchsorted(mean_steps, step, side="right") - 1
        return float(means[idx]) if idx >= 0 else None

    marks = {f"{int(f * 100)}%": at(f * budget) for f in CURVE_POINTS}
    grid = np.linspace(0, budget, points + 1)[1:]
    return {"at_budget_fraction": marks,
            "curve": [[int(s), at(s)] for s in grid],
            "max_rolling_mean": float(means.max()) if len(means) else None,
            "episodes": int(len(values))}


def find_run(run_dir: Path) -> Path:
    """The one run folder the script made under `run_dir`."""
    runs = [p for p in run_dir.iterdir() if p.is_dir()]
    if len(runs) != 1:
        raise RuntimeError(f"expected one run folder in {run_dir}, found {len(runs)}")
    return runs[0]


def window_of(env_id: str, args) -> int:
    """Episodes in the rolling mean: Atari runs finish far fewer episodes."""
    return args.window if env_id == args.env_id else args.atari_window


def run_one(env_id: str, mode: str, seed: int, steps: int, demo: str | None, root: Path,
            args) -> dict:
    """Train one configuration in a subprocess and collect its numbers."""
    run_dir = root / f"{env_id.replace('/', '-')}__{mode}__{seed}"
    run_dir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, str(SCRIPT), "--env-id", env_id, "--mode", mode, "--seed", str(seed),
           "--total-timesteps", str(steps), "--eval-episodes", str(args.eval_episodes),
           "--run-dir", str(run_dir), "--log-every", str(max(steps // 10, 1000))]
    if mode != "a2c" and demo:
        cmd += ["--demo", demo]
    cmd += shlex.split(args.script_args)
    record = {"env_id": env_id, "mode": mode, "seed": seed, "steps": steps,
              "command": shlex.join(cmd), "load_before": load_average()}
    start = time.perf_counter()
    log_path = run_dir / "stdout.log"
    with open(log_path, "w") as log:
        proc = subprocess.run(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    record["wall_s"] = time.perf_counter() - start
    record["returncode"] = proc.returncode
    if proc.returncode != 0:
        tail = log_path.read_text().strip().splitlines()[-3:]
        record["error"] = " / ".join(tail)
        return record
    run_path = find_run(run_dir)
    record["run_path"] = str(run_path)
    evaluation = json.loads((run_path / "eval.json").read_text())
    record["eval_mean"] = evaluation["mean_return"]
    record["eval_std"] = evaluation["std_return"]
    record["eval_returns"] = evaluation["returns"]
    record["eval_lengths"] = evaluation["lengths"]
    if "human_normalized_score" in evaluation:
        record["eval_hns"] = evaluation["human_normalized_score"]
    if (run_path / "routines.json").exists():
        library = json.loads((run_path / "routines.json").read_text())
        record["routines"] = library.get("routines")

    scalars = read_scalars(run_path)
    ret_steps, returns = scalars.get("charts/episodic_return", (np.zeros(0), np.zeros(0)))
    window = window_of(env_id, args)
    record["window"] = window
    record["curve"] = curve_summary(ret_steps, returns, window, steps)
    expert = args.expert.get(env_id)
    if expert is not None:
        record["steps_to"] = {
            f"{frac:g}": first_step_reaching(ret_steps, returns, window, frac * expert)
            for frac in args.fractions
        }
    final = {}
    for tag in ("losses/entropy", "charts/SPS", "routines/primitive_usage",
                *sorted(t for t in scalars if t.startswith("routines/usage_"))):
        if tag in scalars and len(scalars[tag][1]):
            final[tag] = float(scalars[tag][1][-1])
    record["final"] = final
    return record


# ---------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------


def mean_std(values: list[float]) -> str:
    """`mean ± sample std` (just the value for one seed)."""
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.1f}"
    return f"{np.mean(values):.1f} ± {np.std(values, ddof=1):.1f}"


def fmt_steps(step: int | None) -> str:
    return "not reached" if step is None else f"{step:,}"


def median_steps(steps: list[int | None]) -> float:
    """Median of steps-to-threshold with "not reached" counted as infinitely many."""
    return float(np.median([math.inf if s is None else s for s in steps]))


def render_env(env_id: str, records: list[dict], fractions: list[float],
               expert: float | None) -> list[str]:
    """The tables of one env."""
    budget = records[0]["steps"]
    seeds = sorted({r["seed"] for r in records})
    # Runs recorded before "window" was stored used the defaults (Atari: ATARI_WINDOW).
    window = records[0].get("window", DEFAULT_WINDOW if expert is not None else ATARI_WINDOW)
    lines = [f"## {env_id}: {budget:,} agent steps per run, seeds "
             f"{', '.join(str(s) for s in seeds)}", "",
             f"Rolling mean over {window} training episodes."
             + (f" Expert return (shipped demo): {expert:g}." if expert is not None else ""),
             ""]
    lines += ["| mode | eval return (mean ± std over seeds) | per seed | rolling train return "
              "at 25/50/75/100 % of budget (mean over seeds) | max rolling mean | routine use "
              "at end | entropy at end | SPS | wall s per run |",
              "|---|---|---|---|---|---|---|---|---|"]
    by_mode: dict[str, list[dict]] = {}
    for r in records:
        by_mode.setdefault(r["mode"], []).append(r)
    for mode, rs in by_mode.items():
        ok = [r for r in rs if "error" not in r]
        failed = [r for r in rs if "error" in r]
        if not ok:
            lines.append(f"| {mode} | failed: {failed[0]['error']} | | | | | | | |")
            continue
        evals = [r["eval_mean"] for r in ok]
        marks = []
        for key in ("25%", "50%", "75%", "100%"):
            vals = [r["curve"]["at_budget_fraction"][key] for r in ok]
            vals = [v for v in vals if v is not None]
            marks.append(f"{np.mean(vals):.0f}" if vals else "–")
        maxes = [r["curve"]["max_rolling_mean"] for r in ok
                 if r["curve"]["max_rolling_mean"] is not None]
        usage = [1.0 - r["final"]["routines/primitive_usage"] for r in ok
                 if "routines/primitive_usage" in r["final"]]
        entropy = [r["final"].get("losses/entropy", math.nan) for r in ok]
        sps = [r["final"].get("charts/SPS", math.nan) for r in ok]
        lines.append(
            f"| {mode} | {mean_std(evals)} | {', '.join(f'{v:g}' for v in evals)} "
            f"| {' / '.join(marks)} | {mean_std(maxes)} "
            f"| {f'{np.mean(usage):.0%}' if usage else '–'} | {np.mean(entropy):.3f} "
            f"| {np.mean(sps):,.0f} | {np.mean([r['wall_s'] for r in ok]):.0f} |"
            + (f" ({len(failed)} failed)" if failed else "")
        )
    if expert is not None:
        lines += ["", f"Environment steps until the rolling mean first reaches a fraction of the "
                  f"expert's return ({expert:g}), per seed:", "",
                  "| mode | " + " | ".join(f"{f:g} × expert ({f * expert:g})"
                                          for f in fractions) + " |",
                  "|---|" + "---|" * len(fractions)]
        for mode, rs in by_mode.items():
            ok = [r for r in rs if "error" not in r]
            if not ok:
                continue
            cells = []
            for frac in fractions:
                per_seed = [r["steps_to"][f"{frac:g}"] for r in ok]
                reached = sum(s is not None for s in per_seed)
                cells.append(f"{', '.join(fmt_steps(s) for s in per_seed)} "
                             f"({reached}/{len(per_seed)})")
            lines.append(f"| {mode} | " + " | ".join(cells) + " |")
        if {"a2c", "rapl"} <= by_mode.keys():
            full = max(fractions)
            med = {m: median_steps([r["steps_to"][f"{full:g}"] for r in by_mode[m]
                                    if "error" not in r]) for m in ("a2c", "rapl")}
            if math.isinf(med["rapl"]) and math.isinf(med["a2c"]):
                verdict = "undecided: neither reaches it in most seeds within the budget"
            elif med["rapl"] < med["a2c"]:
                verdict = "met (median over seeds, not reached = ∞)"
            else:
                verdict = "not met (median over seeds, not reached = ∞)"
            lines += ["", f"Target (rapl reaches {full:g} × the expert's return in fewer steps "
                      f"than a2c): {verdict}."]
    routines = next((r.get("routines") for r in records if r.get("routines")), None)
    if routines:
        lines += ["", f"Routines (action ids): {routines}"]
    lines += ["", "Loads (1/5/15 min) before each run: "
              + "; ".join(f"{r['mode']} s{r['seed']}: {r['load_before']}" for r in records), ""]
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="MiniQbert-v0", help="the small env")
    parser.add_argument("--steps", type=int, default=200_000,
                        help="agent steps per run on --env-id (0 skips it)")
    parser.add_argument("--atari-env-id", default="ALE/Qbert-v5")
    parser.add_argument("--atari-steps", type=int, default=0,
                        help="agent steps per run on --atari-env-id (0, the default, skips it)")
    parser.add_argument("--atari-demo", default=None,
                        help="demo for the Atari routines (default: demos/ALE-Qbert-v5.npz, "
                             "else a random-policy demo recorded first)")
    parser.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--window", type=int, default=DEFAULT_WINDOW,
                        help="training episodes in the rolling mean of the curve")
    parser.add_argument("--atari-window", type=int, default=ATARI_WINDOW,
                        help="the same for the Atari runs")
    parser.add_argument("--fractions", nargs="+", type=float, default=[0.2, 0.5, 0.9, 1.0],
                        help="fractions of the expert's return to time (the largest is the "
                             "target's)")
    parser.add_argument("--expert-return", type=float, default=None,
                        help="expert return on --env-id (default: its shipped demo's score)")
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time")
    parser.add_argument("--script-args", default="",
                        help="extra arguments for every rapl_a2c.py run, e.g. \"--num-envs 8\"")
    parser.add_argument("--run-dir", type=Path, default=None,
                        help="keep the runs here (default: a temporary folder, deleted)")
    parser.add_argument("--from-json", nargs="+", type=Path, default=None,
                        help="run nothing: write the report of these raw-number files "
                             "(this script's .json outputs), merged, e.g. a MiniQbert and an "
                             "Atari invocation")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "learning.md",
                        help="markdown report; the raw numbers go beside it as .json")
    args = parser.parse_args(argv)
    for name in ("steps", "atari_steps"):
        if getattr(args, name) < 0:
            parser.error(f"--{name.replace('_', '-')} needs to be ≥ 0, "
                         f"actual value: {getattr(args, name)}")
    for name in ("eval_episodes", "window", "atari_window", "jobs"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} needs to be ≥ 1, "
                         f"actual value: {getattr(args, name)}")
    if any(not 0 < f for f in args.fractions):
        parser.error(f"--fractions need to be > 0, actual value: {args.fractions}")

    from routine_gym.plumbing.atomic import atomic_write_text

    if args.from_json:
        batches = []
        for path in args.from_json:
            data = json.loads(Path(path).read_text())
            batches += data["batches"] if "batches" in data else [data]
    else:
        if args.steps == 0 and args.atari_steps == 0:
            parser.error("nothing to run: --steps and --atari-steps are both 0")
        batches = [run_all(args)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, render(batches))
    atomic_write_text(args.out.with_suffix(".json"),
                      json.dumps({"batches": batches}, indent=2) + "\n")
    print(f"written to {args.out} and {args.out.with_suffix('.json')}")


def run_all(args) -> dict:
    """Every planned run; the raw numbers of this invocation (a "batch")."""
    import routine_gym

    routine_gym.register_envs()
    expert = args.expert_return if args.expert_return is not None else expert_return(args.env_id)
    experts = {args.env_id: expert} if expert is not None else {}
    args.expert = experts
    command = "python " + shlex.join([os.path.relpath(__file__, REPO), *sys.argv[1:]])
    info = machine_info()
    print(f"# {command}\n# load average at start: {load_average()}\n"
          f"# busiest processes: {other_processes()}", flush=True)
    info["busiest processes at start"] = other_processes()

    with tempfile.TemporaryDirectory(prefix="bench_learning_") as tmp:
        root = args.run_dir or Path(tmp)
        plan: list[tuple[str, str, int, int, str | None]] = []
        if args.steps > 0:
            plan += [(args.env_id, m, s, args.steps, None) for m in args.modes
                     for s in args.seeds]
        demo_note = None
        if args.atari_steps > 0:
            demo = None
            if any(m != "a2c" for m in args.modes):
                demo, demo_note = qbert_demo(args.atari_env_id, args.atari_demo, Path(tmp))
                print(f"# Atari demo: {demo} ({demo_note})", flush=True)
            plan += [(args.atari_env_id, m, s, args.atari_steps, demo) for m in args.modes
                     for s in args.seeds]

        def job(item):
            env_id, mode, seed, steps, demo = item
            record = run_one(env_id, mode, seed, steps, demo, root, args)
            status = (f"FAILED {record['error']}" if "error" in record else
                      f"eval {record['eval_mean']:.1f}, steps to target "
                      f"{record.get('steps_to')}, {record['wall_s']:.0f} s")
            print(f"{env_id} {mode} seed {seed} (load {record['load_before']}): {status}",
                  flush=True)
            return record

        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            records = list(pool.map(job, plan))

    info["load average at end"] = load_average()
    info["busiest processes at end"] = other_processes()
    return {"command": command, "machine": info, "fractions": args.fractions,
            "expert": experts, "eval_episodes": args.eval_episodes,
            "script_args": args.script_args, "demo": demo_note, "jobs": args.jobs,
            "runs": records}


def render(batches: list[dict]) -> str:
    """The markdown report of one or more batches of runs."""
    lines = [
        "# rapl_a2c.py learning benchmark: a2c vs rapl vs macro",
        "",
        "Produced by `bench/bench_learning.py` (commands, machine and loads below). Eval "
        "return: `eval.json` of each run (full episodes of the final policy, without the "
        "training-only wrappers); std is the sample standard deviation over seeds. Training "
        "curve: TensorBoard `charts/episodic_return` (true full-game returns, logged at the "
        "primitive step each episode ended).",
        "",
    ]
    for batch in batches:
        records = batch["runs"]
        for env_id in dict.fromkeys(r["env_id"] for r in records):
            lines += render_env(env_id, [r for r in records if r["env_id"] == env_id],
                                batch["fractions"], batch["expert"].get(env_id))
    for i, batch in enumerate(batches, 1):
        script_args = batch.get("script_args")
        lines += [f"## Setup{f' (batch {i})' if len(batches) > 1 else ''}", "",
                  f"- Command: `{batch['command']}`",
                  f"- Extra script arguments: `{script_args}`" if script_args else
                  "- Extra script arguments: none (the script's defaults)"]
        if batch.get("eval_episodes"):
            lines.append(f"- Evaluation episodes per run: {batch['eval_episodes']}")
        if batch.get("jobs"):
            lines.append(f"- Runs at a time: {batch['jobs']}")
        if batch.get("demo"):
            lines.append(f"- Atari routines mined from: {batch['demo']}")
        lines.append("- Command of the first run: `" + batch["runs"][0]["command"] + "`")
        lines += ["", "Machine:", ""] + [f"- {k}: {v}" for k, v in batch["machine"].items()]
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
