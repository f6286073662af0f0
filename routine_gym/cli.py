"""The `routine-gym` command line: mine, show, picture, replay, upgrade, export, play and record.

    routine-gym mine demos/MiniQbert-v0.npz --num-routines 3 --out routines.json
    routine-gym show routines.json
    routine-gym picture demos/MiniQbert-v0.npz --out miniqbert.png
    routine-gym picture runs/MinAtar-Breakout-v1__rapl_a2c-rapl__1__1764860000 --out usage.png
    routine-gym replay demos/MiniQbert-v0.npz
    routine-gym upgrade old_demo.npz --out new_demo.npz
    routine-gym export demos/MinAtar-Breakout-v1.npz --minari routine-gym/breakout-expert-v0
    routine-gym mine minari:routine-gym/breakout-expert-v0
    routine-gym show-demos
    routine-gym record MiniQbert-v0 --policy expert --episodes 10 --out my_demo.npz
    routine-gym play ALE/Qbert-v5 --out my_qbert.npz

Run `routine-gym COMMAND --help` for the options of each command.
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.atomic import check_not_an_input
from routine_gym.library import RoutineLibrary, routine_name


class CLIError(Exception):
    """A user error: printed as `routine-gym: error: ...` with exit code 2, no traceback."""


def _needs(flag: str, value: Any, holds: bool, what: str) -> None:
    """Refuse a flag's value outside its domain, as the scripts do: `--fps needs to be ≥ 1,
    actual value: 0`."""
    if isinstance(value, float) and not math.isfinite(value):
        holds, what = False, "a finite number" if holds else what
    if not holds:
        raise CLIError(f"{flag} needs to be {what}, actual value: {value}")


def _load_demo(path: str):
    """A demo file, or a local Minari dataset named `minari:DATASET_ID`."""
    from routine_gym.demo import read_demo
    from routine_gym.demo.minari import minari_dataset_id

    if minari_dataset_id(path) is None and not Path(path).is_file():
        raise CLIError(f"no demo file at {path}")
    return read_demo(path)


def cmd_mine(args: argparse.Namespace) -> int:
    from routine_gym.atomic import check_writable
    from routine_gym.mining import SELECTIONS, make_proposer

    _needs("--num-routines", args.num_routines, args.num_routines >= 1, "≥ 1")
    _needs("--length-weight", args.length_weight, args.length_weight >= 0, "≥ 0")
    _needs("--alpha", args.alpha, args.alpha >= 1, "≥ 1")
    _needs("--seed", args.seed, args.seed >= 0, "≥ 0")
    _needs("--max-routine-length", args.max_routine_length, args.max_routine_length >= 2, "≥ 2")
    _needs("--selection", args.selection, args.selection in SELECTIONS, " or ".join(SELECTIONS))
    if args.out is not None:  # `--out ""` is refused, not taken as no --out
        check_not_an_input(args.out, "--out", args.demo)
        check_writable(args.out, "--out", ".json")
    demo = _load_demo(args.demo)
    proposer = make_proposer(
        args.proposer,
        num_routines=args.num_routines,
        length_weight=args.length_weight,
        alpha=args.alpha,
        seed=args.seed,
        prune_primitives=not args.keep_near_primitives,
        max_length=args.max_routine_length,
        selection=args.selection,
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        library = proposer.mine(demo, source={"path": str(args.demo)})
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    meta = demo.meta
    print(
        f"demo: {args.demo} ({meta.get('env_id', '?')}, {demo.num_episodes} episode(s), "
        f"{len(demo.actions)} actions, score {demo.score:g})"
    )
    print(library.describe())
    if args.out is not None:
        library.save(args.out)
        print(f"saved to {args.out}")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    from routine_gym.demo.minari import minari_dataset_id

    _needs("--head", args.head, args.head >= 0, "≥ 0")
    path = Path(args.path)
    is_file = minari_dataset_id(args.path) is None
    if is_file and not path.is_file():
        raise CLIError(f"no file at {path}")
    if is_file and path.suffix == ".json":
        library = RoutineLibrary.load(path)
        print(library.describe())
        if library.source:
            print("source: " + ", ".join(f"{k}={v}" for k, v in library.source.items()
                                         if k != "scores"))
        return 0
    demo = _load_demo(args.path)
    meta = demo.meta
    print(f"demo: {args.path}")
    for key in ("env_id", "env_kwargs", "source", "created", "seeds", "scores"):
        if key in meta:
            print(f"  {key}: {meta[key]}")
    print(f"  episodes: {demo.num_episodes}, actions: {len(demo.actions)}, "
          f"observations: {'yes' if demo.observations is not None else 'no'}")
    print(f"  steps: {demo.num_decisions} decided by the demonstrator, {demo.num_injected} "
          f"injected by wrappers"
          + (f" ({', '.join(meta['recorded_under'])})" if meta.get("recorded_under") else ""))
    if is_file and _file_version(path) == 1:
        print(f"  format version 1 (no decisions recorded: every step counts as one); "
              f"`routine-gym upgrade {path}` marks the injected steps")
    meanings = meta.get("action_meanings")
    if meanings:
        counts = np.bincount(demo.actions[demo.decisions], minlength=len(meanings))
        usage = ", ".join(f"{m}={c}" for m, c in zip(meanings, counts, strict=True) if c)
        print(f"  decided action counts: {usage}")
        head = demo.decision_actions()[0][: args.head]
        print(f"  first decided actions: {routine_name(head.tolist(), meanings)}")
    return 0


def _file_version(path: Path) -> int:
    from routine_gym.demo import demo_file_version

    return demo_file_version(path)


def cmd_upgrade(args: argparse.Namespace) -> int:
    from routine_gym.atomic import check_writable
    from routine_gym.demo import DEMO_VERSION, DemoReplayError, upgrade_demo
    from routine_gym.demo.minari import minari_dataset_id
    from routine_gym.envs.factory import recording_stacks

    if minari_dataset_id(args.demo) is not None:
        raise CLIError(f"upgrade rewrites a version-1 demo file; {args.demo} is a Minari "
                       "dataset, not a file")
    # In place by default: only a verified replay replaces it. `--out ""` is refused, not
    # taken as no --out.
    out = args.demo if args.out is None else args.out
    check_writable(out, "--out", None if args.out is None else ".npz")  # in place: its name
    demo = _load_demo(args.demo)
    version = _file_version(Path(args.demo))
    if version >= DEMO_VERSION:
        print(f"{args.demo} is already format version {version}; nothing to upgrade")
        return 0
    if demo.env_id is None:
        raise CLIError(f"{args.demo} has no env id, so it cannot be replayed to upgrade it")
    stacks = recording_stacks(demo.env_id)
    if args.preprocessing != "auto":
        if args.preprocessing not in stacks:
            raise CLIError(f"--preprocessing {args.preprocessing} does not apply to "
                           f"{demo.env_id}; choose from {', '.join(stacks)}")
        stacks = {args.preprocessing: stacks[args.preprocessing]}
    failures = []
    for name, wrap in stacks.items():
        try:
            upgraded = upgrade_demo(demo, None if name == "raw" else wrap)
        except DemoReplayError as exc:
            failures.append(f"{name}: {exc}")
            continue
        upgraded.meta["upgraded_from_version"] = version
        upgraded.meta["recorded_under_stack"] = name
        upgraded.save(out, include_observations=demo.has_observations)
        print(f"{args.demo}: recorded under the '{name}' preprocessing; "
              f"{upgraded.num_decisions} decided and {upgraded.num_injected} injected steps; "
              f"saved as version {DEMO_VERSION} to {out}")
        return 0
    raise CLIError(f"{args.demo} replays under none of the preprocessing stacks, so its injected "
                   "steps cannot be re-derived; nothing written: " + " | ".join(failures))


def cmd_export(args: argparse.Namespace) -> int:
    from routine_gym.demo import export_minari

    demo = _load_demo(args.demo)
    target = export_minari(demo, args.minari, source=args.demo)
    observations = "recorded" if demo.has_observations else "replayed from the seeds"
    print(f"exported {args.demo} ({demo.env_id}, {demo.num_episodes} episode(s), {len(demo)} "
          f"steps: {demo.num_decisions} decided, {demo.num_injected} injected; observations "
          f"{observations}) as the Minari dataset {args.minari} at {target}")
    print(f"use it as a demo: routine-gym mine minari:{args.minari}")
    return 0


def cmd_show_demos(args: argparse.Namespace) -> int:
    from routine_gym.demo import DEMO_SETS, DEMO_SUITE, DEMOS_DIR, demo_filename

    _needs("--num-routines", args.num_routines, args.num_routines >= 1, "≥ 1")
    folder = Path(args.dir) if args.dir else Path(DEMOS_DIR)
    if not folder.is_dir():
        raise CLIError(f"no demo folder at {folder}")
    files = sorted(folder.glob("*.npz"))
    shipped = {path.name for path in files}
    missing = [env_id for env_id in DEMO_SUITE if demo_filename(env_id) not in shipped]
    label = "" if args.dir else " (demo set `current`: what every script reads by default)"
    print(f"{len(files)} demo(s) in {folder}{label}")
    _show_demo_files(files, args.num_routines)
    for env_id in missing:
        print(f"\n{env_id}: no demo in {folder} (expected {demo_filename(env_id)})")
    if not args.dir:  # the sets the current demos replaced, kept for the runs made with them
        for name, sub in DEMO_SETS.items():
            older = sorted((folder / sub).glob("*.npz")) if sub else []
            if older:
                print(f"\n{len(older)} demo(s) of the older demo set `{name}` in {folder / sub} "
                      f"(experiments at a budget with this set read them: --demo "
                      f"{folder / sub / older[0].name} names one)")
                _show_demo_files(older, args.num_routines)
    return 0


def _show_demo_files(files: list[Path], num_routines: int) -> None:
    """Each demo file's env, score, steps, source and its mined routines."""
    from routine_gym.demo import Demo
    from routine_gym.mining import SequiturMiner

    miner = SequiturMiner(num_routines=num_routines)
    for path in files:
        demo = Demo.load(path)
        meta = demo.meta
        trained = meta.get("trained_steps")
        source = f"{meta.get('source', 'agent')} demo"
        if trained:
            source += f" from an agent ({meta.get('mode', 'a2c')}) trained {trained:,} steps"
        if "candidates" in meta:
            source += f", best of {len(meta['candidates']['seeds'])} episodes"
        print(f"\n{demo.env_id}  ({path.name}, {path.stat().st_size / 1024:.1f} kB)")
        print(f"  score {demo.score:g}, {len(demo.actions)} steps ({demo.num_decisions} "
              f"decided, {demo.num_injected} injected), {demo.num_episodes} episode(s); {source}")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            library = miner.mine(demo)
        for k in range(len(library)):
            print(f"  routine {k}: {library.name(k)}  (f = {library.frequencies[k]})")
        for w in caught:
            print(f"  note: {w.message}")


def cmd_picture(args: argparse.Namespace) -> int:
    from routine_gym import pictures
    from routine_gym.atomic import check_writable
    from routine_gym.demo.minari import minari_dataset_id
    from routine_gym.mining import SequiturMiner

    _needs("--num-routines", args.num_routines, args.num_routines >= 1, "≥ 1")
    _needs("--max-routines", args.max_routines, 1 <= args.max_routines <= 1000,
           "in [1, 1000]")
    check_not_an_input(args.out, "--out", args.source)
    check_writable(args.out, "--out", ".png")
    if minari_dataset_id(args.source) is None and Path(args.source).is_dir():
        if args.routines is not None:
            raise CLIError(f"--routines names a demo's routines; {args.source} is a run folder, "
                           "whose routines are its own routines.json")
        usage = pictures.routine_usage(args.source)
        pictures.save_png(pictures.draw_routine_usage(usage), args.out)
        shares = ", ".join(f"{name} {share:.1%}" for name, share in zip(
            ("primitives", *usage.names), usage.overall, strict=True) if share is not None)
        print(f"wrote {args.out}: routine usage of {usage.run} over {usage.primitive_steps:,} "
              f"agent steps ({usage.decisions:,} decisions: {shares})")
        return 0
    demo = _load_demo(args.source)
    if args.routines is not None:
        check_not_an_input(args.out, "--out", args.routines)
        library = RoutineLibrary.load(args.routines)
    else:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            library = SequiturMiner(num_routines=args.num_routines).mine(demo)
        for w in caught:
            print(f"warning: {w.message}", file=sys.stderr)
    total = len(library)
    library = pictures.top_routines(library, args.max_routines) if total else library
    picture = pictures.routine_picture(demo, library, source=args.source)
    pictures.save_png(pictures.draw_routine_picture(picture), args.out)
    frames = ("the demo's observations" if picture.replayed_steps == 0 else
              f"{picture.replayed_steps} replayed steps")
    print(f"wrote {args.out}: {len(picture.films)} routine(s) of {picture.env_id} "
          f"({args.source}), frames from {frames}")
    print(pictures.describe_picture(picture))
    if len(library) < total:
        print(f"drew {len(library)} of {total} routines (the best by score); --max-routines "
              "to change")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from routine_gym.demo import DemoReplayError, replay

    if args.episode is not None:
        _needs("--episode", args.episode, args.episode >= 0, "≥ 0")
    demo = _load_demo(args.demo)
    try:
        result = replay(demo, episode=args.episode, check=True)
    except DemoReplayError as exc:
        print(f"replay FAILED: {exc}", file=sys.stderr)
        return 1
    except IndexError as exc:  # --episode out of range
        raise CLIError(str(exc)) from exc
    for i, (score, length) in enumerate(zip(result.scores, result.lengths, strict=True)):
        print(f"episode {i}: score {score:g}, length {length}: matches the recording")
    return 0


def _resolve_policy(spec: str, env, noise: float = 0.0, seed: int = 0) -> Callable[[Any], int]:
    """`random`, `expert` (MiniQbert's scripted expert) or `module:function`."""
    if spec == "random":
        space = env.action_space
        space.seed(seed)  # the same --seed records the same demo
        return lambda obs: int(space.sample())
    if spec == "expert":
        from routine_gym.envs import profile_for

        expert = profile_for(env.spec.id).scripted_expert(env, noise, np.random.default_rng(seed))
        if expert is None:
            raise CLIError("--policy expert is an env's scripted expert (MiniQbert's "
                           f"scripted expert, say); {env.spec.id if env.spec else env} has none")
        return expert
    if ":" not in spec:
        raise CLIError(f"unknown policy {spec!r}: use random, expert or module:function")
    module_name, _, attr = spec.partition(":")
    if os.getcwd() not in sys.path and "" not in sys.path:
        # A module of the user's own, beside them, as `python -m` would find it (the
        # `routine-gym` launcher puts only its own folder on the path).
        sys.path.insert(0, os.getcwd())
    try:
        policy = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise CLIError(f"cannot import policy {spec!r}: {exc}") from exc
    if not callable(policy):
        raise CLIError(f"policy {spec!r} is not callable")
    return policy


def cmd_record(args: argparse.Namespace) -> int:
    from routine_gym.atomic import check_writable
    from routine_gym.envs import make_env

    _needs("--episodes", args.episodes, args.episodes >= 1, "≥ 1")
    _needs("--seed", args.seed, args.seed >= 0, "≥ 0")
    if args.max_steps is not None:
        _needs("--max-steps", args.max_steps, args.max_steps >= 1, "≥ 1")
    _needs("--expert-noise", args.expert_noise, 0 <= args.expert_noise <= 1, "in [0, 1]")
    if args.expert_noise and args.policy != "expert":
        raise CLIError(f"--expert-noise is the scripted expert's noise; --policy {args.policy} "
                       "takes none (use --policy expert, or drop --expert-noise)")
    check_writable(args.out, "--out", ".npz")  # before recording: no run for an output that fails
    from routine_gym.demo import record_agent_demo
    from routine_gym.envs.factory import default_env_kwargs

    env_kwargs = {**default_env_kwargs(args.env_id), **_parse_kwargs(args.env_kwarg)}
    probe = make_env(args.env_id, **env_kwargs)
    policy = _resolve_policy(args.policy, probe, args.expert_noise, args.seed)
    probe.close()
    demo = record_agent_demo(
        args.env_id,
        policy,
        num_episodes=args.episodes,
        seed=args.seed,
        env_kwargs=env_kwargs,
        keep=args.keep,
        max_steps=args.max_steps,
        record_observations=args.observations,
    )
    demo.save(args.out, include_observations=args.observations)
    print(f"saved {demo.num_episodes} episode(s), {len(demo.actions)} actions, "
          f"score {demo.score:g} to {args.out}")
    return 0


def cmd_play(args: argparse.Namespace) -> int:
    from routine_gym.atomic import check_writable
    from routine_gym.demo import record_human_demo

    _needs("--episodes", args.episodes, args.episodes >= 1, "≥ 1")
    _needs("--seed", args.seed, args.seed >= 0, "≥ 0")
    if args.fps is not None:
        _needs("--fps", args.fps, args.fps >= 1, "≥ 1")
    if args.zoom is not None:
        _needs("--zoom", args.zoom, args.zoom > 0, "> 0")
    check_writable(args.out, "--out", ".npz")  # before anyone plays a session for nothing
    if not _has_display():
        raise CLIError("play needs a display to show the game and read the keyboard, and none "
                       "is set (DISPLAY or WAYLAND_DISPLAY); record an agent with "
                       "`routine-gym record` instead")
    try:
        demo = record_human_demo(
            args.env_id,
            seed=args.seed,
            fps=args.fps,
            zoom=args.zoom,
            env_kwargs=_parse_kwargs(args.env_kwarg),
            num_episodes=args.episodes,
        )
    except RuntimeError as exc:  # nothing played, or pygame (its error is a RuntimeError)
        raise CLIError(f"no demo recorded: {exc}") from exc
    if len(demo.actions) == 0:
        raise CLIError("no complete episode was played; nothing saved")
    demo.save(args.out, include_observations=args.observations)
    print(f"saved {demo.num_episodes} episode(s), {len(demo.actions)} actions, "
          f"score {demo.score:g} to {args.out}")
    return 0


def _has_display() -> bool:
    """Whether pygame can open a window: always off Linux; on Linux an X or Wayland display,
    or an SDL video driver chosen by hand (`SDL_VIDEODRIVER`, e.g. `dummy` in tests)."""
    if not sys.platform.startswith("linux"):
        return True
    return any(os.environ.get(name) for name in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER"))


def _parse_kwargs(pairs: Sequence[str] | None) -> dict[str, Any]:
    """`["max_episode_steps=500", "size=5"]` → `{"max_episode_steps": 500, "size": 5}`."""
    import json

    out: dict[str, Any] = {}
    for pair in pairs or ():
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise CLIError(f"--env-kwarg takes KEY=VALUE, got {pair!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    """The `routine-gym` command line (`routine_gym.cli_parser`), each command bound to the
    `cmd_*` function that runs it."""
    from routine_gym.cli_experiment import (
        cmd_experiment_list,
        cmd_experiment_report,
        cmd_experiment_run,
    )
    from routine_gym.cli_parser import build_parsers

    parser, commands = build_parsers()
    handlers = {
        "mine": cmd_mine, "show": cmd_show, "show-demos": cmd_show_demos,
        "picture": cmd_picture, "replay": cmd_replay,
        "upgrade": cmd_upgrade, "export": cmd_export, "record": cmd_record, "play": cmd_play,
        "experiment list": cmd_experiment_list, "experiment run": cmd_experiment_run,
        "experiment report": cmd_experiment_report,
    }
    for name, command in commands.items():
        command.set_defaults(func=handlers[name])
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from routine_gym.envs import quiet_ale
    from routine_gym.errors import DISK_FULL_EXIT, debug_requested, disk_full, one_line

    quiet_ale()
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = debug_requested(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
        sys.stdout.flush()  # here, where a reader gone away is caught below, not at exit
        return code
    except (CLIError, ValueError, TypeError, FileNotFoundError) as exc:
        if debug:
            raise
        parser.exit(2, f"routine-gym: error: {one_line(exc)}\n")
    except BrokenPipeError:
        # The reader of our output went away (`routine-gym experiment list | head`): stop
        # quietly, as `ls | head` does, without a second error when the stream is flushed.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except OSError as exc:
        line = disk_full(exc)
        if line is None or debug:
            raise
        parser.exit(DISK_FULL_EXIT, f"routine-gym: error: {line}\n")
    except Exception as exc:
        # gymnasium's own errors (an unknown env id, ...) are user errors too; if gymnasium was
        # never imported, the exception cannot be one of them.
        gym_error = sys.modules.get("gymnasium.error")
        if gym_error is not None and isinstance(exc, gym_error.Error) and not debug:
            parser.exit(2, f"routine-gym: error: {one_line(exc)}\n")
        raise
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
