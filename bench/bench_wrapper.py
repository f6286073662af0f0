"""Benchmark: `RoutineActionWrapper`'s overhead per primitive step against Gymnasium's
`RepeatAction` and the bare env (SPEC §7: no larger than one of Gymnasium's own light wrappers).

Every variant runs the same primitive actions (action 0 throughout) on its own instance of the
same env, reset with the same seed, so the envs go through the same states and resets:

- ``bare``: `env.step(0)`, one primitive step per call;
- ``RecordEpisodeStatistics``, ``TimeLimit``: two more light Gymnasium wrappers, for scale;
- ``RepeatAction``: `RepeatAction(env, num_repeats=L).step(0)`, L primitive steps per call;
- ``routine``: `RoutineActionWrapper(env, [[0] * L]).step(n)`, the routine, L primitive steps
  per call, with `record_observations` False and True;
- ``primitive``: the same wrapper's `step(0)`, one primitive step per call, with
  `record_observations` False and True;
- ``python``: on the constant env, the routine variants again with the wrapper's Python `step`
  (what runs where the compiled core, `routine_gym/_wrapper_core.cpp`, is not built), as the
  peer of the compiled step the other variants run.

Time per primitive step = loop time / primitive steps executed (the env's `step` is counted,
so routines and repeats cut short by the end of an episode are counted right; resets happen
in the loop at the same points for every variant). Overhead = wrapped − bare per primitive
step; ratio = the wrapper's overhead / `RepeatAction`'s at the same L (one-step calls: against
`RepeatAction(env, 1)`). Targets (issue 27): ratio ≤ 1.5 with observations off, ≤ 3 with
them on. Timing uses `time.perf_counter_ns` with the
garbage collector off; each figure is the best of many short measurements, the variants
measured in turn within each repeat, so a burst of load on the machine hits all of them
alike and the best is one taken in a quiet moment. Every variant's env is reset with seed 0
once, then runs action 0 on (resetting at the end of each episode), so all variants go through
the same states in the same order.

Envs (`--envs`): ``constant``, a tiny env whose step returns constants, so the wrapper's own
cost is all there is to see; ``cartpole``, `gym.make("CartPole-v1")`; ``qbert``,
`gym.make("ALE/Qbert-v5")` (L in {1, 10} only), where the overhead's share of a real step
shows. The ratio to RepeatAction is judged on the constant env; on the real envs the overhead is
a difference of two noisy times, so it is reported as a share of a step (the constant env's
overhead over the real env's step), with the directly measured difference beside it.

Usage:
    python bench/bench_wrapper.py
    python bench/bench_wrapper.py --steps 20000 --repeats 15 --out bench/results/wrapper.md
"""

from __future__ import annotations

import argparse
import gc
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ale_py
import gymnasium as gym
import numpy as np
from common import base_machine_info, load_average
from gymnasium import spaces
from gymnasium.wrappers import RecordEpisodeStatistics, RepeatAction, TimeLimit

import routine_gym
import routine_gym.wrapper
from routine_gym.plumbing.atomic import atomic_write_text
from routine_gym.wrapper import RoutineActionWrapper

REPO = Path(__file__).resolve().parents[1]
#: The targets of issue 27: the wrapper's overhead over RepeatAction's, with observations off
#: and on (SPEC §9: no larger than one of Gymnasium's own light wrappers).
TARGET_RATIO, TARGET_RATIO_OBS = 1.5, 3.0
ENVS = ("constant", "cartpole", "qbert")
#: Routine lengths L per env; Qbert's step is ~1000x the constant env's, so fewer variants.
ENV_LENGTHS = {"constant": (1, 3, 5, 10), "cartpole": (1, 3, 5, 10), "qbert": (1, 10)}


