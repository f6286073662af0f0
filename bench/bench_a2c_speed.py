"""Benchmark: agent steps per second of `algos/rapl_a2c.py` against Stable-Baselines3's A2C and
against the network alone.

SPEC §7: on `ALE/Qbert-v5` with 16 envs on this CPU, `rapl_a2c.py` should make at least 1.5×
the agent steps per second of SB3's A2C measured in the same run, with the routines on
(`--mode rapl`) as fast as plain A2C (`--mode a2c`). On MinAtar (`--env-id MinAtar/...`, 16
envs) the script should run at the network's speed: `--mode a2c` at ≥ 20,000 agent steps/s
and ≥ 0.8× the network-only bound (below) measured in the same run, `--mode rapl` at least as
fast; SB3's ratio is reported as measured, with no target.

Configurations, each run as its own subprocess so that nothing (threads, caches, ALE state) is
shared between them:

- ``net-t1`` / ``net-t2``: the network-only bound, this file's `--worker net` with 1 or 2
  torch threads: the `Agent` of `rapl_a2c.py` (imported from the file) for the env's agent
  observation space and primitive action count (`--mode a2c`), trained with exactly the
  script's per-rollout network work and defaults (its `Args`, `--update-forward auto`):
  `--num-steps` acting passes on batches of `--num-envs` observations, each sampled action
  brought back with `.cpu().numpy()`; for the small networks (MinAtar) `Agent.act` without a
  graph, then one `Agent.evaluate` pass over the rollout's decision states and the bootstrap
  states; for the large CNNs (Atari) `get_action_and_value` keeping each pass's graph, then
  one pass without a graph over the bootstrap states; the losses (policy, value ×
  `vf_coef`, entropy × `ent_coef`) against random returns, the loss values read with
  `.item()`, `zero_grad`, `backward`, `clip_grad_norm_`,
  and an RMSprop(`foreach=True`) step, with the learning rate annealed per rollout as the
  script does, and freed memory kept for reuse as `start_run` keeps it for the script
  (`routine_gym.plumbing.memory`). The inputs are random (0/1 floats for float spaces such as
  MinAtar's, uint8 for Atari frames): a few batches generated before timing and reused
  cyclically. No env is stepped, so no script can be faster with this network and these
  threads.
- ``a2c-t1`` … ``rapl-async-t2``: `python algos/rapl_a2c.py --mode {a2c,rapl} --num-envs 16
  --eval-episodes 0 --torch-threads {1,2} [--async-envs]` (the script's default is
  `--torch-threads 0`, torch's own count: 2 on a 2-core machine). RAPL mines its routines
  from `--demo`: `demos/ALE-Qbert-v5.npz` when it exists, else a one-episode random-policy Qbert
  demo (at most 2,000 steps) recorded into a temporary folder first.
- ``sb3-default`` / ``sb3-t1``: SB3's A2C, once with torch's default thread count and once with
  1 thread; its 16 envs are stepped in one process (`DummyVecEnv`). On Atari, the RL Zoo's
  Atari A2C: `make_atari_env("QbertNoFrameskip-v4", n_envs=16)`, `VecFrameStack(n_stack=4)`,
  `A2C("CnnPolicy", n_steps=5, ent_coef=0.01, vf_coef=0.25)` with `RMSpropTFLike(eps=1e-5)`.
  On MinAtar, the same env stack and network as ours: a `DummyVecEnv` of 16
  `routine_gym.envs.factory.make_env` envs (the MinAtar game, `RecordEpisodeStatistics`, the
  channels-first float32 (C, 10, 10) view), `A2C("CnnPolicy", n_steps=5, ent_coef=0.01,
  vf_coef=0.5, learning_rate=7e-4)` with `MinAtarExtractor` (MinAtar's network, as
  `routine_gym.networks.make_torso` builds it), `net_arch=[]` (linear actor and critic heads
  on its 128 features) and `normalize_images=False`, and SB3's default RMSprop(alpha=0.99,
  eps=1e-5), the same as ours.

Agent steps are primitive agent steps (on Atari 4 frames each, in both libraries): a routine
of length ℓ counts ℓ. Each configuration runs `--warmup` steps, then `--steps` measured steps;
the time is taken in this process around the measured steps, from the arrival of the script's
progress line at the first step ≥ warm-up to that of its last line (`--log-every 1000`), for
SB3 by a callback at the same points (both brackets hold the same number of whole updates),
and for the network-only bound inside the worker around whole rollouts (`--num-envs` ×
`--num-steps` agent steps each): the warm-up rollouts cover `--warmup` steps, the timed ones
`--steps` (both rounded up to whole rollouts). Env creation, routine mining, the first
`reset`, the network's construction and the final `close` are outside it. The script's own
cumulative `SPS` (which includes the warm-up) is reported beside it, and so is the CPU time
used over the same steps (/proc for the script and its env workers, `time.process_time()` for
SB3 and the network worker), which a shared machine disturbs less than wall time. The load
averages are taken before each configuration; each summary figure is the best repeat of its
configuration, and each of our configurations is also given as a fraction of the
network-only bound with the same number of torch threads.

Usage:
    python bench/bench_a2c_speed.py
    python bench/bench_a2c_speed.py --warmup 2000 --steps 20000 --repeats 2
    python bench/bench_a2c_speed.py --configs a2c-t1 rapl-t1 sb3-default --demo my_demo.npz
    python bench/bench_a2c_speed.py --env-id MinAtar/Breakout-v1 \\
        --demo demos/MinAtar-Breakout-v1.npz --configs net-t1 a2c-t1 rapl-t1 sb3-t1 \\
        --out bench/results/a2c_speed_minatar.md
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

from common import base_machine_info, git_head, load_average, memory, tuning_env_vars

from routine_gym.plumbing.openmp import shorten_spin

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "algos" / "rapl_a2c.py"
#: The SPEC §7 target: ours / SB3 in agent steps per second.
TARGET_RATIO = 1.5
#: MinAtar's acceptance: `--mode a2c` at least this many agent steps per second ...
MINATAR_MIN_SPS = 20_000
#: ... and at least this fraction of the network-only bound with the same torch threads.
MINATAR_BOUND_RATIO = 0.8
#: Random input batches the network worker cycles through (generated before timing).
NET_BATCHES = 8


class Config(NamedTuple):
    """Whose A2C (ours, sb3) or the network alone (net), which mode, torch threads (0: torch's
    default), envs in subprocesses or not."""

    kind: str
    mode: str | None
    threads: int
    async_envs: bool = False


CONFIGS: dict[str, Config] = {
    "net-t1": Config("net", None, 1),
    "net-t2": Config("net", None, 2),
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
        "memory": memory(),
        "torch": f"{torch.__version__} (default threads {torch.get_num_threads()}, "
                 f"interop {torch.get_num_interop_threads()})",
        "gymnasium": gym.__version__,
        "ale-py": ale_py.__version__,
        "thread and memory env vars": tuning_env_vars(),
        "rapl_a2c.py sha256": hashlib.sha256(SCRIPT.read_bytes()).hexdigest()[:16],
        "git HEAD": git_head(REPO, [str(SCRIPT)]),
    }
    try:
        import stable_baselines3

        info["stable-baselines3"] = stable_baselines3.__version__
    except ImportError:
        info["stable-baselines3"] = "not installed"
    return info






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


#: A progress line's arrival: (perf_counter time, step, script SPS, routine use %, CPU seconds of
#: the process tree or None).
Stamp = tuple[float, int, int, float, "float | None"]


def stream_progress(cmd: list[str], warmup: int,
                    total: int) -> tuple[list[Stamp], list[str], int, str]:
    """Run a script's command line in a subprocess, stamping each progress line as it arrives.

    The process tree's CPU time is read only at the lines a measurement starts and ends at, the
    first at or after `warmup` steps and those at or after `total`: reading it walks all of
    /proc (~1 ms), which at every line (`--log-every 1000`: ~30 lines a second) took a few
    percent of a core from the two-thread script being timed.

    Returns the stamps (CPU time None where not read), the output lines before the first
    progress line, the exit code and stderr."""
    stamps: list[Stamp] = []
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
                first_timed = step >= warmup and not (stamps and stamps[-1][1] >= warmup)
                cpu = tree_cpu_seconds(proc.pid) if first_timed or step >= total else None
                stamps.append((now, step, int(match.group(2)), float(match.group(3)), cpu))
            elif not stamps:
                header.append(line.rstrip())
        returncode = proc.wait()
        err.seek(0)
        stderr = err.read()
    return stamps, header, returncode, stderr


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
    stamps, header, result.returncode, stderr = stream_progress(cmd, args.warmup, total)
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


#: What a worker's JSON line holds besides the description kept in `Result.extra`.
_TIMING_KEYS = ("start_step", "end_step", "seconds", "cpu_seconds", "torch_threads")


def run_worker(name: str, config: Config, args, repeat: int) -> Result:
    """Run this file's `--worker sb3` (SB3's A2C) or `--worker net` (the network alone) in a
    subprocess and read its JSON line."""
    threads = config.threads
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", config.kind,
           "--env-id", args.env_id]
    if config.kind == "sb3" and not is_minatar(args.env_id):  # MinAtar: SB3 runs --env-id
        cmd += ["--sb3-env-id", args.sb3_env_id]
    cmd += ["--num-envs", str(args.num_envs), "--warmup", str(args.warmup),
            "--steps", str(args.steps), "--worker-threads", str(threads)]
    result = Result(name, repeat, shlex.join(cmd), "default" if threads == 0 else str(threads),
                    load_average())
    env = dict(os.environ)
    if config.kind == "net":  # the bound under the scripts' OpenMP spin; SB3 as its users run it
        shorten_spin(env)
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env)
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
    if result.cpu_seconds:
        result.cpu_sps = (result.end_step - result.start_step) / result.cpu_seconds
    result.torch_threads = f"{data['torch_threads']}" + (" (default)" if threads == 0 else "")
    result.extra = {k: v for k, v in data.items() if k not in _TIMING_KEYS}
    return result


def minatar_extractor_class():
    """`MinAtarExtractor`: MinAtar's network as an SB3 features extractor (SB3 imported late,
    so that the parent process never loads it)."""
    import torch.nn as nn
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class MinAtarExtractor(BaseFeaturesExtractor):
        """Conv2d(C, 16, 3, stride 1), ReLU, Flatten, Linear(16·(H−2)·(W−2), 128), ReLU: the
        torso `routine_gym.networks.make_torso` builds for MinAtar (SB3 initialises it
        orthogonally with gain √2, as `layer_init` does)."""

        def __init__(self, observation_space, features_dim: int = 128) -> None:
            super().__init__(observation_space, features_dim)
            c, h, w = observation_space.shape
            self.torso = nn.Sequential(
                nn.Conv2d(c, 16, 3, stride=1), nn.ReLU(), nn.Flatten(),
                nn.Linear(16 * (h - 2) * (w - 2), features_dim), nn.ReLU(),
            )

        def forward(self, observations):
            return self.torso(observations)

    return MinAtarExtractor


def sb3_timer(warmup: int, end_at: int):
    """SB3's callback that takes the time stamps."""
    from stable_baselines3.common.callbacks import BaseCallback

    class Timer(BaseCallback):
        """Time stamps at the first step ≥ warm-up and at the end; stops training there."""

        def __init__(self) -> None:
            super().__init__()
            self.start: tuple[float, int, float] | None = None
            self.end: tuple[float, int, float] | None = None

        def _on_step(self) -> bool:
            now, cpu = time.perf_counter(), time.process_time()
            if self.start is None and self.num_timesteps >= warmup:
                self.start = (now, self.num_timesteps, cpu)
            if self.num_timesteps >= end_at:
                self.end = (now, self.num_timesteps, cpu)
                return False
            return True

    return Timer()


