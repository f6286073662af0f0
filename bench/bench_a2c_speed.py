"""Benchmark: agent steps per second of `algos/rapl_a2c.py` against Stable-Baselines3's A2C.

SPEC §7: on `ALE/Qbert-v5` with 16 envs on this CPU, `rapl_a2c.py` should make at least 1.5×
the agent steps per second of SB3's A2C measured in the same run, with the routines on
(`--mode rapl`) as fast as plain A2C (`--mode a2c`).

Configurations, each run as its own subprocess so that nothing (threads, caches, ALE state) is
shared between them:

- ``a2c-t1`` … ``rapl-async-t2``: `python algos/rapl_a2c.py --mode {a2c,rapl} --num-envs 16
  --eval-episodes 0 --torch-threads {1,2} [--async-envs]` (the script's default is
  `--torch-threads 0`, torch's own count: 2 on a 2-core machine). RAPL mines its routines
  from `--demo`: `demos/ALE-Qbert-v5.npz` when it exists, else a one-episode random-policy Qbert
  demo (at most 2,000 steps) recorded into a temporary folder first.
- ``sb3-default`` / ``sb3-t1``: the RL Zoo's Atari A2C: `make_atari_env("QbertNoFrameskip-v4",
  n_envs=16)`, `VecFrameStack(n_stack=4)`, `A2C("CnnPolicy", n_steps=5, ent_coef=0.01,
  vf_coef=0.25)` with `RMSpropTFLike(eps=1e-5)`, once with torch's default thread count and
  once with 1 thread; its 16 envs are stepped in one process (`DummyVecEnv`).

Agent steps are primitive agent steps (4 frames each, in both libraries): a routine of length
ℓ counts ℓ. Each configuration runs `--warmup` steps, then `--steps` measured steps; the time is
taken in this process around the measured steps, from the arrival of the script's progress line
at the first step ≥ warm-up to that of its last line (`--log-every 1000`), and for SB3 by a
callback at the same points (both brackets hold the same number of whole updates). Env
creation, routine mining, the first `reset` and the final `close` are outside it. The script's
own cumulative `SPS` (which includes the warm-up) is reported beside it, and so is the CPU time
used over the same steps (/proc for the script and its env workers, `time.process_time()` for
SB3), which a shared machine disturbs less than wall time. The load averages are taken before
each configuration; each summary figure is the best repeat of its configuration.

Usage:
    python bench/bench_a2c_speed.py
    python bench/bench_a2c_speed.py --warmup 2000 --steps 20000 --repeats 2
    python bench/bench_a2c_speed.py --configs a2c-t1 rapl-t1 sb3-default --demo my_demo.npz
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

from common import base_machine_info, load_average

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "algos" / "rapl_a2c.py"
#: The SPEC §7 target: ours / SB3 in agent steps per second.
TARGET_RATIO = 1.5


class Config(NamedTuple):
    """Whose A2C, which mode, torch threads (0: torch's default), envs in subprocesses or not."""

    kind: str
    mode: str | None
    threads: int
    async_envs: bool = False


CONFIGS: dict[str, Config] = {
    "a2c-t1": Config("ours", "a2c", 1),
    "a2c-t2": Config("ours", "a2c", 2),
    "rapl-t1": Config("ours", "rapl", 1),
    "rapl-t2": Config("ours", "rapl", 2),
    "a2c-async-t1": Config("ours", "a2c", 1, True),
    "a2c-async-t2": Config("ours", "a2c", 2, True),
    "rapl-async-t1": Config("ours", "rapl", 1, True),
    "rapl-async-t2": Config("ours", "rapl", 2, True),
    "sb3-default": Config("sb3", None, 0),
    "sb3-t1": Config("sb3", None, 1),
}
PROGRESS = re.compile(r"^step\s+([\d,]+)/[\d,]+\s+SPS\s+(\d+).*routine use\s+([\d.]+)%")


@dataclass
class Result:
    """One configuration's measurement."""

    config: str
    repeat: int
    command: str
    torch_threads: str
    load_before: str
    start_step: int = 0
    end_step: int = 0
    seconds: float | None = None
    sps: float | None = None
    cpu_seconds: float | None = None
    cpu_sps: float | None = None
    script_sps: int | None = None
    routine_use: float | None = None
    returncode: int = 0
    error: str = ""
    extra: dict = field(default_factory=dict)


def machine_info() -> dict[str, str]:
    """CPU, cores, library versions, thread settings and date: what a reader needs to compare."""
    import ale_py
    import gymnasium as gym
    import torch

    info = {
        **base_machine_info(),
        "memory": _memory(),
        "torch": f"{torch.__version__} (default threads {torch.get_num_threads()}, "
                 f"interop {torch.get_num_interop_threads()})",
        "gymnasium": gym.__version__,
        "ale-py": ale_py.__version__,
        "thread env vars": ", ".join(
            f"{k}={os.environ[k]}" for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")
            if k in os.environ
        ) or "none set",
        "rapl_a2c.py sha256": hashlib.sha256(SCRIPT.read_bytes()).hexdigest()[:16],
        "git HEAD": _git_head(),
    }
    try:
        import stable_baselines3

        info["stable-baselines3"] = stable_baselines3.__version__
    except ImportError:
        info["stable-baselines3"] = "not installed"
    return info


def _memory() -> str:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    return "unknown"


def _git_head() -> str:
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", str(SCRIPT)], cwd=REPO,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" (rapl_a2c.py modified)" if dirty else "")


def process_cpu_seconds(pid: int) -> float | None:
    """User + system CPU time of process `pid`, all its threads, from /proc (Linux)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat.rsplit(")", 1)[1].split()  # after the command name, which may hold spaces
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def tree_cpu_seconds(pid: int) -> float | None:
    """CPU time of process `pid` and of all its descendants alive now (AsyncVectorEnv workers)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    tree, frontier = {pid}, [pid]
    while frontier:
        children = [p for p, parent in parents.items() if parent in frontier]
        tree.update(children)
        frontier = children
    total = process_cpu_seconds(pid)
    if total is None:
        return None
    return total + sum(process_cpu_seconds(p) or 0.0 for p in tree - {pid})


def other_processes(top: int = 3) -> str:
    """The busiest other processes (ps), so a reader sees what shared the CPU."""
    try:
        out = subprocess.run(["ps", "-eo", "pid,pcpu,args", "--sort=-pcpu"],
                             capture_output=True, text=True, check=True).stdout.splitlines()
    except (OSError, subprocess.CalledProcessError):
        return "ps unavailable"
    rows = [line.strip() for line in out[1:] if str(os.getpid()) not in line.split()[:1]]
    return "; ".join(row[:140] for row in rows[:top])


# ---------------------------------------------------------------------------------------------
# The demo RAPL mines its routines from
# ---------------------------------------------------------------------------------------------


def qbert_demo(env_id: str, requested: str | None, workdir: Path) -> tuple[str, str]:
    """The demo path for `--mode rapl` and where it came from."""
    if requested:
        return requested, "given with --demo"
    shipped = REPO / "demos" / f"{env_id.replace('/', '-')}.npz"
    if shipped.exists():
        return str(shipped), "shipped demo"
    import numpy as np

    import routine_gym
    from routine_gym.demo import record_agent_demo
    from routine_gym.envs.factory import default_env_kwargs, make_primitive_env

    routine_gym.register_envs()
    probe = make_primitive_env(env_id)
    num_actions = int(probe.action_space.n)
    probe.close()
    rng = np.random.default_rng(0)

    def policy(obs) -> int:
        return int(rng.integers(num_actions))

    demo = record_agent_demo(env_id, policy, num_episodes=1, max_steps=2000,
                             env_kwargs=default_env_kwargs(env_id), progress=False)
    path = workdir / f"{env_id.replace('/', '-')}-random.npz"
    demo.save(path, include_observations=False)
    return str(path), f"random policy, 1 episode, {len(demo)} steps, score {demo.score:g}"


# ---------------------------------------------------------------------------------------------
# Running one configuration
# ---------------------------------------------------------------------------------------------


def run_ours(name: str, config: Config, args, demo: str, run_dir: Path, repeat: int) -> Result:
    """Run `rapl_a2c.py` in a subprocess and time its progress lines as they arrive."""
    mode, threads = config.mode, config.threads
    total = args.warmup + args.steps
    cmd = [sys.executable, str(SCRIPT), "--env-id", args.env_id, "--mode", mode,
           "--num-envs", str(args.num_envs), "--total-timesteps", str(total),
           "--eval-episodes", "0", "--log-every", str(args.log_every),
           "--torch-threads", str(threads), "--run-dir", str(run_dir), "--seed", "1"]
    if mode != "a2c":
        cmd += ["--demo", demo]
    if config.async_envs:
        cmd.append("--async-envs")
    result = Result(name, repeat, shlex.join(cmd), str(threads), load_average())
    stamps: list[tuple[float, int, int, float, float | None]] = []
    header: list[str] = []
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=err, text=True,
                                bufsize=1, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert proc.stdout is not None
        for line in iter(proc.stdout.readline, ""):
            now = time.perf_counter()
            match = PROGRESS.match(line.strip())
            if match:
                step = int(match.group(1).replace(",", ""))
                stamps.append((now, step, int(match.group(2)), float(match.group(3)),
                               tree_cpu_seconds(proc.pid)))
            elif not stamps:
                header.append(line.rstrip())
        result.returncode = proc.wait()
        err.seek(0)
        stderr = err.read()
    result.extra["routines"] = [h.strip() for h in header if h.strip().startswith("[")]
    if result.returncode != 0:
        result.error = stderr.strip().splitlines()[-1] if stderr.strip() else "no output"
        return result
    start = next((s for s in stamps if s[1] >= args.warmup), None)
    if start is None or stamps[-1] is start:
        result.error = f"too few progress lines ({len(stamps)})"
        return result
    end = stamps[-1]
    result.start_step, result.end_step = start[1], end[1]
    result.seconds = end[0] - start[0]
    result.sps = (end[1] - start[1]) / result.seconds
    result.script_sps, result.routine_use = end[2], end[3]
    if start[4] is not None and end[4] is not None and end[4] > start[4]:
        result.cpu_seconds = end[4] - start[4]
        result.cpu_sps = (end[1] - start[1]) / result.cpu_seconds
    return result


def run_sb3(name: str, threads: int, args, repeat: int) -> Result:
    """Run SB3's A2C in a subprocess (this file's `--worker sb3`) and read its JSON line."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "sb3",
           "--sb3-env-id", args.sb3_env_id, "--num-envs", str(args.num_envs),
           "--warmup", str(args.warmup), "--steps", str(args.steps),
           "--worker-threads", str(threads)]
    result = Result(name, repeat, shlex.join(cmd), "default" if threads == 0 else str(threads),
                    load_average())
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    result.returncode = proc.returncode
    line = next((x for x in reversed(proc.stdout.splitlines()) if x.startswith("{")), None)
    if proc.returncode != 0 or line is None:
        result.error = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "?"
        return result
    data = json.loads(line)
    result.start_step, result.end_step = data["start_step"], data["end_step"]
    result.seconds = data["seconds"]
    result.sps = (result.end_step - result.start_step) / result.seconds
    result.cpu_seconds = data["cpu_seconds"]
    result.cpu_sps = (result.end_step - result.start_step) / result.cpu_seconds
    result.torch_threads = f"{data['torch_threads']}" + (" (default)" if threads == 0 else "")
    result.extra = {k: data[k] for k in ("env_id", "optimizer", "interop_threads")}
    return result


def sb3_worker(args) -> None:
    """SB3 A2C as the RL Zoo runs it on Atari; prints one JSON line with the timed bracket."""
    import ale_py
    import gymnasium as gym
    import torch
    from stable_baselines3 import A2C
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_atari_env
    from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike
    from stable_baselines3.common.vec_env import VecFrameStack

    gym.register_envs(ale_py)
    if args.worker_threads > 0:
        torch.set_num_threads(args.worker_threads)
    env = VecFrameStack(make_atari_env(args.sb3_env_id, n_envs=args.num_envs, seed=1),
                        n_stack=4)
    end_at = args.warmup + args.steps

    class Timer(BaseCallback):
        """Time stamps at the first step ≥ warm-up and at the end; stops training there."""

        def __init__(self) -> None:
            super().__init__()
            self.start: tuple[float, int, float] | None = None
            self.end: tuple[float, int, float] | None = None

        def _on_step(self) -> bool:
            now, cpu = time.perf_counter(), time.process_time()
            if self.start is None and self.num_timesteps >= args.warmup:
                self.start = (now, self.num_timesteps, cpu)
            if self.num_timesteps >= end_at:
                self.end = (now, self.num_timesteps, cpu)
                return False
            return True

    # The RL Zoo's hyperparameters for A2C on Atari (hyperparams/a2c.yml, `atari:`).
    model = A2C("CnnPolicy", env, n_steps=5, ent_coef=0.01, vf_coef=0.25, device="cpu",
                policy_kwargs={"optimizer_class": RMSpropTFLike,
                               "optimizer_kwargs": {"eps": 1e-5}},
                seed=1, verbose=0)
    timer = Timer()
    model.learn(total_timesteps=end_at + args.num_envs * 5, callback=timer)
    env.close()
    assert timer.start is not None and timer.end is not None
    print(json.dumps({
        "start_step": timer.start[1], "end_step": timer.end[1],
        "seconds": timer.end[0] - timer.start[0], "cpu_seconds": timer.end[2] - timer.start[2],
        "torch_threads": torch.get_num_threads(),
        "interop_threads": torch.get_num_interop_threads(), "env_id": args.sb3_env_id,
        "optimizer": "RMSpropTFLike(eps=1e-5)",
    }))


# ---------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------


def best(results: list[Result], config: str) -> Result | None:
    """The fastest successful repeat of `config` (load only slows a run down)."""
    ok = [r for r in results if r.config == config and not r.error]
    return max(ok, key=lambda r: r.sps) if ok else None


def script_default_threads() -> int | None:
    """The `--torch-threads` default of rapl_a2c.py as its source states it (it has changed)."""
    match = re.search(r"^\s*torch_threads: int = (\d+)", SCRIPT.read_text(), re.MULTILINE)
    return int(match.group(1)) if match else None


def _num(value: float | None, spec: str) -> str:
    return "–" if value is None else format(value, spec)


def render(results: list[Result], info: dict[str, str], command: str, demo_note: str,
           args) -> str:
    """The markdown report."""
    sb3_default, sb3_t1 = best(results, "sb3-default"), best(results, "sb3-t1")

    def ratio(r: Result, ref: Result | None) -> str:
        if ref is None or r.error:
            return "–"
        value = r.sps / ref.sps
        mark = "" if value >= TARGET_RATIO or CONFIGS[r.config].kind == "sb3" else " (under)"
        return f"{value:.2f}×{mark}"

    lines = [
        "# rapl_a2c.py vs Stable-Baselines3 A2C: agent steps per second",
        "",
        "Produced by `bench/bench_a2c_speed.py`; the command, machine and load are below. "
        f"{args.num_envs} envs, {args.warmup:,} warm-up + {args.steps:,} measured agent steps "
        "per configuration, each in its own process; SPS = measured steps / wall time around "
        "them (external). `script SPS` is the script's own cumulative figure (warm-up "
        "included). `CPU s`: user + system CPU time of the process (all its threads) over the "
        "same steps; `steps per CPU s` is less sensitive to other jobs on a shared machine "
        "than SPS, but charges a 2-thread run for its threads' spinning. Target (SPEC §7): "
        f"ours ≥ {TARGET_RATIO}× SB3 in SPS, routines on as fast as plain A2C. The load "
        "average lags: just after an `--async-envs` run it still counts that run's env "
        "workers.",
        "",
        "| config | torch threads | repeat | load (1/5/15) before | steps timed | wall s | SPS "
        "| script SPS | CPU s | steps per CPU s | routine use | ÷ SB3 (default threads) "
        "| ÷ SB3 (1 thread) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        if r.error:
            lines.append(f"| {r.config} | {r.torch_threads} | {r.repeat} | {r.load_before} "
                         f"| failed: {r.error} | | | | | | | | |")
            continue
        use = f"{r.routine_use:.1f} %" if r.routine_use is not None else "–"
        lines.append(
            f"| {r.config} | {r.torch_threads} | {r.repeat} | {r.load_before} "
            f"| {r.end_step - r.start_step:,} | {r.seconds:.1f} | **{r.sps:,.0f}** "
            f"| {r.script_sps if r.script_sps is not None else '–'} "
            f"| {_num(r.cpu_seconds, '.1f')} | {_num(r.cpu_sps, ',.0f')} | {use} "
            f"| {ratio(r, sb3_default)} | {ratio(r, sb3_t1)} |"
        )
    lines += ["", "## Summary (best repeat of each configuration)", ""]
    default_threads = script_default_threads()
    for name, config in CONFIGS.items():
        ours = best(results, name)
        if config.kind != "ours" or ours is None:
            continue
        label = f"{config.mode}, --torch-threads {config.threads}"
        if config.async_envs:
            label += ", --async-envs"
        elif config.threads == default_threads:
            label += " (the script's default)"
        if sb3_default is None:
            lines.append(f"- {label}: {ours.sps:,.0f} SPS; SB3 not measured")
            continue
        value = ours.sps / sb3_default.sps
        verdict = "meets" if value >= TARGET_RATIO else "misses"
        lines.append(f"- {label}: {ours.sps:,.0f} SPS = {value:.2f}× SB3 with torch's default "
                     f"threads ({sb3_default.sps:,.0f}); {verdict} the {TARGET_RATIO}× target.")
        if sb3_t1 is not None:
            lines.append(f"  Against SB3 with 1 thread ({sb3_t1.sps:,.0f} SPS): "
                         f"{ours.sps / sb3_t1.sps:.2f}×.")
        if ours.cpu_sps and sb3_default.cpu_sps and sb3_t1 is not None and sb3_t1.cpu_sps:
            lines.append(f"  Per CPU second: {ours.cpu_sps:,.0f} steps, "
                         f"{ours.cpu_sps / sb3_default.cpu_sps:.2f}× SB3 default threads, "
                         f"{ours.cpu_sps / sb3_t1.cpu_sps:.2f}× SB3 1 thread.")
    for variant in ("t1", "t2", "async-t1", "async-t2"):
        a2c, rapl = best(results, f"a2c-{variant}"), best(results, f"rapl-{variant}")
        if a2c is not None and rapl is not None:
            lines.append(f"- rapl / a2c ({variant}): {rapl.sps / a2c.sps:.2f}× in agent steps "
                         "(a routine of length ℓ counts ℓ steps).")
    if default_threads == 0:
        lines.append("- The script's default `--torch-threads 0` is torch's own thread count "
                     f"({os.cpu_count()} here), i.e. the `-t{os.cpu_count()}` rows.")
    routines = next((r.extra.get("routines") for r in results if r.extra.get("routines")), None)
    lines += ["", "## Setup", "", f"- Command: `{command}`", f"- RAPL demo: {demo_note}"]
    if routines:
        lines.append("- Routines mined: " + "; ".join(f"`{x}`" for x in routines))
    lines += ["- Commands per configuration (first repeat):"]
    seen: set[str] = set()
    for r in results:
        if r.config not in seen:
            seen.add(r.config)
            lines.append(f"  - {r.config}: `{r.command}`")
    lines += ["", "## Machine", ""]
    lines += [f"- {k}: {v}" for k, v in info.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="ALE/Qbert-v5", help="env of rapl_a2c.py")
    parser.add_argument("--sb3-env-id", default="QbertNoFrameskip-v4",
                        help="env of SB3's make_atari_env (the RL Zoo uses NoFrameskip-v4)")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--warmup", type=int, default=2000, help="agent steps before timing")
    parser.add_argument("--steps", type=int, default=20000, help="agent steps timed")
    parser.add_argument("--repeats", type=int, default=1,
                        help="rounds over all configurations (the best of each is summarised)")
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--demo", default=None,
                        help="demo for --mode rapl (default: demos/ALE-Qbert-v5.npz, else a "
                             "random-policy demo recorded on the fly)")
    parser.add_argument("--log-every", type=int, default=1000,
                        help="progress-line spacing of rapl_a2c.py (the timing resolution)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "a2c_speed.md",
                        help="markdown report; the raw numbers go beside it as .json")
    parser.add_argument("--from-json", type=Path, default=None,
                        help="run nothing: write the report again from this file's raw numbers")
    parser.add_argument("--worker", choices=["sb3"], help=argparse.SUPPRESS)
    parser.add_argument("--worker-threads", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    for name in ("num_envs", "steps", "log_every", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} needs to be ≥ 1, "
                         f"actual value: {getattr(args, name)}")
    if args.warmup < 0:
        parser.error(f"--warmup needs to be ≥ 0, actual value: {args.warmup}")
    if args.worker == "sb3":
        sb3_worker(args)
        return

    from routine_gym.plumbing.atomic import atomic_write_text

    if args.from_json is not None:
        raw = json.loads(args.from_json.read_text())
        for name in ("warmup", "steps", "num_envs"):
            setattr(args, name, raw[name])
        results = [Result(**r) for r in raw["results"]]
        report = render(results, raw["machine"], raw["command"], raw["demo"], args)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, report)
        print(f"written to {args.out}")
        return

    command = "python " + shlex.join([os.path.relpath(__file__, REPO), *sys.argv[1:]])
    info = machine_info()
    print(f"# {command}\n# load average at start: {load_average()}\n"
          f"# busiest processes: {other_processes()}", flush=True)
    results: list[Result] = []
    with tempfile.TemporaryDirectory(prefix="bench_a2c_speed_") as tmp:
        demo, demo_note = ("", "not used")
        if any(CONFIGS[c].mode not in (None, "a2c") for c in args.configs):
            demo, demo_note = qbert_demo(args.env_id, args.demo, Path(tmp))
            print(f"# demo: {demo} ({demo_note})", flush=True)
        for repeat in range(1, args.repeats + 1):
            for name in args.configs:
                config = CONFIGS[name]
                if config.kind == "ours":
                    result = run_ours(name, config, args, demo, Path(tmp) / "runs", repeat)
                else:
                    result = run_sb3(name, config.threads, args, repeat)
                results.append(result)
                print(f"{name:12s} repeat {repeat}  load {result.load_before}  "
                      + (f"FAILED {result.error}" if result.error else
                         f"{result.sps:8,.0f} SPS over {result.end_step - result.start_step:,}"
                         f" steps in {result.seconds:.1f} s"), flush=True)
    info["load average at end"] = load_average()
    info["busiest processes at end"] = other_processes()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, render(results, info, command, demo_note, args))
    raw = {"command": command, "machine": info, "demo": demo_note,
           "warmup": args.warmup, "steps": args.steps, "num_envs": args.num_envs,
           "results": [asdict(r) for r in results]}
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(raw, indent=2) + "\n")
    print(f"written to {args.out} and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
