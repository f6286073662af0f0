"""The demo and the routines of a run: the one way every script in `algos/` loads them.

- `load_demo(env_id, path)`: the demo given (a demo file, or a local Minari dataset as
  `minari:DATASET_ID`), or the one shipped in `demos/` for the env.
- `check_demo_env(demo, env_id)`: the demo's actions are the env's primitive actions.
- `load_routines(...)`: the K routines of a run, mined from a demo (any proposer of
  `routine_gym.mining`) or the best K of a saved library (`--routine-library`), checked
  against the env; fewer than K is a warning, none at all an error where routines are needed.
"""

from __future__ import annotations

import dataclasses
import re
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium as gym
from gymnasium import spaces

from routine_gym.demo import Demo, read_demo, shipped_demo_path
from routine_gym.demo.minari import minari_dataset_id
from routine_gym.envs import same_env
from routine_gym.envs.factory import make_primitive_env
from routine_gym.errors import UsageError
from routine_gym.library import RoutineLibrary
from routine_gym.mining import MAX_ROUTINE_LENGTH, make_proposer

__all__ = ["check_demo_env", "load_demo", "load_routines", "run_demo", "run_library",
           "unused_routine_flags"]

#: The `Args` fields that only mining a demo reads (a saved library's routines are taken whole).
MINING_FLAGS = ("proposer", "length_weight", "alpha", "min_routine_length",
                "max_routine_length", "selection")


def load_demo(env_id: str, path: str | None = None, purpose: str = "imitation") -> tuple[Demo, str]:
    """The demo of a run: `path`, or the demo shipped in `demos/` for `env_id`.

    Args:
        env_id: the env the run trains on; the demo must have been recorded on it.
        path: the demo file or `minari:DATASET_ID` (`--demo`), or None for the shipped one.
        purpose: what the demo is for, named in the error when there is none
            (`"imitation"`, `"--mode rapl"`, ...).

    Raises:
        UsageError: no path was given and no demo of `env_id` ships (saying how to make one),
            or the file (dataset) is not a demo, or a demo of another env, or minari is not
            installed for a `minari:` demo.
        FileNotFoundError: no file at `path`, or no such local Minari dataset.
    """
    path = path or shipped_demo_path(env_id)
    if path is None:
        raise UsageError(
            f"{purpose} needs a demo, and no demo of {env_id} ships in demos/: record one "
            f"(`routine-gym record {env_id} --policy random --episodes 10 --out demo.npz`, or "
            f"a trained expert's: `python algos/rapl_a2c.py --env-id {env_id} --mode a2c "
            f"--record-demo demo.npz`) and pass it with --demo"
        )
    try:
        return read_demo(path, env_id=env_id), path
    except FileNotFoundError as exc:
        if minari_dataset_id(path) is not None:  # the message says where it was looked for
            raise FileNotFoundError(f"--demo {exc}") from None
        raise FileNotFoundError(f"--demo {path}: no such demo file") from None
    except ValueError as exc:
        raise UsageError(str(exc)) from exc


def _env_action_meanings(env: gym.Env) -> list[str] | None:
    getter = getattr(env.unwrapped, "get_action_meanings", None)
    return [str(m) for m in getter()] if callable(getter) else None


def check_demo_env(demo: Demo, env_id: str, env_kwargs: dict[str, Any] | None = None) -> int:
    """Check that `demo` was recorded on the primitive env of `env_id`; its number of actions.

    The demo's actions must be the env's primitive actions: the same `Discrete(n)` and, when
    both name their actions, the same action meanings (a full-action-set Qbert demo does not fit
    the minimal-action-set env, though both are `ALE/Qbert-v5`).

    Raises:
        UsageError: naming the demo's and the env's action spaces or meanings.
    """
    if not same_env(demo.env_id, env_id):
        raise UsageError(f"the demo was recorded on {demo.env_id}, not {env_id}")
    env = make_primitive_env(env_id, **(env_kwargs if env_kwargs is not None else demo.env_kwargs))
    try:
        space = env.action_space
        meanings = _env_action_meanings(env)
    finally:
        env.close()
    if not isinstance(space, spaces.Discrete):
        raise UsageError(f"imitation needs a Discrete action space; {env_id} has {space}")
    n = int(space.n)
    if demo.num_actions != n:
        raise UsageError(
            f"the demo's action space Discrete({demo.num_actions}) does not match {env_id}'s "
            f"Discrete({n}): record the demo on the same env (same action set)"
        )
    demo_meanings = list(demo.action_meanings)
    numeric = [str(a) for a in range(n)]
    if meanings is not None and demo_meanings != numeric and demo_meanings != meanings:
        raise UsageError(
            f"the demo's actions {demo_meanings} are not {env_id}'s actions {meanings}"
        )
    return n