def sb3_worker(args) -> None:
    """SB3 A2C, as the RL Zoo runs it on Atari, or on MinAtar with our env stack and network;
    prints one JSON line with the timed bracket."""
    import torch
    from stable_baselines3 import A2C

    if args.worker_threads > 0:
        torch.set_num_threads(args.worker_threads)
    end_at = args.warmup + args.steps
    minatar = args.env_id.startswith("MinAtar/")
    if minatar:
        from stable_baselines3.common.vec_env import DummyVecEnv

        import routine_gym
        from routine_gym.envs.factory import make_env
        from routine_gym.networks import make_torso

        routine_gym.register_envs()
        env_id = args.env_id
        env = DummyVecEnv([make_env(env_id, seed=1, idx=i, training=True)
                           for i in range(args.num_envs)])
        extractor = minatar_extractor_class()
        model = A2C("CnnPolicy", env, n_steps=5, ent_coef=0.01, vf_coef=0.5,
                    learning_rate=7e-4, device="cpu", seed=1, verbose=0,
                    policy_kwargs={"features_extractor_class": extractor,
                                   "features_extractor_kwargs": {"features_dim": 128},
                                   "net_arch": [], "normalize_images": False})
        # The same network as ours: the extractor's parameters have our torso's shapes.
        ours, _ = make_torso(env_id, env.observation_space.shape)
        theirs = model.policy.features_extractor
        assert [p.shape for p in theirs.parameters()] == [p.shape for p in ours.parameters()]
        optimizer = "RMSprop(alpha=0.99, eps=1e-5) (SB3's A2C default)"
        setup = (f"SB3 on MinAtar: `DummyVecEnv` of {args.num_envs} "
                 "`routine_gym.envs.factory.make_env(env_id, seed=1, idx=i, training=True)` "
                 "envs (MinAtar game, RecordEpisodeStatistics, channels-first float32 "
                 f"{tuple(env.observation_space.shape)} view); `A2C(\"CnnPolicy\", n_steps=5, "
                 "ent_coef=0.01, vf_coef=0.5, learning_rate=7e-4)` with `MinAtarExtractor` "
                 "(Conv2d(C,16,3) ReLU Flatten Linear(16·8·8,128) ReLU, our torso), "
                 "`net_arch=[]`, `normalize_images=False`; SB3's default RMSprop(alpha=0.99, "
                 "eps=1e-5), the same as ours")
    else:
        import ale_py
        import gymnasium as gym
        from stable_baselines3.common.env_util import make_atari_env
        from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike
        from stable_baselines3.common.vec_env import VecFrameStack

        gym.register_envs(ale_py)
        env_id = args.sb3_env_id
        env = VecFrameStack(make_atari_env(env_id, n_envs=args.num_envs, seed=1), n_stack=4)
        # The RL Zoo's hyperparameters for A2C on Atari (hyperparams/a2c.yml, `atari:`).
        model = A2C("CnnPolicy", env, n_steps=5, ent_coef=0.01, vf_coef=0.25, device="cpu",
                    policy_kwargs={"optimizer_class": RMSpropTFLike,
                                   "optimizer_kwargs": {"eps": 1e-5}},
                    seed=1, verbose=0)
        optimizer, setup = "RMSpropTFLike(eps=1e-5)", None
    timer = sb3_timer(args.warmup, end_at)
    from stable_baselines3.common.logger import Logger
    model.set_logger(Logger(None, []))  # no output; SB3's default makes a folder /tmp/SB3-…
    model.learn(total_timesteps=end_at + args.num_envs * 5, callback=timer)
    env.close()
    assert timer.start is not None and timer.end is not None
    line = {
        "start_step": timer.start[1], "end_step": timer.end[1],
        "seconds": timer.end[0] - timer.start[0], "cpu_seconds": timer.end[2] - timer.start[2],
        "torch_threads": torch.get_num_threads(),
        "interop_threads": torch.get_num_interop_threads(), "env_id": env_id,
        "optimizer": optimizer,
    }
    if setup is not None:
        line["setup"] = setup
    print(json.dumps(line))


