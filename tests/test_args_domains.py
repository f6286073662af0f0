"""Every numeric flag of every script has its domain checked before any work.

A flag's domain is a rule in `routine_gym.plumbing.arguments.DOMAINS` (shared by the scripts),
a rule of the script's module-level `extra_checks(args)` (its own flags), or a line of
`ANY_VALUE` saying why any value is legitimate. A new int or float field of an `Args` with
none of the three fails `test_every_numeric_flag_has_a_domain`, naming its script and flag.
"""

from __future__ import annotations

import ast
import dataclasses
import os
import types
import typing

import pytest
from script_loader import ALGOS, load_script

from routine_gym.errors import UsageError
from routine_gym.plumbing.arguments import (
    DOMAINS,
    MAX_TORCH_THREADS,
    _flag,
    check_args,
    usable_cpus,
)

NAMES = sorted(path.stem for path in ALGOS.glob("*.py"))
SCRIPTS = {name: load_script(name, f"domains_{name}") for name in NAMES}

#: Numeric flags where any value is legitimate, with why. None today: even `--seed` has a domain
#: (NumPy's global seed takes only [0, 2**32 - 1]).
ANY_VALUE: dict[str, str] = {}

_TIME = "time follows from it, not memory nor threads (a loop's length)"
_SCALAR = "a coefficient or rate: no memory nor thread follows (a value that breaks training "
_SCALAR += "is stopped by routine_gym.plumbing.divergence)"
#: Numeric flags from which neither memory nor threads follow, with why. Every other numeric
#: flag needs an upper bound (`test_every_memory_or_thread_flag_has_an_upper_bound`), so a new
#: flag is either bounded or named here.
NO_MEMORY_OR_THREADS: dict[str, str] = {
    **dict.fromkeys(["total_timesteps", "gradient_steps", "update_epochs", "prim_epochs",
                     "disc_epochs", "compile_iterations", "compile_option_steps",
                     "learning_starts"], _TIME),
    **dict.fromkeys(["log_every", "scalars_every", "checkpoint_every", "train_frequency",
                     "target_network_frequency"], "how often something is done"),
    "eval_max_steps": "a cap on an episode's steps: the memory follows the episode's real length",
    "alpha": "the miner's minimum count of a routine: a larger one finds fewer",
    "seed": "bounded anyway ([0, 2**32 - 1])",
    "seed_stride": "seed arithmetic (each experiment seed's block of env seeds)",
    "num_levels": "Procgen's level seeds: numbers, not levels held in memory",
    "start_level": "Procgen's first level seed",
    **dict.fromkeys(["learning_rate", "disc_learning_rate", "compile_learning_rate",
                     "reward_scale", "ent_coef", "vf_coef", "prim_coef", "max_grad_norm",
                     "rmsprop_alpha", "rmsprop_eps", "temperature", "tau", "lambda_sample",
                     "clip_coef", "gamma", "gae_lambda", "length_weight", "target_kl",
                     "compile_prior_rate", "deliberation_cost", "option_epsilon", "term_coef",
                     "interrupt", "intra_coef"],
                    _SCALAR),
}


def numeric_fields(args_type: type) -> list[str]:
    """The `Args` fields whose type is int or float, alone or in a union (`int | None`)."""
    hints = typing.get_type_hints(args_type)
    names = []
    for field in dataclasses.fields(args_type):
        hint = hints[field.name]
        union = isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union
        if any(t in (int, float) for t in (typing.get_args(hint) if union else (hint,))):
            names.append(field.name)
    return names


def own_checked_fields(module: types.ModuleType) -> set[str]:
    """The fields the script's `extra_checks` rules, read from a call on the default `Args`."""
    checks = getattr(module, "extra_checks", None)
    return {name for name, _, _ in checks(module.Args())} if checks else set()


def test_numeric_fields_sees_ints_floats_and_optional_ones():
    @dataclasses.dataclass
    class Args:
        a: int = 1
        b: float = 1.0
        c: int | None = None
        d: bool = True
        e: str = "x"

    assert numeric_fields(Args) == ["a", "b", "c"]


