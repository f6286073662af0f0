"""Benchmark: agent steps per second of `algos/rapl_ppo.py` against `algos/rapl_a2c.py`.

The acceptance of issue 29: on `MinAtar/Breakout-v1`, `rapl_ppo.py` makes at least as many
primitive agent steps per second as `rapl_a2c.py`, measured in the same run. Both modes are
compared: plain (`--mode ppo` against `--mode a2c`) and with routines (`--mode rapl` of each).
Each script runs with its own defaults for the env (`rapl_a2c.py`: 16 envs × 5 steps, one
RMSprop step per rollout; `rapl_ppo.py`'s MinAtar defaults: 64 envs × 128 steps, 4 epochs of 8
minibatches of Adam) and `--eval-episodes 0`, at each `--torch-threads` setting (default: 0,
torch's own choice, which is both scripts' default, then 1, which the experiments' sweeps use),
each configuration in its own subprocess, the two scripts of a pair one after the other, the
pair's order alternating from one repeat to the next so that a drift in the machine's load
favours neither.

The time is taken in this process from the arrival of the script's progress line at the first
step ≥ `--warmup` to that of its last line (`--log-every 1000`: rapl_ppo prints one per rollout,
rapl_a2c one per 1,000 steps), so env creation, routine mining and the first updates are
outside it; SPS = steps between the two lines / seconds between them. The CPU time of the
process over the same steps (/proc) is reported beside it: a shared machine disturbs it less
than wall time. RAPL mines its routines from `demos/MinAtar-Breakout-v1.npz`.

`--explain` adds rapl_ppo with `--update-epochs 1` against the same rapl_a2c runs: PPO's
default makes 4 gradient passes over every decision (A2C one), which is where its time goes on
MinAtar's small network; one epoch shows what the rest of the script costs. It also adds
RAPL-PPO with `--prim-epochs 4`, the script before 2026-12-05, which trained every state
inside a routine in all 4 epochs too (the default trains each once a rollout, as RAPL-A2C).

Usage:
    python bench/bench_ppo_speed.py                                   # 2 repeats, ~5 minutes
    python bench/bench_ppo_speed.py --warmup 20000 --steps 100000 --repeats 1 --explain
    python bench/bench_ppo_speed.py --torch-threads 1                 # one setting only

At the default threads PPO's large minibatches (1,024 states) use the second core, and A2C's
(80 states) hardly do; at one thread each, PPO's four passes over every sample cost more than
A2C's one.
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from bench_a2c_speed import other_processes, stream_progress
from common import base_machine_info, git_head, load_average, memory, tuning_env_vars

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = {"a2c": REPO / "algos" / "rapl_a2c.py", "ppo": REPO / "algos" / "rapl_ppo.py"}
#: The configurations: (script, mode, extra flags), and the pairs compared (A2C's first). The
#: `-e1` and `-p4` pairs are for explanation, not acceptance: rapl_ppo with one epoch per
#: rollout, so that each sample gets one gradient pass as in A2C (PPO's default is 4), and
#: RAPL-PPO training the states inside routines in every epoch (`--prim-epochs 4`).
CONFIGS = {"a2c": ("a2c", "a2c", ()), "ppo": ("ppo", "ppo", ()),
           "rapl-a2c": ("a2c", "rapl", ()), "rapl-ppo": ("ppo", "rapl", ()),
           "ppo-e1": ("ppo", "ppo", ("--update-epochs", "1")),
           "rapl-ppo-e1": ("ppo", "rapl", ("--update-epochs", "1")),
           "rapl-ppo-p4": ("ppo", "rapl", ("--prim-epochs", "4"))}
PAIRS = (("a2c", "ppo"), ("rapl-a2c", "rapl-ppo"))
EXPLAIN_PAIRS = (("a2c", "ppo-e1"), ("rapl-a2c", "rapl-ppo-e1"), ("rapl-a2c", "rapl-ppo-p4"))
#: What each explanation pair's rapl_ppo differs by.
EXPLAINED = {"ppo-e1": "one epoch", "rapl-ppo-e1": "one epoch",
             "rapl-ppo-p4": "inner states in every epoch, as before 2026-12-05"}


@dataclass
class Result:
    """One configuration's measurement."""

    config: str
    repeat: int
    threads: int
    command: str
    load_before: str
    start_step: int = 0
    end_step: int = 0
    seconds: float | None = None
    sps: float | None = None
    cpu_seconds: float | None = None
    routine_use: float | None = None
    error: str = ""

    @property
    def cpu_sps(self) -> float | None:
        if not self.cpu_seconds:
            return None
        return (self.end_step - self.start_step) / self.cpu_seconds