def load_script_module():
    """`algos/rapl_a2c.py` as a module (its `Agent` and `Args`), without running it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rapl_a2c", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while it runs
    spec.loader.exec_module(module)
    return module


def net_worker(args) -> None:
    """The network-only bound: the script's per-rollout network work on random inputs, timed
    over whole rollouts; prints one JSON line like `sb3_worker`."""
    import warnings

    import numpy as np
    import torch
    import torch.nn as nn

    import routine_gym
    from routine_gym.envs import profile_for
    from routine_gym.envs.factory import make_vector_env
    from routine_gym.plumbing.run import seed_and_tune
    from routine_gym.returns import critic_loss

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    script = load_script_module()
    defaults = script.Args()  # the script's own hyperparameters (lr, RMSprop, N, coefficients)
    seed_and_tune(1, args.worker_threads)  # what `start_run` sets for the script

    probe = make_vector_env(args.env_id, 1)
    space, num_actions = probe.single_observation_space, int(probe.single_action_space.n)
    probe.close()
    agent = script.Agent(args.env_id, space, num_actions)
    # The script's --update-forward auto: the acting graphs for the large CNNs.
    keep_graph = profile_for(args.env_id).network in ("nature_cnn", "impala_cnn")
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=defaults.learning_rate,
                                    alpha=defaults.rmsprop_alpha, eps=defaults.rmsprop_eps,
                                    foreach=True)

    n, e = defaults.num_steps, args.num_envs
    rng = np.random.default_rng(1)
    shape = (e, *space.shape)
    if np.dtype(space.dtype) == np.uint8:
        inputs = [rng.integers(0, 256, size=shape, dtype=np.uint8) for _ in range(NET_BATCHES)]
    else:
        inputs = [rng.integers(0, 2, size=shape).astype(space.dtype) for _ in range(NET_BATCHES)]
    targets = [rng.normal(size=(n, e)) for _ in range(NET_BATCHES)]  # returns, float64
    actions = [rng.integers(0, num_actions, size=(n, e)) for _ in range(NET_BATCHES)]
    per_rollout = n * e
    warm = -(-args.warmup // per_rollout)
    timed = max(1, -(-args.steps // per_rollout))
    total = (warm + timed) * per_rollout

    def rollout(i: int) -> None:
        """One rollout's network work of `rapl_a2c.py --mode a2c`, in its order."""
        if defaults.anneal_lr:
            optimizer.param_groups[0]["lr"] = (1.0 - i * per_rollout / total) \
                * defaults.learning_rate
        rollout_obs, acting_outputs = [], []
        for step in range(n):
            obs = inputs[(i * (n + 1) + step) % NET_BATCHES]
            if keep_graph:  # acting keeps its graph for the update (--update-forward acting)
                action, logprob, entropy, value = agent.get_action_and_value(
                    torch.as_tensor(obs))
                acting_outputs.append((logprob, entropy, value))
                action.cpu().numpy()
            else:  # acting: no graph
                with torch.inference_mode():
                    agent.act(torch.as_tensor(obs)).cpu().numpy()
            rollout_obs.append(obs)
        rollout_obs.append(inputs[(i * (n + 1) + n) % NET_BATCHES])  # the state after it
        if keep_graph:
            logprobs, entropies, values = (torch.cat(x) for x in zip(*acting_outputs,
                                                                     strict=True))
            values = values.view(n, e)
            with torch.no_grad():  # the bootstrap
                agent.get_value(torch.as_tensor(rollout_obs[n])).cpu().numpy()
        else:
            # The update: one pass over the n·e decision states and the e states after them.
            logprobs, entropies, all_values = agent.evaluate(
                torch.as_tensor(np.stack(rollout_obs).reshape(-1, *space.shape)),
                torch.as_tensor(actions[i % NET_BATCHES].reshape(-1)))
            values = all_values[: n * e].view(n, e)
            all_values[n * e:].detach().cpu().numpy()  # the bootstrap
        b_returns = torch.as_tensor(targets[i % NET_BATCHES], dtype=torch.float32)
        advantages = b_returns - values
        pg_loss = -(logprobs.view(n, e) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = entropies.view(n, e).mean()
        prim_loss = torch.zeros(())
        loss = pg_loss - defaults.ent_coef * entropy_loss + defaults.vf_coef * critic_loss(
            v_loss, prim_loss, defaults.critic_loss, defaults.prim_coef)
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(agent.parameters(), defaults.max_grad_norm)
        optimizer.step()
        for value in (v_loss, prim_loss, pg_loss, entropy_loss):  # the script logs these
            value.item()

    for i in range(warm):
        rollout(i)
    start, start_cpu = time.perf_counter(), time.process_time()
    for i in range(warm, warm + timed):
        rollout(i)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - start_cpu
    print(json.dumps({
        "start_step": warm * per_rollout, "end_step": total, "seconds": seconds,
        "cpu_seconds": cpu_seconds, "torch_threads": torch.get_num_threads(),
        "interop_threads": torch.get_num_interop_threads(), "env_id": args.env_id,
        "obs": f"{tuple(space.shape)} {np.dtype(space.dtype).name}",
        "num_actions": num_actions,
        "parameters": sum(p.numel() for p in agent.parameters()),
        "optimizer": f"RMSprop(lr={defaults.learning_rate:g}, alpha={defaults.rmsprop_alpha:g}, "
                     f"eps={defaults.rmsprop_eps:g}, foreach=True)",
        "setup": (f"Network-only bound: `Agent` of rapl_a2c.py for {tuple(space.shape)} "
                  f"{np.dtype(space.dtype).name} observations and {num_actions} actions "
                  f"({sum(p.numel() for p in agent.parameters()):,} parameters); per rollout "
                  + (f"{n} acting passes on {e} observations keeping their graphs for the "
                     f"update (actions `.cpu().numpy()`), one pass without a graph over the "
                     f"{e} bootstrap states (the script's --update-forward acting)"
                     if keep_graph else
                     f"{n} acting passes on {e} observations without a graph (actions "
                     f"`.cpu().numpy()`), one pass over the {n * e} decision states and the "
                     f"{e} bootstrap states (`Agent.evaluate`)")
                  + ", the losses (value × "
                  f"{defaults.vf_coef:g}, entropy × {defaults.ent_coef:g}) from random "
                  f"returns, backward, `clip_grad_norm_({defaults.max_grad_norm:g})`, "
                  f"RMSprop(lr={defaults.learning_rate:g}, alpha={defaults.rmsprop_alpha:g}, "
                  f"eps={defaults.rmsprop_eps:g}, foreach=True) step; {NET_BATCHES} random "
                  "input batches reused cyclically, no env; "
                  f"{warm} warm-up + {timed} timed rollouts; "
                  f"GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT', 'unset')} (the scripts' "
                  "OpenMP spin, `routine_gym.plumbing.openmp`; SB3 runs with libgomp's "
                  "default, as its users run it)"),
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


def is_minatar(env_id: str) -> bool:
    """MinAtar's games have their own acceptance (the network-only bound, no SB3 target)."""
    return env_id.startswith("MinAtar/")


def threads_of(r: Result) -> int | None:
    """The torch threads a result ran with (`2 (default)` → 2), None when unknown."""
    match = re.match(r"\d+", r.torch_threads)
    return int(match.group()) if match and int(match.group()) > 0 else None


def bound_for(results: list[Result], r: Result) -> Result | None:
    """The network-only bound with the same torch threads as `r` (best repeat)."""
    threads = threads_of(r)
    return best(results, f"net-t{threads}") if f"net-t{threads}" in CONFIGS else None


def render(results: list[Result], info: dict[str, str], command: str, demo_note: str,
           args) -> str:
    """The markdown report."""
    minatar = is_minatar(args.env_id)
    sb3_default, sb3_t1 = best(results, "sb3-default"), best(results, "sb3-t1")
    has_net = any(CONFIGS.get(r.config, Config("", None, 0)).kind == "net" for r in results)

    def ratio(r: Result, ref: Result | None) -> str:
        if ref is None or r.error or CONFIGS[r.config].kind == "net":
            return "–"
        value = r.sps / ref.sps
        mark = "" if (minatar or value >= TARGET_RATIO or CONFIGS[r.config].kind == "sb3") \
            else " (under)"
        return f"{value:.2f}×{mark}"

    def of_bound(r: Result) -> str:
        bound = bound_for(results, r)
        if bound is None or r.error or CONFIGS[r.config].kind == "net":
            return "–"
        return f"{r.sps / bound.sps:.2f}×"

    if minatar:
        target = (f"Acceptance on MinAtar: `--mode a2c` ≥ {MINATAR_MIN_SPS:,} SPS and ≥ "
                  f"{MINATAR_BOUND_RATIO}× the network-only bound with the same torch threads "
                  "measured in the same run, routines on (`--mode rapl`) at least as fast; "
                  "the ratios to SB3 are reported as measured, with no target.")
    else:
        target = (f"Target (SPEC §7): ours ≥ {TARGET_RATIO}× SB3 in SPS, routines on as fast "
                  "as plain A2C.")
    net_note = (" `net-t*`: the network-only bound, the script's per-rollout network work "
                "alone on random inputs (no env), timed inside its worker over whole rollouts; "
                "`÷ net bound`: SPS ÷ that bound with the same torch threads."
                if has_net else "")
    title = "# rapl_a2c.py vs Stable-Baselines3 A2C: agent steps per second"
    if has_net:
        title += ", and the network-only bound"
    bound_head, bound_sep = (" ÷ net bound |", "---|") if has_net else ("", "")
    lines = [
        title,
        "",
        "Produced by `bench/bench_a2c_speed.py`; the command, machine and load are below. "
        f"{args.num_envs} envs, {args.warmup:,} warm-up + {args.steps:,} measured agent steps "
        "per configuration, each in its own process; SPS = measured steps / wall time around "
        "them (external). `script SPS` is the script's own cumulative figure (warm-up "
        "included). `CPU s`: user + system CPU time of the process (all its threads) over the "
        "same steps; `steps per CPU s` is less sensitive to other jobs on a shared machine "
        f"than SPS, but charges a 2-thread run for its threads' spinning.{net_note} {target} "
        "The load average lags: just after an `--async-envs` run it still counts that run's "
        "env workers.",
        "",
        "| config | torch threads | repeat | load (1/5/15) before | steps timed | wall s | SPS "
        f"| script SPS | CPU s | steps per CPU s | routine use |{bound_head} "
        "÷ SB3 (default threads) | ÷ SB3 (1 thread) |",
        f"|---|---|---|---|---|---|---|---|---|---|---|{bound_sep}---|---|",
    ]
    empty = "|" + " |" * (9 if has_net else 8)
    for r in results:
        if r.error:
            lines.append(f"| {r.config} | {r.torch_threads} | {r.repeat} | {r.load_before} "
                         f"| failed: {r.error} {empty}")
            continue
        use = f"{r.routine_use:.1f} %" if r.routine_use is not None else "–"
        bound_cell = f" {of_bound(r)} |" if has_net else ""
        lines.append(
            f"| {r.config} | {r.torch_threads} | {r.repeat} | {r.load_before} "
            f"| {r.end_step - r.start_step:,} | {r.seconds:.1f} | **{r.sps:,.0f}** "
            f"| {r.script_sps if r.script_sps is not None else '–'} "
            f"| {_num(r.cpu_seconds, '.1f')} | {_num(r.cpu_sps, ',.0f')} | {use} |{bound_cell}"
            f" {ratio(r, sb3_default)} | {ratio(r, sb3_t1)} |"
        )
    lines += ["", "## Summary (best repeat of each configuration)", ""]
    for name, config in CONFIGS.items():
        net = best(results, name)
        if config.kind == "net" and net is not None:
            lines.append(f"- Network-only bound, {config.threads} torch "
                         f"thread{'s' if config.threads > 1 else ''} ({name}): "
                         f"{net.sps:,.0f} SPS (the script's network work alone, no env).")
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
        bound = bound_for(results, ours)
        if minatar:
            lines.extend(_minatar_summary(label, config, ours, bound, sb3_default, sb3_t1,
                                          _paired_ratios(results, name)))
            continue
        if sb3_default is None:
            lines.append(f"- {label}: {ours.sps:,.0f} SPS; SB3 not measured")
        else:
            value = ours.sps / sb3_default.sps
            verdict = "meets" if value >= TARGET_RATIO else "misses"
            lines.append(f"- {label}: {ours.sps:,.0f} SPS = {value:.2f}× SB3 with torch's "
                         f"default threads ({sb3_default.sps:,.0f}); {verdict} the "
                         f"{TARGET_RATIO}× target.")
            if sb3_t1 is not None:
                lines.append(f"  Against SB3 with 1 thread ({sb3_t1.sps:,.0f} SPS): "
                             f"{ours.sps / sb3_t1.sps:.2f}×.")
            if ours.cpu_sps and sb3_default.cpu_sps and sb3_t1 is not None and sb3_t1.cpu_sps:
                lines.append(f"  Per CPU second: {ours.cpu_sps:,.0f} steps, "
                             f"{ours.cpu_sps / sb3_default.cpu_sps:.2f}× SB3 default threads, "
                             f"{ours.cpu_sps / sb3_t1.cpu_sps:.2f}× SB3 1 thread.")
        if bound is not None:
            lines.append(f"  {ours.sps / bound.sps:.2f}× the network-only bound with the same "
                         f"threads ({bound.sps:,.0f}).")
    for variant in ("t1", "t2", "async-t1", "async-t2"):
        a2c, rapl = best(results, f"a2c-{variant}"), best(results, f"rapl-{variant}")
        if a2c is not None and rapl is not None:
            line = (f"- rapl / a2c ({variant}): {rapl.sps / a2c.sps:.2f}× in agent steps "
                    "(a routine of length ℓ counts ℓ steps)")
            if minatar:
                line += (f"; rapl at least as fast as a2c: "
                         f"{'yes' if rapl.sps >= a2c.sps else 'no'}")
            lines.append(line + ".")
    if minatar:
        for sb3 in (sb3_default, sb3_t1):
            if sb3 is None:
                continue
            bound = bound_for(results, sb3)
            line = (f"- SB3 A2C ({sb3.config}, torch threads: {sb3.torch_threads}): "
                    f"{sb3.sps:,.0f} SPS")
            if bound is not None:
                line += f" = {sb3.sps / bound.sps:.2f}× the network-only bound ({bound.sps:,.0f})"
            lines.append(line + ".")
    if default_threads == 0:
        lines.append("- The script's default `--torch-threads 0` is torch's own thread count "
                     f"({os.cpu_count()} here), i.e. the `-t{os.cpu_count()}` rows.")
    routines = next((r.extra.get("routines") for r in results if r.extra.get("routines")), None)
    lines += ["", "## Setup", "", f"- Command: `{command}`", f"- RAPL demo: {demo_note}"]
    if routines:
        lines.append("- Routines mined: " + "; ".join(f"`{x}`" for x in routines))
    setups: list[str] = []
    for r in results:
        setup = r.extra.get("setup")
        if setup and setup not in setups:
            setups.append(setup)
    lines += [f"- {setup}." for setup in setups]
    lines += ["- Commands per configuration (first repeat):"]
    seen: set[str] = set()
    for r in results:
        if r.config not in seen:
            seen.add(r.config)
            lines.append(f"  - {r.config}: `{r.command}`")
    lines += ["", "## Machine", ""]
    lines += [f"- {k}: {v}" for k, v in info.items()]
    return "\n".join(lines) + "\n"


def _paired_ratios(results: list[Result], name: str) -> list[float]:
    """Each repeat of configuration `name` ÷ the network-only bound (same threads) of the same
    repeat, measured minutes apart: on a machine whose speed drifts, a steadier figure than one
    configuration's best against another's (which can come from different minutes)."""
    threads = CONFIGS[name].threads
    ratios = []
    for ours in results:
        if ours.config != name or ours.error or not ours.sps:
            continue
        bound = next((r for r in results if r.config == f"net-t{threads}"
                      and r.repeat == ours.repeat and not r.error and r.sps), None)
        if bound is not None:
            ratios.append(ours.sps / bound.sps)
    return ratios


def _minatar_summary(label: str, config: Config, ours: Result, bound: Result | None,
                     sb3_default: Result | None, sb3_t1: Result | None,
                     paired: list[float]) -> list[str]:
    """One of our configurations on MinAtar: ÷ the bound, the acceptance (a2c), ÷ SB3."""
    if bound is None:
        head = f"- {label}: {ours.sps:,.0f} SPS; network-only bound not measured"
    else:
        head = (f"- {label}: {ours.sps:,.0f} SPS = {ours.sps / bound.sps:.2f}× the "
                f"network-only bound ({bound.sps:,.0f})")
    if config.mode == "a2c":
        fast = ours.sps >= MINATAR_MIN_SPS
        near = None if bound is None else ours.sps / bound.sps >= MINATAR_BOUND_RATIO
        outcome = ("misses" if not fast or near is False else
                   "meets" if near else "cannot be judged against")
        head += (f"; {outcome} the MinAtar acceptance (≥ {MINATAR_MIN_SPS:,} SPS: "
                 f"{'yes' if fast else 'no'}; ≥ {MINATAR_BOUND_RATIO}× the bound: "
                 f"{'not measured' if near is None else 'yes' if near else 'no'})")
    lines = [head + "."]
    if paired:
        lines.append("  Per repeat, ÷ the bound of the same repeat: "
                     + ", ".join(f"{r:.2f}×" for r in paired)
                     + f" (median {statistics.median(paired):.2f}×).")
    against = [f"{ours.sps / sb3.sps:.2f}× SB3 with {what} ({sb3.sps:,.0f})"
               for sb3, what in ((sb3_default, "torch's default threads"),
                                 (sb3_t1, "1 thread")) if sb3 is not None]
    lines.append("  As measured: " + ", ".join(against) + "." if against
                 else "  SB3 not measured.")
    if ours.cpu_sps:
        per_cpu = f"  Per CPU second: {ours.cpu_sps:,.0f} steps"
        if bound is not None and bound.cpu_sps:
            per_cpu += f", {ours.cpu_sps / bound.cpu_sps:.2f}× the bound's"
        lines.append(per_cpu + ".")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="ALE/Qbert-v5",
                        help="env of rapl_a2c.py and of the network-only bound; a MinAtar/ "
                             "env is SB3's too")
    parser.add_argument("--sb3-env-id", default="QbertNoFrameskip-v4",
                        help="Atari: env of SB3's make_atari_env (the RL Zoo uses "
                             "NoFrameskip-v4); unused with a MinAtar/ --env-id")
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
    parser.add_argument("--worker", choices=["sb3", "net"], help=argparse.SUPPRESS)
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
    if args.worker == "net":
        net_worker(args)
        return

    from routine_gym.atomic import atomic_write_text

    if args.from_json is not None:
        raw = json.loads(args.from_json.read_text())
        for name in ("warmup", "steps", "num_envs"):
            setattr(args, name, raw[name])
        # Older files lack `env_id`: it is in their command (else the default, Qbert).
        given = re.search(r"--env-id[ =](\S+)", raw["command"])
        args.env_id = raw.get("env_id") or (given.group(1) if given else "ALE/Qbert-v5")
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
                    result = run_worker(name, config, args, repeat)
                results.append(result)
                print(f"{name:12s} repeat {repeat}  load {result.load_before}  "
                      + (f"FAILED {result.error}" if result.error else
                         f"{result.sps:8,.0f} SPS over {result.end_step - result.start_step:,}"
                         f" steps in {result.seconds:.1f} s"), flush=True)
    info["load average at end"] = load_average()
    info["busiest processes at end"] = other_processes()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(args.out, render(results, info, command, demo_note, args))
    raw = {"command": command, "machine": info, "demo": demo_note, "env_id": args.env_id,
           "warmup": args.warmup, "steps": args.steps, "num_envs": args.num_envs,
           "results": [asdict(r) for r in results]}
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(raw, indent=2) + "\n")
    print(f"written to {args.out} and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