def _env_actions(env_id: str, env_kwargs: dict[str, Any] | None) -> tuple[int, list[str] | None]:
    env = make_primitive_env(env_id, **(env_kwargs or {}))
    try:
        space = env.action_space
        if not isinstance(space, spaces.Discrete):
            raise UsageError(f"routines need a Discrete action space; {env_id} has {space}")
        return int(space.n), _env_action_meanings(env)
    finally:
        env.close()


def _saved_library(library_path: str, env_id: str, num_routines: int, demo: Demo | None,
                   env_kwargs: dict[str, Any] | None) -> RoutineLibrary:
    """The best `num_routines` of the library saved at `library_path` (all it holds, with a
    warning, when it holds fewer), checked against `env_id`'s actions (`load_routines`)."""
    library = RoutineLibrary.load(library_path)
    mined_on = library.source.get("env_id")
    if not same_env(mined_on, env_id):
        raise UsageError(
            f"{library_path} was mined from a demo of {mined_on}, not {env_id}"
        )
    if demo is not None:
        n, meanings = demo.num_actions, list(demo.action_meanings)
    else:
        n, meanings = _env_actions(env_id, env_kwargs)
    if library.action_meanings is not None and meanings is not None and list(
        library.action_meanings
    ) != list(meanings):
        raise UsageError(
            f"{library_path} has actions {list(library.action_meanings)}, "
            f"{env_id} has {list(meanings)}: a library of another env"
        )
    bad = [r for r in library.routines if max(r) >= n]
    if bad:
        raise UsageError(
            f"{library_path}: routine {bad[0]} uses an action outside {env_id}'s "
            f"Discrete({n})"
        )
    if len(library) < num_routines:
        warnings.warn(
            f"{library_path} holds {len(library)} routine(s), fewer than the "
            f"{num_routines} asked for; using {len(library)}",
            stacklevel=3,  # load_routines's caller
        )
    k = min(num_routines, len(library))
    return RoutineLibrary(
        routines=library.routines[:k],
        scores=library.scores[:k],
        frequencies=library.frequencies[:k],
        occurrences=library.occurrences[:k],
        params=library.params,
        source={**library.source, "path": library_path},
        action_meanings=library.action_meanings,
    )