def run_config(name: str, args, run_dir: Path, repeat: int, threads: int) -> Result:
    """Run one script in a subprocess at `--torch-threads threads` and time its progress
    lines as they arrive."""
    script, mode, extra = CONFIGS[name]
    cmd = [sys.executable, str(SCRIPTS[script]), "--env-id", args.env_id, "--mode", mode,
           "--total-timesteps", str(args.warmup + args.steps), "--eval-episodes", "0",
           "--log-every", "1000", "--torch-threads", str(threads), "--run-dir", str(run_dir),
           "--seed", "1", *extra]
    if mode == "rapl":
        cmd += ["--demo", args.demo]
    result = Result(name, repeat, threads, shlex.join(cmd), load_average())
    stamps, _, returncode, stderr = stream_progress(cmd, args.warmup, args.warmup + args.steps)
    stderr = stderr.strip()
    if returncode != 0:
        result.error = stderr.splitlines()[-1] if stderr else f"exit code {returncode}"
        return result
    start = next((s for s in stamps if s[1] >= args.warmup), None)
    if start is None or stamps[-1] is start:
        result.error = f"too few progress lines after the warm-up ({len(stamps)})"
        return result
    end = stamps[-1]
    result.start_step, result.end_step = start[1], end[1]
    result.seconds = end[0] - start[0]
    result.sps = (end[1] - start[1]) / result.seconds
    result.routine_use = end[3]
    if start[4] is not None and end[4] is not None and end[4] > start[4]:
        result.cpu_seconds = end[4] - start[4]
    return result


