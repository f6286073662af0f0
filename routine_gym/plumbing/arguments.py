"""The one argument check of every script in `algos/`, and the command line that feeds it.

`check_args(args)` checks every numeric flag with a domain (`DOMAINS`, by its field name, plus
a script's own `extra_checks(args)`), with Gymnasium-style messages that name the flag and the
bad value (`--gamma needs to be in (0, 1], actual value: 1.5`); a float that is not finite and
a rollout longer than the budget are refused whatever the flag. `parse_args` is tyro with
one-line errors, and remembers which flags the command line set (`--resume` needs to know).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
import weakref
from collections.abc import Callable, Iterable, Sequence
from dataclasses import fields
from typing import Any

from routine_gym.atomic import check_not_an_input
from routine_gym.errors import UsageError

__all__ = ["DOMAINS", "ExtraChecks", "check_args", "given_flags", "parse_args", "usable_cpus"]


# -- the argument check ------------------------------------------------------------------------

def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # macOS, Windows
        return os.cpu_count() or 1


def _between(low: int, high: int, why: str = "") -> tuple[Callable[[Any], bool],
                                                        Callable[[Any], str]]:
    """A domain `[low, high]`; the message names the bound the value is past."""
    return (lambda v: low <= v <= high, lambda v: f"≥ {low}" if v < low else f"≤ {high:,}{why}")


# Upper bounds of the flags that memory or threads follow from: a value past them is a typo or
# a misunderstanding, and would otherwise crash (torch's 100,000 threads: a segfault), hang
# (10^7 envs: 2 GB and counting) or die of a MemoryError after minutes. Each is far above
# any setting of the paper or of CleanRL; the memory the rollout or replay storage takes at
# the env's real observation size is checked again where it is allocated
# (`routine_gym.plumbing.memory.check_memory`).
#: torch's threads: more than the CPUs only make its workers wait for each other (1,000 on 2
#: CPUs turned an 8 s run into more than 120 s); 4x leaves room for a deliberate experiment.
MAX_TORCH_THREADS = 4 * usable_cpus()
#: Parallel envs: 16x the largest default (Procgen PPO's 64); each is a game in memory.
MAX_ENVS = 1024
#: Steps per env in a rollout (2^20; CleanRL's longest is 2,048).
MAX_ROLLOUT_STEPS = 1 << 20
#: A minibatch or replay batch, in transitions (2^20).
MAX_BATCH = 1 << 20
#: Replay memory, in transitions (100x SQIL's default of 10^5; Atari frames: 7 GB).
MAX_BUFFER = 10_000_000
#: Evaluation and demo episodes: every step of every episode is kept until the end (100x the
#: largest default, 100).
MAX_EPISODES = 10_000
#: Routines in a library (the agent's action space grows by each; the paper's K is 3 to 5).
MAX_ROUTINES = 1_000
#: A routine's length: the rollout storage keeps max-length steps of each decision.
MAX_ROUTINE_LENGTH = 1_024

#: Each numeric flag's domain, by `Args` field name: (test, what the message says it needs, or a
#: function of the value giving it). A
#: flag of one script alone has its rule in that script's module-level `extra_checks(args)`;
#: tests/test_args_domains.py checks that every numeric flag of every script has one or the
#: other, and that every flag memory or threads follow from has an upper bound.
_AT_LEAST_1 = (lambda v: v >= 1, "≥ 1")
_AT_LEAST_0 = (lambda v: v >= 0, "≥ 0")
_POSITIVE = (lambda v: v > 0, "> 0")
_UNIT = (lambda v: 0 < v <= 1, "in (0, 1]")
DOMAINS: dict[str, tuple[Callable[[Any], bool], str | Callable[[Any], str]]] = {
    "total_timesteps": _AT_LEAST_1,
    "gradient_steps": _AT_LEAST_1,
    "num_envs": _between(1, MAX_ENVS),
    "num_steps": _between(1, MAX_ROLLOUT_STEPS),
    "num_routines": _between(0, MAX_ROUTINES),
    "alpha": _AT_LEAST_1,
    "min_routine_length": _between(2, MAX_ROUTINE_LENGTH),
    "max_routine_length": _between(2, MAX_ROUTINE_LENGTH),
    "length_weight": _AT_LEAST_0,
    "gamma": _UNIT,
    "gae_lambda": (lambda v: 0 <= v <= 1, "in [0, 1]"),
    "learning_rate": _POSITIVE,
    "disc_learning_rate": _POSITIVE,
    "reward_scale": _POSITIVE,
    "ent_coef": _AT_LEAST_0,
    "vf_coef": _AT_LEAST_0,
    "prim_coef": _AT_LEAST_0,
    "intra_coef": _AT_LEAST_0,
    "max_grad_norm": _POSITIVE,
    "rmsprop_alpha": (lambda v: 0 <= v < 1, "in [0, 1)"),
    "rmsprop_eps": _POSITIVE,
    "temperature": _POSITIVE,
    "tau": _UNIT,
    "batch_size": _between(1, MAX_BATCH),
    "buffer_size": _between(8, MAX_BUFFER),
    "train_frequency": _AT_LEAST_1,
    "target_network_frequency": _AT_LEAST_1,
    "lambda_sample": _AT_LEAST_0,
    "learning_starts": _AT_LEAST_0,
    "num_minibatches": _between(1, MAX_BATCH),
    "update_epochs": _AT_LEAST_1,
    "prim_epochs": _AT_LEAST_1,
    "disc_minibatches": _between(1, MAX_BATCH),
    "disc_epochs": _AT_LEAST_1,
    "clip_coef": _POSITIVE,
    "eval_episodes": _between(0, MAX_EPISODES),
    "eval_max_steps": _AT_LEAST_1,
    "demo_episodes": _between(1, MAX_EPISODES),
    "checkpoint_every": _AT_LEAST_0,
    "log_every": _AT_LEAST_1,
    "scalars_every": _AT_LEAST_1,
    "torch_threads": _between(
        0, MAX_TORCH_THREADS, f" (4 × the {usable_cpus()} CPUs this process may use)"),
    "num_levels": _AT_LEAST_0,
    "start_level": _AT_LEAST_0,
    # Its other rules (the blocks of `plumbing.seeds`) depend on other flags: `stride_checks`.
    "seed_stride": _AT_LEAST_1,
    # NumPy's global seed (`np.random.seed`) takes no other; Gymnasium refuses negative ones.
    "seed": (lambda v: 0 <= v < 2**32, "in [0, 2**32 - 1]"),
}


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


#: Extra argument rules: a list of `(field, holds, what it needs)`, or a function of the
#: `Args` returning one (so a run's settings restored by `--resume` are checked too).
ExtraChecks = Iterable[tuple[str, bool, str]] | Callable[[Any], Iterable[tuple[str, bool, str]]]


def check_args(args: Any, extra: ExtraChecks = ()) -> None:
    """Refuse any numeric flag outside its domain (`DOMAINS`), before any work starts.

    A float flag that is not finite (`inf`, `nan`) is refused whatever its rule, and so is an
    empty text flag (`--record-demo ''` recorded nothing and exited 0, `--resume ''` started a
    new run: an empty name was taken as unset), and so is a `--record-demo` that is the run's
    `--demo`; a rollout (`--num-steps`) longer than the whole budget (`--total-timesteps`) is
    refused too.

    Args:
        args: a script's `Args`; every field named in `DOMAINS` is checked (None means unset
            and passes).
        extra: the script's own rules, as `(field, holds, what it needs)`, or a function of
            `args` returning them.

    Raises:
        UsageError: `--flag needs to be <domain>, actual value: <value>`.

    Example:
        >>> from dataclasses import dataclass
        >>> @dataclass
        ... class Args:
        ...     gamma: float = 1.5
        >>> check_args(Args())
        Traceback (most recent call last):
        ...
        routine_gym.errors.UsageError: --gamma needs to be in (0, 1], actual value: 1.5
    """
    for f in fields(args):
        if f.name not in DOMAINS:
            continue
        value = getattr(args, f.name)
        if value is None:
            continue
        test, needs = DOMAINS[f.name]
        bad_number = isinstance(value, float) and not math.isfinite(value)
        if bad_number or not test(value):
            if callable(needs):
                needs = needs(value)
            raise UsageError(f"{_flag(f.name)} needs to be {needs}, actual value: {value}")
    for f in fields(args):
        value = getattr(args, f.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise UsageError(f"{_flag(f.name)} needs to be a finite number, actual value: "
                             f"{value}")
        if isinstance(value, str) and not value.strip():
            raise UsageError(f"{_flag(f.name)} needs a value (a name, path or word), actual "
                             f"value: {value!r}")
    # The agent's demo recorded over the one it learned from would replace it.
    check_not_an_input(getattr(args, "record_demo", None), "--record-demo",
                       getattr(args, "demo", None))
    steps, budget = getattr(args, "num_steps", None), getattr(args, "total_timesteps", None)
    if isinstance(steps, int) and isinstance(budget, int) and steps > budget:
        raise UsageError(f"--num-steps needs to be ≤ --total-timesteps ({budget:,}), actual "
                         f"value: {steps:,}")
    for name, holds, needs in (extra(args) if callable(extra) else extra):
        if not holds:
            raise UsageError(f"{_flag(name)} needs to be {needs}, "
                             f"actual value: {getattr(args, name)}")


def parse_args(args_type: type, renamed: dict[str, str] | None = None,
               argv: Sequence[str] | None = None) -> Any:
    """`tyro.cli(args_type)`, after refusing flags that were renamed, naming the new one.

    tyro's own errors (an unknown flag, a value of the wrong type) come back as a `UsageError`
    of one line, the heart of tyro's message.
    """
    import tyro

    argv = list(sys.argv[1:] if argv is None else argv)
    names = [a[2:].split("=")[0].replace("-", "_") for a in argv if a.startswith("--")]
    for old, new in (renamed or {}).items():
        if any(a == old or a.startswith(old + "=") for a in argv):
            raise UsageError(f"{old} was renamed: use {new}")
    captured = io.StringIO()
    try:
        with contextlib.redirect_stderr(captured):
            parsed = tyro.cli(args_type, args=argv)
    except SystemExit as exc:
        if exc.code in (0, None):
            raise
        raise UsageError(_tyro_message(captured.getvalue()) + " (see --help)") from None
    # tyro's `--no-flag` sets the boolean `flag` (`--resume RUN --no-track` changes `track`).
    _GIVEN_FLAGS[id(parsed)] = (weakref.ref(parsed), frozenset(
        [*names, *(n[len("no_"):] for n in names if n.startswith("no_"))]))
    return parsed


#: id(Args) -> (the Args, the fields its command line set), for each `Args` `parse_args`
#: returned, so `--resume` can tell a flag given with its default value from one not given.
_GIVEN_FLAGS: dict[int, tuple[weakref.ref, frozenset[str]]] = {}


def _tyro_message(box: str) -> str:
    """The message lines of tyro's error box, up to its first rule, on one line."""
    lines = []
    for line in box.splitlines()[1:]:
        text = line.strip().strip("│╭╰╮╯").strip()
        if not text or set(text) <= set("─"):
            break
        lines.append(text)
    return " ".join(lines) or "bad arguments"


def given_flags(args: Any) -> set[str]:
    """The `Args` fields the command line set, for an `args` that `parse_args` returned; empty
    for one made in Python (`main(Args(...))`), whatever was parsed before in the process."""
    parsed, names = _GIVEN_FLAGS.get(id(args), (lambda: None, frozenset()))
    return set(names) if parsed() is args else set()