def load_routines(
    env_id: str,
    num_routines: int,
    *,
    demo: Demo | None = None,
    library_path: str | None = None,
    proposer: str = "full",
    length_weight: float = 0.1,
    alpha: int = 2,
    seed: int = 0,
    min_length: int = 2,
    max_length: int | None = MAX_ROUTINE_LENGTH,
    selection: str = "paper",
    source: dict[str, Any] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    required: str | None = None,
) -> RoutineLibrary | None:
    """The K routines of a run: mined from `demo`, or the best K of the library at `library_path`.

    K larger than what the miner finds (or the saved library holds) is not an error: the run
    uses every routine there is, with a warning. `num_routines=0` gives None (no routines).

    Args:
        env_id: the env the routines act in.
        num_routines: K.
        demo: the demo to mine (not needed with `library_path`).
        library_path: a saved `RoutineLibrary` JSON to take the best K of, instead of mining.
        proposer, length_weight, alpha, seed, min_length, max_length: the miner
            (`routine_gym.mining.make_proposer`); the scripts' `--min-routine-length` and
            `--max-routine-length`.
        selection: `"paper"` or `"authors"`, the selection phase of the full miner
            (`routine_gym.mining.SequiturMiner`; SPEC §5b) and of `bpe`; the ablations take only
            `"paper"`.
        source: provenance the mined library records (the demo's path).
        env_kwargs: `gym.make` keyword arguments of the env a saved library is checked against.
        required: when set (`"--mode rapl"`), finding no routine is an error naming it.

    Raises:
        UsageError: `num_routines` is negative, or the saved library was mined on another env
            or holds actions the env does not have.
        UsageError: `required` and no routine was found.
        UsageError: a bad miner setting (`min_length` above `max_length`), naming the flag.
    """
    if num_routines < 0:
        raise UsageError(f"--num-routines needs to be ≥ 0, actual value: {num_routines}")
    if num_routines == 0:
        return None
    if library_path is not None:
        library = _saved_library(library_path, env_id, num_routines, demo, env_kwargs)
        where = library_path
    else:
        if demo is None:
            raise ValueError("load_routines needs a demo to mine or a library_path")
        try:
            miner = make_proposer(proposer, num_routines, length_weight, alpha, seed=seed,
                                  min_length=min_length, max_length=max_length,
                                  selection=selection)
        except ValueError as err:
            message = str(err).replace("min_length", "--min-routine-length")
            message = re.sub(r"\bselection\b", "--selection", message)
            raise UsageError(message.replace("max_length", "--max-routine-length")) from None
        with warnings.catch_warnings():
            # The miner's own "only k routines survive" warning is re-issued below.
            warnings.simplefilter("ignore")
            library = miner.mine(demo, source=source)
        if 0 < len(library) < num_routines:
            warnings.warn(
                f"the demo yields {len(library)} routine(s) after scoring and pruning, fewer "
                f"than --num-routines {num_routines}; using {len(library)}",
                stacklevel=2,
            )
        where = (source or {}).get("path", "the demo")
    if len(library) == 0:
        if required is not None:
            if min_length > 2:
                raise UsageError(
                    f"{required} found no routine of ≥ {min_length} actions in {where}; use a "
                    "smaller --min-routine-length or a longer demo"
                )
            raise UsageError(
                f"{required} found no routine in {where} (the demo may be too short or too "
                "varied); use a longer demo, a smaller --alpha, or no routines "
                "(rapl_a2c.py --mode a2c, rapl_sqil.py --num-routines 0)"
            )
        warnings.warn(f"{where} yields no routine; the run uses the primitive actions only",
                      stacklevel=2)
        return None
    return library


def mechanism_rules(args: Any, plain: str) -> list[tuple[str, bool, str]]:
    """The rules (as a script's `extra_checks` gives them) of the routine mechanisms beyond the
    paper that `rapl_a2c.py` and `rapl_ppo.py` share: `--intra-coef` for RAPL only,
    `--routine-logit` and `--interrupt` never with the mode without routines (`plain`: a2c or
    ppo), `--interrupt` a margin ≥ 0 and not with `--async-envs`."""
    return [("intra_coef", args.mode == "rapl" or args.intra_coef == 0.0, "0 unless --mode rapl "
             "(only RAPL records the states inside routines)"),
            ("routine_logit", args.mode != plain or args.routine_logit == "free",
             f"free with --mode {plain} (it has no routines)"),
            ("interrupt", args.interrupt is None or args.interrupt >= 0, "≥ 0 (a margin in nats)"),
            ("interrupt", args.interrupt is None or args.mode != plain,
             f"unset with --mode {plain} (it has no routines to interrupt)"),
            ("interrupt", args.interrupt is None or not args.async_envs,
             "unset with --async-envs (the routines would run in subprocesses, away from the "
             "policy that stops them)")]


