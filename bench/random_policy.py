"""The uniformly random policy's score on every env of the shipped demo suite, for scale.

    python bench/random_policy.py                  # 10 full episodes per env, seeds 0..9
    python bench/random_policy.py --episodes 30

Each episode is a full game in the primitive env the demos are recorded in
(`make_primitive_env`: Atari with frame skip 4 and sticky actions as `-v5` defines; CoinRun on
the training levels 0-99, easy). `demos/README.md` puts these beside each expert's score.
Writes `bench/results/random_policy.json` and `.md`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from common import base_machine_info, load_average

import routine_gym
from routine_gym.demo import DEMO_SUITE
from routine_gym.plumbing.atomic import atomic_write_text
from routine_gym.plumbing.evaluation import random_policy_scores

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10, help="episodes per env (10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (0)")
    parser.add_argument("--env-id", action="append", default=None,
                        help="only this env (repeatable; default: the demo suite and MiniQbert)")
    args = parser.parse_args()
    routine_gym.register_envs()
    env_ids = args.env_id or [*DEMO_SUITE, "MiniQbert-v0"]

    rows = []
    for env_id in env_ids:
        start = time.perf_counter()
        row = random_policy_scores(env_id, args.episodes, args.seed)
        row["seconds"] = time.perf_counter() - start
        rows.append(row)
        print(f"{env_id:24s} random policy {row['mean']:9.1f} ± {row['std']:7.1f} "
              f"(mean length {row['mean_length']:.0f}, {row['seconds']:.0f} s)", flush=True)

    machine = {**base_machine_info(), "load_average": load_average()}
    RESULTS.mkdir(exist_ok=True)
    atomic_write_text(RESULTS / "random_policy.json",
                      json.dumps({"machine": machine, "rows": rows}, indent=2))
    lines = [
        "# Random-policy scores",
        "",
        f"`python bench/random_policy.py --episodes {args.episodes} --seed {args.seed}`, "
        f"{machine['date']}. Uniformly random actions, full episodes, seeds "
        f"{args.seed}–{args.seed + args.episodes - 1}.",
        "",
        "| env | random policy score (mean ± std) | mean episode length |",
        "|---|---|---|",
    ]
    for row in rows:
        lines.append(f"| `{row['env_id']}` | {row['mean']:.1f} ± {row['std']:.1f} | "
                     f"{row['mean_length']:.0f} |")
    atomic_write_text(RESULTS / "random_policy.md", "\n".join(lines) + "\n")
    print(f"wrote {RESULTS / 'random_policy.md'}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