class ConstantEnv(gym.Env):
    """An env whose step costs almost nothing: constant observation and reward, never ends.

    It counts its steps itself (`steps`), which every variant pays alike.
    """

    def __init__(self) -> None:
        self.action_space = spaces.Discrete(4)
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._obs = np.zeros(4, dtype=np.float32)
        self.steps = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Return the constant observation."""
        super().reset(seed=seed)
        return self._obs, {}

    def step(self, action: int):
        """Return the constant observation, reward 1, never terminated or truncated."""
        self.steps += 1
        return self._obs, 1.0, False, False, {}


def make_env(name: str) -> tuple[gym.Env, Callable[[], int]]:
    """A fresh env `name`, and a function giving how many primitive steps it has executed."""
    if name == "constant":
        env = ConstantEnv()
        return env, lambda: env.steps
    env = gym.make({"cartpole": "CartPole-v1", "qbert": "ALE/Qbert-v5"}[name])
    # Count on the innermost env: an instance attribute shadows the method for the wrappers
    # above it; the extra call costs every variant the same.
    base = env.unwrapped
    inner_step = base.step
    counter = [0]

    def counting_step(action):
        counter[0] += 1
        return inner_step(action)

    base.step = counting_step
    return env, lambda: counter[0]


def python_step_wrapper(env: gym.Env, routines: list[list[int]],
                        record: bool) -> RoutineActionWrapper:
    """A wrapper that runs its Python `step`, as it does without the compiled core."""
    compiled = routine_gym.wrapper._Stepper
    routine_gym.wrapper._Stepper = None
    try:
        return RoutineActionWrapper(env, routines, record_observations=record)
    finally:
        routine_gym.wrapper._Stepper = compiled


@dataclass
class Variant:
    """One way to step the env: a (wrapped) env, the action it is given, steps per call."""

    label: str
    length: int  # L: 1 for bare and primitive
    env: gym.Env
    action: int
    steps_per_call: int
    executed: Callable[[], int]
    best_ns: float = float("inf")


def make_variants(name: str, lengths: tuple[int, ...]) -> list[Variant]:
    """Every variant of the module docstring for env `name`, each on its own env."""
    variants = []
    env, executed = make_env(name)
    variants.append(Variant("bare", 1, env, 0, 1, executed))
    # Two more of Gymnasium's light wrappers, for scale (SPEC §7 names no particular one).
    env, executed = make_env(name)
    variants.append(Variant("RecordEpisodeStatistics", 1, RecordEpisodeStatistics(env), 0, 1,
                            executed))
    env, executed = make_env(name)
    variants.append(Variant("TimeLimit", 1, TimeLimit(env, 10**9), 0, 1, executed))
    for length in lengths:
        env, executed = make_env(name)
        variants.append(Variant("RepeatAction", length, RepeatAction(env, length), 0, length,
                                executed))
        for record in (False, True):
            env, executed = make_env(name)
            wrapped = RoutineActionWrapper(env, [[0] * length], record_observations=record)
            n = wrapped.num_primitive_actions
            variants.append(Variant(f"routine obs={'on' if record else 'off'}", length, wrapped,
                                    n, length, executed))
        if name == "constant":
            for record in (False, True):
                env, executed = make_env(name)
                wrapped = python_step_wrapper(env, [[0] * length], record)
                variants.append(Variant(f"python obs={'on' if record else 'off'}", length,
                                        wrapped, wrapped.num_primitive_actions, length,
                                        executed))
    for record in (False, True):
        env, executed = make_env(name)
        # Routines of the longest length, so the info arrays have their largest size.
        wrapped = RoutineActionWrapper(env, [[0] * max(lengths)], record_observations=record)
        variants.append(Variant(f"primitive obs={'on' if record else 'off'}", 1, wrapped, 0, 1,
                                executed))
    return variants


def time_per_step(variant: Variant, primitive_steps: int) -> float:
    """Nanoseconds per executed primitive step over about `primitive_steps` of them."""
    env, action = variant.env, variant.action
    step, reset = env.step, env.reset
    calls = max(primitive_steps // variant.steps_per_call, 1)
    before = variant.executed()
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter_ns()
        for _ in range(calls):
            _, _, terminated, truncated, _ = step(action)
            if terminated or truncated:
                reset()
        elapsed = time.perf_counter_ns() - start
    finally:
        gc.enable()
    return elapsed / (variant.executed() - before)


def measure(name: str, lengths: tuple[int, ...], primitive_steps: int,
            repeats: int) -> tuple[list[Variant], str]:
    """Best time per primitive step of every variant of env `name`, and the load it ran under."""
    variants = make_variants(name, lengths)
    # Seeded once: a seeded ALE reset reloads the game (~0.1-0.5 s). Each variant then runs
    # action 0 on, and ends episodes at the same points, so all go through the same states.
    for variant in variants:
        variant.env.reset(seed=0)
    load_before = load_average()
    for _ in range(repeats):
        for variant in variants:
            variant.best_ns = min(variant.best_ns, time_per_step(variant, primitive_steps))
    for variant in variants:
        variant.env.close()
    return variants, f"{load_before} → {load_average()}"


class Results:
    """The best times of one env's variants, and the derived overheads."""

    def __init__(self, name: str, variants: list[Variant], lengths: tuple[int, ...],
                 steps: int, load: str) -> None:
        self.name, self.lengths, self.steps, self.load = name, lengths, steps, load
        self.ns = {(v.label, v.length): v.best_ns for v in variants}
        self.bare = self.ns[("bare", 1)]

    def overhead(self, label: str, length: int = 1) -> float:
        """Wrapped − bare nanoseconds per primitive step."""
        return self.ns[(label, length)] - self.bare

    def render(self, reference: Results | None) -> list[str]:
        """Times per step, then overheads: with ratios on the trivial env (`reference` None),
        as a share of this env's step elsewhere, `reference`'s overheads included."""
        ns, bare = self.ns, self.bare
        lines = [
            f"### {self.name}",
            "",
            f"{self.steps:,} primitive steps per measurement; load (1/5/15 min) {self.load}.",
            "",
            "Time per primitive step (ns):",
            "",
            "| L | bare | RepeatAction | routine obs=off | routine obs=on |",
            "|---:|---:|---:|---:|---:|",
        ]
        for length in self.lengths:
            lines.append(
                f"| {length} | {bare:,.0f} | {ns[('RepeatAction', length)]:,.0f} "
                f"| {ns[('routine obs=off', length)]:,.0f} "
                f"| {ns[('routine obs=on', length)]:,.0f} |"
            )
        longest = max(self.lengths)
        lines += [
            "",
            f"Primitive action through the wrapper (a routine of length {longest} present): "
            f"obs=off {ns[('primitive obs=off', 1)]:,.0f} ns, obs=on "
            f"{ns[('primitive obs=on', 1)]:,.0f} ns per step (bare {bare:,.0f} ns). Overhead of "
            "Gymnasium's light wrappers, one step per call: "
            f"RepeatAction(1) {self.overhead('RepeatAction'):,.0f} ns, RecordEpisodeStatistics "
            f"{self.overhead('RecordEpisodeStatistics'):,.0f} ns, TimeLimit "
            f"{self.overhead('TimeLimit'):,.0f} ns.",
            "",
        ]
        return lines + (self._ratios() if reference is None else self._shares(reference))

    def _ratios(self) -> list[str]:
        lines = [
            "Overhead per primitive step (ns) and ratio to RepeatAction's overhead "
            f"(targets: ≤ {TARGET_RATIO} obs=off, ≤ {TARGET_RATIO_OBS} obs=on):",
            "",
            "| call | L | RepeatAction overhead | wrapper overhead obs=off | ratio "
            "| wrapper overhead obs=on | ratio |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        rows = [("routine", length, length) for length in self.lengths]
        for call, length, reference_length in [*rows, ("primitive", 1, 1)]:
            reference = self.overhead("RepeatAction", reference_length)
            off = self.overhead(f"{call} obs=off", length)
            on = self.overhead(f"{call} obs=on", length)
            lines.append(
                f"| {call} | {length} | {reference:,.0f} | {off:,.0f} "
                f"| {_ratio(off, reference, TARGET_RATIO)} | {on:,.0f} "
                f"| {_ratio(on, reference, TARGET_RATIO_OBS)} |"
            )
        if ("python obs=off", self.lengths[0]) not in self.ns:
            return lines + [""]
        lines += [
            "",
            "The wrapper's Python `step` in the same run (what runs without the compiled core; "
            "the routine rows above are the compiled step):",
            "",
            "| call | L | RepeatAction overhead | Python step overhead obs=off | ratio "
            "| Python step overhead obs=on | ratio |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        for length in self.lengths:
            reference = self.overhead("RepeatAction", length)
            off = self.overhead("python obs=off", length)
            on = self.overhead("python obs=on", length)
            lines.append(
                f"| routine | {length} | {reference:,.0f} | {off:,.0f} "
                f"| {_ratio(off, reference, TARGET_RATIO)} | {on:,.0f} "
                f"| {_ratio(on, reference, TARGET_RATIO_OBS)} |"
            )
        return lines + [""]

    def _shares(self, reference: Results) -> list[str]:
        lines = [
            "Overhead as a share of this env's step. The wrapper's own cost does not depend on "
            f"the env, so the precise figure is the one measured on `{reference.name}`; the "
            "overheads measured here directly are differences of two noisy times (a few % of "
            "a step), shown for the observation copies, which do depend on the env.",
            "",
            f"| call | L | overhead obs=off on {reference.name} (ns) | share of a step "
            "| measured here obs=off (ns) | measured here obs=on (ns) | share obs=on |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        rows = [("routine", length) for length in self.lengths if length in reference.lengths]
        for call, length in [*rows, ("primitive", 1)]:
            clean = reference.overhead(f"{call} obs=off", length)
            off = self.overhead(f"{call} obs=off", length)
            on = self.overhead(f"{call} obs=on", length)
            lines.append(
                f"| {call} | {length} | {clean:,.0f} | {clean / self.bare:.2%} | {off:,.0f} "
                f"| {on:,.0f} | {on / self.bare:.2%} |"
            )
        return lines + [""]


def _ratio(value: float, reference: float, target: float) -> str:
    """`value / reference` marked against `target` (n/a when the reference is not > 0)."""
    if reference <= 0:
        return "n/a"
    ratio = value / reference
    return f"{ratio:.2f}" if ratio <= target else f"**{ratio:.2f}** (over)"


def machine_info() -> dict[str, str]:
    """The machine, versions and date: what a reader needs to compare the figures."""
    return {
        **base_machine_info(),
        "gymnasium": gym.__version__,
        "ale-py": ale_py.__version__,
        "routine_gym": getattr(routine_gym, "__version__", "editable checkout"),
        "wrapper step": ("compiled (routine_gym._wrapper_core)"
                         if routine_gym.wrapper._Stepper is not None
                         else "Python (the compiled core is not built)"),
    }


def main(argv: list[str] | None = None) -> None:
    """Parse the flags, measure every env, print and write the markdown tables."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", nargs="+", choices=ENVS, default=list(ENVS),
                        help="envs to measure (see the module docstring)")
    parser.add_argument("--steps", type=int, default=20_000,
                        help="primitive steps per measurement on the constant env")
    parser.add_argument("--cartpole-steps", type=int, default=2_000,
                        help="primitive steps per measurement on CartPole-v1")
    parser.add_argument("--atari-steps", type=int, default=200,
                        help="primitive steps per measurement on ALE/Qbert-v5")
    parser.add_argument("--repeats", type=int, default=15,
                        help="measurements per variant (the best is kept)")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "wrapper.md",
                        help="markdown file to write")
    args = parser.parse_args(argv)
    steps = {"constant": args.steps, "cartpole": args.cartpole_steps, "qbert": args.atari_steps}
    if min(steps.values()) < 10 or args.repeats < 1:
        parser.error(f"steps must be ≥ 10 and repeats ≥ 1, got {steps}, "
                     f"{args.repeats}")

    command = shlex.join(sys.orig_argv)
    info = machine_info()
    info["load average at start"] = load_average()
    print(f"# {command}\n# load average at start: {info['load average at start']}", flush=True)
    sections = []
    reference = None
    # The trivial env first: its overheads are the reference the real envs are compared with.
    for name in sorted(args.envs, key=ENVS.index):
        lengths = ENV_LENGTHS[name]
        variants, load = measure(name, lengths, steps[name], args.repeats)
        for v in variants:
            print(f"{name:>8} {v.label:<24} L={v.length:<2} {v.best_ns:11,.0f} ns/step",
                  flush=True)
        results = Results(name, variants, lengths, steps[name], load)
        sections += results.render(reference)
        if name == "constant":
            reference = results
    info["load average at end"] = load_average()
    text = "\n".join([
        "# Wrapper overhead benchmark",
        "",
        "Produced by `bench/bench_wrapper.py`; the command, machine and load are below.",
        "",
        f"Command: `{command}`",
        "",
        *[f"- {k}: {v}" for k, v in info.items()],
        "",
        f"Best of {args.repeats} measurements per variant, garbage collector off while timing. "
        "Overhead = wrapped − bare time per primitive step; ratio = RoutineActionWrapper's "
        f"overhead / RepeatAction's at the same L (targets ≤ {TARGET_RATIO} with observations "
        f"off, ≤ {TARGET_RATIO_OBS} with them on).",
        "",
        *sections,
    ])
    print(text)
    atomic_write_text(args.out, text)
    print(f"written to {args.out}")


if __name__ == "__main__":
    from common import children_die_with_me  # no orphan workers after a SIGTERM

    children_die_with_me()
    main()