@pytest.mark.parametrize("script", NAMES)
def test_every_numeric_flag_has_a_domain(script):
    module = SCRIPTS[script]
    covered = set(DOMAINS) | own_checked_fields(module) | set(ANY_VALUE)
    missing = [name for name in numeric_fields(module.Args) if name not in covered]
    assert missing == [], (f"{script}.py: no domain for {missing}: add one to "
                           "routine_gym.plumbing.arguments.DOMAINS, to the script's "
                           "extra_checks, or to ANY_VALUE with why")


@pytest.mark.parametrize("script", NAMES)
def test_the_script_passes_its_own_checks_as_extra_checks(script):
    # One shape, so the rules are found above: a module-level `extra_checks`, handed to
    # start_run by that name (not a lambda, which a test could not read).
    tree = ast.parse((ALGOS / f"{script}.py").read_text())
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)
             and getattr(node.func, "id", None) == "start_run"]
    assert len(calls) == 1
    given = [kw.value for kw in calls[0].keywords if kw.arg == "extra_checks"]
    if hasattr(SCRIPTS[script], "extra_checks"):
        assert len(given) == 1 and isinstance(given[0], ast.Name)
        assert given[0].id == "extra_checks"
    else:
        assert given == []


@pytest.mark.parametrize("script", NAMES)
def test_the_defaults_pass_every_check(script):
    module = SCRIPTS[script]
    args = module.Args()
    for name in numeric_fields(module.Args):
        value = getattr(args, name)
        if name in DOMAINS and value is not None:
            test, needs = DOMAINS[name]
            assert test(value), f"{script}.py: default --{name} {value} is not {needs}"
    for name, holds, needs in (module.extra_checks(args)
                               if hasattr(module, "extra_checks") else []):
        assert holds, f"{script}.py: default --{name} is not {needs}"


@pytest.mark.parametrize(("script", "setting", "message"), [
    *[(script, {"seed": -1}, "--seed needs to be in [0, 2**32 - 1], actual value: -1")
      for script in NAMES],
    ("rapl_a2c", {"seed": 2**32},
     "--seed needs to be in [0, 2**32 - 1], actual value: 4294967296"),
    ("option_critic", {"deliberation_cost": -0.01},
     "--deliberation-cost needs to be ≥ 0, actual value: -0.01"),
])
def test_a_value_outside_its_domain_is_refused_by_name(script, setting, message, tmp_path):
    module = SCRIPTS[script]
    with pytest.raises(UsageError) as refused:
        module.main(module.Args(env_id="MiniQbert-v0", run_dir=str(tmp_path), **setting))
    assert message in str(refused.value)
    assert os.listdir(tmp_path) == []  # refused before a run folder was made


@pytest.mark.parametrize("script", NAMES)
def test_every_memory_or_thread_flag_has_an_upper_bound(script):
    # Issue 46: --torch-threads 100000 segfaulted, --num-envs 10^7 hung at 2 GB, --num-steps
    # 10^11 died of a MemoryError. A flag memory or threads follow from refuses a huge value
    # before any work, even with the budget raised as far as it goes.
    module = SCRIPTS[script]
    unbounded = []
    for name in numeric_fields(module.Args):
        if name in NO_MEMORY_OR_THREADS:
            continue
        args = module.Args()
        for budget in ("total_timesteps", "gradient_steps"):
            if hasattr(args, budget):
                setattr(args, budget, 10**18)
        setattr(args, name, 10**15)
        try:
            check_args(args, getattr(module, "extra_checks", ()))
        except UsageError as exc:
            if _flag(name) in str(exc):
                continue
        unbounded.append(name)
    assert unbounded == [], (f"{script}.py: no upper bound for {unbounded}: memory or threads "
                             "follow from them; bound them in DOMAINS or the script's "
                             "extra_checks, or name them in NO_MEMORY_OR_THREADS with why")


def test_torch_threads_is_bounded_by_four_times_the_usable_cpus():
    assert MAX_TORCH_THREADS == 4 * usable_cpus()
    args = SCRIPTS["rapl_a2c"].Args(torch_threads=MAX_TORCH_THREADS)
    check_args(args)
    args.torch_threads = MAX_TORCH_THREADS + 1
    with pytest.raises(UsageError, match=rf"--torch-threads needs to be ≤ {MAX_TORCH_THREADS:,} "
                                         rf"\(4 × the {usable_cpus()} CPUs"):
        check_args(args)