def _num(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def summary_line(results: list[Result], args, threads: int, a2c: str, ppo: str) -> str:
    """One pair's ratios over the repeats at one thread setting, and the verdict."""
    ratios, cpu_ratios = [], []
    mine = [r for r in results if r.threads == threads and not r.error]
    for repeat in range(args.repeats):
        pair = {r.config: r for r in mine if r.repeat == repeat}
        if a2c in pair and ppo in pair:
            ratios.append(pair[ppo].sps / pair[a2c].sps)
            if pair[ppo].cpu_sps and pair[a2c].cpu_sps:
                cpu_ratios.append(pair[ppo].cpu_sps / pair[a2c].cpu_sps)
    label = f"{ppo} / {a2c}, --torch-threads {threads}"
    if not ratios:
        return f"- {label}: no complete pair."
    best = {name: max(r.sps for r in mine if r.config == name) for name in (a2c, ppo)}
    verdict = "yes" if statistics.median(ratios) >= 1.0 else "no"
    if (a2c, ppo) in EXPLAIN_PAIRS:
        verdict += f" ({EXPLAINED[ppo]}: an explanation, not the acceptance)"
    return (f"- {label}: per repeat {', '.join(f'{x:.2f}×' for x in ratios)} in wall-clock "
            f"SPS (median {statistics.median(ratios):.2f}×); per CPU second "
            f"{', '.join(f'{x:.2f}×' for x in cpu_ratios) or '–'}. Best repeats: "
            f"{best[ppo]:,.0f} vs {best[a2c]:,.0f} SPS. rapl_ppo at least as fast: {verdict}.")


def render(results: list[Result], args, command: str, before: str, after: str) -> str:
    """The markdown report: every measurement, then the pairs' ratios."""
    lines = [
        "# rapl_ppo.py vs rapl_a2c.py: agent steps per second on " + args.env_id, "",
        "Produced by `bench/bench_ppo_speed.py` (its docstring says how it measures). Each "
        "script with its own defaults for the env, at each `--torch-threads` setting (0: "
        "torch's default, both scripts' default; 1: the sweeps'); SPS = primitive "
        "agent steps between the progress line at the first step ≥ the warm-up and the last "
        "one, over the wall time between them; `CPU s` the process's CPU time over the same "
        "steps. Other jobs on the machine would lower the figures and make repeats vary: the "
        "load averages before each run are in the table and the busiest other processes at the "
        "end under Setup. The benchmark's own runs keep about two cores busy, so a load near 2 "
        "before a run is mostly the previous run's. Compare the two scripts of a pair, which ran "
        "back to back.", "",
        "| config | script | mode | threads | repeat | load (1/5/15) before | steps timed | wall s "
        "| SPS | CPU s | steps per CPU s | routine use |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        script, mode, _ = CONFIGS[r.config]
        if r.error:
            lines.append(f"| {r.config} | rapl_{script}.py | {mode} | {r.threads} | {r.repeat} | "
                         f"{r.load_before} | error: {r.error} | | | | | |")
            continue
        lines.append(
            f"| {r.config} | rapl_{script}.py | {mode} | {r.threads} | {r.repeat} | "
            f"{r.load_before} | "
            f"{r.end_step - r.start_step:,} | {r.seconds:.1f} | **{r.sps:,.0f}** | "
            f"{_num(r.cpu_seconds, '.1f')} | {_num(r.cpu_sps, ',.0f')} | "
            f"{_num(r.routine_use, '.1f')} % |")
    lines += ["", "## Summary", ""]
    for threads in args.torch_threads:
        for a2c, ppo in (*PAIRS, *(p for p in EXPLAIN_PAIRS if args.explain)):
            lines.append(summary_line(results, args, threads, a2c, ppo))
    lines += [
        "", "## Setup", "",
        f"- Command: `{command}`",
        f"- Load average (1/5/15 min) before the benchmark: {before}; after: {after}",
        f"- Busiest other processes at the end: {other_processes()}",
        "- Commands per configuration (first repeat):",
        *[f"  - {r.config}: `{r.command}`" for r in results if r.repeat == 0],
        "", "## Machine", "",
    ]
    import torch

    info = {**base_machine_info(), "memory": memory(),
            "torch": f"{torch.__version__} (default threads {torch.get_num_threads()})",
            "thread and memory env vars": tuning_env_vars(),
            "git HEAD": git_head(REPO, [str(p) for p in SCRIPTS.values()])}
    lines += [f"- {key}: {value}" for key, value in info.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env-id", default="MinAtar/Breakout-v1")
    parser.add_argument("--demo", default=str(REPO / "demos" / "MinAtar-Breakout-v1.npz"))
    parser.add_argument("--warmup", type=int, default=20_000, help="agent steps before timing")
    parser.add_argument("--steps", type=int, default=100_000, help="agent steps timed")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--explain", action="store_true",
                        help="also run the explanation pairs (rapl_ppo --update-epochs 1, "
                             "and RAPL-PPO --prim-epochs 4)")
    parser.add_argument("--torch-threads", type=int, nargs="+", default=[0, 1],
                        help="the scripts' --torch-threads settings, each measured (0: torch's "
                             "default)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "ppo_speed.md")
    args = parser.parse_args(argv)
    command = "python bench/bench_ppo_speed.py " + shlex.join(argv if argv is not None
                                                               else sys.argv[1:])
    before = load_average()
    results = []
    with tempfile.TemporaryDirectory(prefix="bench_ppo_speed_") as tmp:
        runs = [(repeat, threads, pair) for repeat in range(args.repeats)
                for threads in args.torch_threads
                for pair in (*PAIRS, *(EXPLAIN_PAIRS if args.explain else ()))]
        for repeat, threads, pair in runs:
            for name in pair if repeat % 2 == 0 else reversed(pair):
                result = run_config(name, args, Path(tmp) / "runs", repeat, threads)
                results.append(result)
                print(f"{name} t{threads} (repeat {repeat}): "
                      + (result.error or f"{result.sps:,.0f} SPS"), flush=True)
    report = render(results, args, command.strip(), before, load_average())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".tmp")
    tmp_out.write_text(report)
    tmp_out.replace(args.out)  # never half a report on disk
    print(report)


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
