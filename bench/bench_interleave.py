"""Do MinAtar's vector env and the A2C network slow each other down when they take turns?

`bench_a2c_speed.py` finds `rapl_a2c.py --mode a2c` on MinAtar spending more time in the network
than its network-only bound spends on the same work, and more in the env than the env takes
alone. This benchmark isolates that: in one process, with one torch thread, it times
`rapl_a2c.py`'s own `Agent.act` on 16 MinAtar observations (the acting pass) again and again,
with something else run between two passes, and times that something too:

- `nothing`: the acting pass alone, back to back (what the bound measures);
- `env`: one step of the vector env of the training script (`make_vector_env`, 16 games);
- `memory sweep`: a write to every 64th byte of a 4 MiB array (every cache line of the core's
  caches evicted; as long as the env step or longer);
- `python loop`: `sum(range(3000))`, a tight Python loop about half as long as the env step;
- `game states`: 30 calls of the game's own `state()`, MinAtar's numpy work alone;
- `env alone`: the env step back to back, no acting pass (its own speed).

Each is measured `--repeats` times in turn; the table gives the best per kind. Usage:

    python bench/bench_interleave.py --out bench/results/interleave_minatar.md
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import common
import numpy as np
from bench_a2c_speed import load_script_module

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env-id", default="MinAtar/Breakout-v1")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--passes", type=int, default=3000, help="acting passes per measurement")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=None, help="markdown report (and .json beside it)")
    args = parser.parse_args()
    if args.passes < 1 or args.repeats < 1:
        parser.error("--passes and --repeats need to be at least 1")

    import torch

    import routine_gym
    from routine_gym.envs.factory import make_vector_env
    from routine_gym.plumbing.run import seed_and_tune

    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    seed_and_tune(1, 1)  # what the script sets: seeds, one torch thread, freed memory kept
    script = load_script_module()  # the `Agent` the script trains

    envs = make_vector_env(args.env_id, args.num_envs, 1, training=True)
    obs, _ = envs.reset(seed=1)
    agent = script.Agent(args.env_id, envs.single_observation_space,
                         int(envs.single_action_space.n))
    actions = np.random.default_rng(0).integers(0, int(envs.single_action_space.n),
                                                size=(args.passes, args.num_envs))
    sweep = np.zeros(4 * 2**20, dtype=np.uint8)
    game = envs._games[0].env if hasattr(envs, "_games") else None

    def env_step(k: int) -> None:
        envs.step(actions[k])

    def memory_sweep(k: int) -> None:
        sweep[::64] += 1

    def python_loop(k: int) -> None:
        sum(range(3000))

    def game_states(k: int) -> None:
        for _ in range(30):
            game.state()

    kinds = {"nothing": None, "env": env_step, "memory sweep": memory_sweep,
             "python loop": python_loop}
    if game is not None:
        kinds["game states"] = game_states

    def measure(between) -> tuple[float, float]:
        """µs per acting pass and per `between` call, over `--passes` of each in turn."""
        x = torch.as_tensor(obs)
        acting = other = 0.0
        with torch.inference_mode():
            for k in range(args.passes):
                t0 = time.perf_counter()
                agent.act(x).numpy()
                t1 = time.perf_counter()
                if between is not None:
                    between(k)
                t2 = time.perf_counter()
                acting, other = acting + t1 - t0, other + t2 - t1
        return acting / args.passes * 1e6, other / args.passes * 1e6

    def env_alone() -> float:
        t0 = time.perf_counter()
        for k in range(args.passes):
            envs.step(actions[k])
        return (time.perf_counter() - t0) / args.passes * 1e6

    load_before = common.load_average()
    best: dict[str, list[float]] = {}  # per kind: the best acting pass and work between
    alone_best = float("inf")  # the env step back to back
    measure(None)  # warm-up
    for repeat in range(args.repeats):
        for name, between in kinds.items():
            act_us, other_us = measure(between)
            print(f"repeat {repeat + 1}  {name:13s} acting pass {act_us:7.1f} µs  "
                  f"between {other_us:7.1f} µs", flush=True)
            old = best.get(name, [float("inf"), float("inf")])
            best[name] = [min(old[0], act_us), min(old[1], other_us)]
        alone = env_alone()
        print(f"repeat {repeat + 1}  env alone     step {alone:7.1f} µs", flush=True)
        alone_best = min(alone_best, alone)
    envs.close()

    # (kind, acting pass or None, the work between): `env alone` has no acting pass.
    rows = [(name, a, b) for name, (a, b) in best.items()] + [("env alone", None, alone_best)]
    alone_act = best["nothing"][0]
    lines = [
        "# Do MinAtar's env and the A2C network slow each other down?",
        "",
        "Produced by `bench/bench_interleave.py`; the command, machine and load are below. "
        f"One process, one torch thread: `rapl_a2c.py`'s `Agent.act` on {args.num_envs} "
        f"{args.env_id} observations, {args.passes} passes per measurement, with the named "
        "work between two passes; best of "
        f"{args.repeats} repeats per kind. `env alone`: the vector env's step back to back.",
        "",
        "| between two acting passes | acting pass (µs) | vs nothing | the work between (µs) |",
        "|---|---:|---:|---:|",
    ]
    for name, a, b in rows:
        if name == "env alone":
            lines.append(f"| (env alone, no acting) | – | – | {b:.1f} |")
        else:
            between_cell = "–" if name == "nothing" else f"{b:.1f}"
            lines.append(f"| {name} | {a:.1f} | {a / alone_act:.2f}× | {between_cell} |")
    slowdown_act = best["env"][0] - alone_act
    slowdown_env = best["env"][1] - alone_best
    lines += [
        "",
        f"Taking turns, the acting pass is {slowdown_act:.1f} µs slower than alone and the env "
        f"step {slowdown_env:.1f} µs slower than alone: {slowdown_act + slowdown_env:.1f} µs per "
        f"vector step, {(slowdown_act + slowdown_env) / args.num_envs:.2f} µs per agent step.",
        "",
        "## Setup",
        "",
        f"- Command: `python bench/bench_interleave.py {' '.join(sys.argv[1:])}`",
        f"- load average before: {load_before}; after: {common.load_average()}",
    ]
    info = {**common.base_machine_info(), "torch": torch.__version__,
            "thread and memory env vars": common.tuning_env_vars(),
            "git HEAD": common.git_head(ROOT, ["algos", "routine_gym", "bench"])}
    lines += ["", "## Machine", ""] + [f"- {k}: {v}" for k, v in info.items()]
    report = "\n".join(lines) + "\n"
    print(report)
    if args.out:
        out = Path(args.out)
        out.write_text(report)
        out.with_suffix(".json").write_text(json.dumps(
            {"rows": [{"between": n, "acting_us": a, "between_us": b} for n, a, b in rows],
             "machine": info, "args": vars(args)}, indent=2) + "\n")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