def unused_routine_flags(args: Any, no_routines: str | None, demo_only_mined: bool = True
                         ) -> list[tuple[str, bool, str]]:
    """The rules (as a script's `extra_checks` gives them) that refuse a routine flag the run
    would ignore: set away from its default where nothing reads it.

    - A run without routines (`no_routines` says why: `"--mode a2c"`) reads none of
      `--routine-library`, `--num-routines` and the mining flags (`MINING_FLAGS`), nor `--demo`
      when the script reads the demo only to mine it (`demo_only_mined`).
    - A run given `--routine-library` mines nothing: the mining flags, and `--demo` when it is
      only mined, go unread.

    Example:
        >>> from dataclasses import dataclass
        >>> @dataclass
        ... class Args:
        ...     demo: str | None = None
        ...     routine_library: str | None = None
        ...     num_routines: int = 3
        ...     alpha: int = 2
        >>> unused_routine_flags(Args(alpha=1), "--mode a2c")[-1]
        ('alpha', False, '2 with --mode a2c, which uses no routines')
    """
    defaults = {f.name: f.default for f in dataclasses.fields(args)}
    if no_routines is not None:
        cause = f"{no_routines}, which uses no routines"
        unread = ["routine_library", *MINING_FLAGS]
        if not no_routines.startswith("--num-routines"):
            unread.append("num_routines")
        if demo_only_mined:
            unread.append("demo")
    elif getattr(args, "routine_library", None) is not None:
        cause = "--routine-library, whose routines are not mined from a demo"
        unread = [*MINING_FLAGS, *(["demo"] if demo_only_mined else [])]
    else:
        return []
    rules = []
    for name in sorted(set(unread) & defaults.keys(), key=list(defaults).index):
        default = defaults[name]
        wanted = "left out" if default is None else f"{default}"
        rules.append((name, getattr(args, name) == default, f"{wanted} with {cause}"))
    return rules


def run_library(args: Any, checkpoint: dict[str, Any] | None, folder: str, demo: Any = None,
                *, meanings: Callable[[], Any] | None = None,
                env_kwargs: dict[str, Any] | None = None, required: str | None = None) -> Any:
    """A run's routine library, set up in one call: the resumed `checkpoint`'s, else the best
    K of `--routine-library`, else mined from `demo` with the run's miner flags
    (`--num-routines`, `--proposer`, `--length-weight`, `--alpha`, `--seed`,
    `--min-routine-length`, `--max-routine-length`, `--selection`). A library is printed with
    action names (`meanings()`, called only then) and saved as `folder/routines.json`.

    Args:
        args: the script's `Args`.
        checkpoint: the resumed checkpoint, or None for a new run.
        folder: the run's folder.
        demo: the demo to mine (None with `--routine-library`).
        meanings: the action names, asked for only when there is a library to print.
        env_kwargs: the env a saved library is checked against (`load_routines`).
        required: finding no routine is an error naming it (`"--mode rapl"`).

    Returns:
        The `RoutineLibrary`, or None (K = 0, or nothing mined and not required).
    """
    import json
    import os

    if checkpoint is not None and checkpoint["library"]:
        library = RoutineLibrary.from_dict(json.loads(checkpoint["library"]))
    else:
        library = load_routines(
            args.env_id, args.num_routines, demo=demo, library_path=args.routine_library,
            proposer=args.proposer, length_weight=args.length_weight, alpha=args.alpha,
            seed=args.seed, min_length=getattr(args, "min_routine_length", 2),
            source={"path": args.demo}, max_length=args.max_routine_length,
            env_kwargs=env_kwargs, required=required,
            **({"selection": args.selection}
               if getattr(args, "selection", "paper") != "paper" else {}),
        )
    if library is not None:
        print(library.describe(meanings() if meanings is not None else None))
        library.save(os.path.join(folder, "routines.json"))
    return library


def run_demo(args: Any, *, resumed: bool, purpose: str) -> Any:
    """The demo a run's routines are mined from and its evaluation aligns with (None with
    `--routine-library`): `--demo`, else the env's shipped one, loaded on a new run and on
    `--resume` alike, so that a resumed run's `eval.json` keeps its alignment and demo score.
    On `--resume` a demo gone since is a warning, not an error: the run goes on (its routines
    are the checkpoint's) and is evaluated without alignment.

    Args:
        args: the script's `Args` (`args.demo` is set to the path loaded).
        resumed: whether the run is resumed.
        purpose: what needs the demo, for a missing one's message (`"--mode rapl"`).
    """
    import sys

    if args.routine_library is not None:
        return None
    try:
        demo, args.demo = load_demo(args.env_id, args.demo, purpose=purpose)
    except (UsageError, FileNotFoundError) as exc:
        if not resumed:
            raise
        from routine_gym.errors import one_line

        print(f"warning: {one_line(exc)}; the evaluation has no alignment",
              file=sys.stderr, flush=True)
        return None
    return demo
