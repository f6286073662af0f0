"""The run set-up every script in `algos/` shares: the plumbing CleanRL writes at the top of
each script, written once.

`start_run(args, script, checkpoint_keys)` checks the arguments, resolves `--resume` (the
saved `Args`, the checkpoint, the run's own folder), makes the run folder
`{run_dir}/{env}__{exp_name}[-{mode}]__{seed}__{time}`, the TensorBoard writer with the
hyper-parameter table, seeds Python, NumPy and torch (and a `numpy.random.Generator` for the
script's own draws), sets torch's threads, keeps freed memory for reuse
(`routine_gym.plumbing.memory`) and picks the device. The `Run` it returns holds the
run's lifecycle, so a script's `main` holds only its algorithm: `run.resume(...)` names what a
checkpoint holds and puts it back on `--resume` (returning the step counters),
`run.checkpoint_if_due(...)` saves one every `--checkpoint-every` steps (with every RNG state,
the `Args` as JSON, and the training film's episode count, so a resumed `--capture-video` run
goes on numbering its films), and `run.finish(policy, ...)` saves the last checkpoint and the model,
evaluates (`eval.json`, `--extra-evals`), records `--record-demo` and closes the writer; files
go through the one atomic writer of `routine_gym.atomic`. A checkpoint is never
written, nor the model evaluated, once a parameter or an optimizer state is not finite: the run
stops with one line and exit code 3 (`routine_gym.plumbing.divergence`). With `--track` the
writer's scalars also go to Weights & Biases (`routine_gym.plumbing.tracking`), and the W&B run id
travels in the checkpoints so that `--resume` continues the same W&B run.

The argument check (`check_args`, `DOMAINS`) and the command line (`parse_args`) are in
`routine_gym.plumbing.arguments`.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from routine_gym.atomic import atomic_write_bytes, check_writable
from routine_gym.errors import UsageError
from routine_gym.plumbing.arguments import ExtraChecks, check_args, given_flags, parse_args
from routine_gym.plumbing.checkpoint import CHECKPOINT_NAME, resume_settings, write_checkpoint
from routine_gym.plumbing.divergence import (
    EXIT_CODE,
    TrainingDiverged,
    as_divergence,
    check_parameters,
)
from routine_gym.plumbing.env_setup import (
    check_env,
    eval_env_kwargs,
    level_env_kwargs,
    profile_reward_scale,
    train_env_kwargs,
)
from routine_gym.plumbing.folder_lock import LOCK_FILE, hold_folder
from routine_gym.plumbing.rng import rng_state, seed_and_tune, set_rng_state
from routine_gym.plumbing.run_folder import (
    check_demo_source,
    check_tracking_now,
    new_run_folder,
    remove_failed_run,
)
from routine_gym.plumbing.seeds import demo_seed, eval_seed, stride_checks

__all__ = [
    "Every",
    "Run",
    "check_env",
    "eval_env_kwargs",
    "level_env_kwargs",
    "run_script",
    "seed_and_tune",
    "start_run",
    "train_env_kwargs",
]


def run_script(main: Callable[[Any], Any], args_type: type,
               renamed: dict[str, str] | None = None) -> None:
    """A script's entry point: parse its flags and run `main`, reporting a user's mistakes
    (`routine_gym.errors`) as one line on stderr with exit code 2; `--debug` (or
    `ROUTINE_GYM_DEBUG=1`) shows their traceback instead. A bug keeps its traceback."""
    from routine_gym.envs import quiet_ale
    from routine_gym.errors import (
        DISK_FULL_EXIT,
        debug_requested,
        disk_full,
        expected_errors,
        one_line,
    )
    from routine_gym.plumbing.eager_optim import eager_optimizers

    quiet_ale()
    eager_optimizers()  # 1.4 s off the start: no script compiles (`eager_optim`)
    argv = sys.argv[1:]
    debug = debug_requested(argv)
    script = os.path.basename(sys.argv[0])
    try:
        try:
            main(parse_args(args_type, renamed, argv))
        except RuntimeError as exc:
            # torch refusing to sample from an overflowed policy: the run diverged.
            diverged = as_divergence(exc, _RUNS[-1].step if _RUNS else None)
            if diverged is None:
                raise
            raise diverged from exc
    except TrainingDiverged as exc:
        # One line and exit code 3 (the command was valid, the run diverged); the run folder and
        # its last checkpoint stay, with no eval.json (routine_gym.plumbing.divergence).
        _end_tracking(exit_code=EXIT_CODE)
        if debug:
            raise
        print(f"{script}: error: {one_line(exc)}", file=sys.stderr)
        raise SystemExit(EXIT_CODE) from None
    except expected_errors() as exc:
        for run in _NEW_RUNS:
            remove_failed_run(run)
        _end_tracking(exit_code=2)  # before the error line, which a log's last line should be
        if debug:
            raise
        print(f"{script}: error: {one_line(exc)}", file=sys.stderr)
        raise SystemExit(2) from None
    except OSError as exc:
        line = disk_full(exc)
        if line is None or debug:
            raise
        for run in _NEW_RUNS:  # a new run that wrote nothing but its first events
            with contextlib.suppress(OSError):
                remove_failed_run(run)
        with contextlib.suppress(OSError):
            _end_tracking(exit_code=DISK_FULL_EXIT)
        print(f"{script}: error: {line}", file=sys.stderr)
        raise SystemExit(DISK_FULL_EXIT) from None


# -- the run ----------------------------------------------------------------------------------


class Every:
    """Fires once each time a step counter passes the next multiple of `period` (0: never).

    Steps advance by more than one (a rollout, a routine), so a multiple may be jumped over;
    it fires on the first step at or past it. A resumed run starts counting where it stopped.

    Example:
        >>> checkpoints = Every(100, start=30)
        >>> [step for step in (80, 100, 150, 230, 240, 310) if checkpoints.due(step)]
        [100, 230, 310]
    """

    def __init__(self, period: int, start: int = 0) -> None:
        self.period = int(period)
        self.next = (start // self.period + 1) * self.period if self.period > 0 else None

    def due(self, step: int) -> bool:
        if self.next is None or step < self.next:
            return False
        self.next = (step // self.period + 1) * self.period
        return True



@dataclass
class Run:
    """A started run: its settings, folder, writer, device, RNG and (resumed) checkpoint."""

    args: Any
    name: str
    path: str
    writer: Any
    device: torch.device
    rng: np.random.Generator
    checkpoint: dict[str, Any] | None
    """The checkpoint `--resume` read (None for a new run)."""
    budget: str = "total_timesteps"
    """The `Args` field of the run's budget."""
    saved_budget: int | None = None
    """The budget the resumed checkpoint was saved with."""
    tracking: Any = None
    """The W&B run the writer's scalars also go to (`--track`; None without)."""
    wandb_run_id: str | None = None
    """The W&B run id the checkpoints keep: this run's, or the resumed checkpoint's."""
    step: int | None = None
    """The step counter at the end of the last iteration (`checkpoint_if_due`), for reports."""
    release: Callable[[], None] | None = None
    """Releases the run folder's lock (`routine_gym.plumbing.folder_lock`), held from the
    start; `finish` calls it (a process that dies drops it anyway)."""

    @property
    def checkpoint_path(self) -> str:
        return os.path.join(self.path, CHECKPOINT_NAME)

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        """Write `state` plus every RNG state and the `Args` atomically as the checkpoint.

        A lower budget given on `--resume` (to go straight to evaluation) does not replace the
        run's saved budget: a later `--resume` still trains to it.
        """
        settings = asdict(self.args)
        if self.saved_budget is not None and settings[self.budget] < self.saved_budget:
            settings[self.budget] = self.saved_budget
        tracked = {} if self.wandb_run_id is None else {"wandb_run_id": self.wandb_run_id}
        write_checkpoint(
            {**state, "rng": rng_state(self.rng), "args": json.dumps(settings), **tracked},
            self.checkpoint_path,
        )

    def restore(self, target: Any, key: str) -> None:
        """`target.load_state_dict(checkpoint[key])`, refusing one of another shape by name."""
        try:
            target.load_state_dict(self.checkpoint[key])
        except (RuntimeError, ValueError, KeyError, TypeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UsageError(f"--resume {self.args.resume}: its {key} does not fit this run "
                             f"({first[:200]})") from None

    def restore_rng(self) -> None:
        """Put every RNG back where the resumed checkpoint left it."""
        try:
            set_rng_state(self.checkpoint["rng"], self.rng)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise UsageError(f"--resume {self.args.resume}: its RNG state is not one "
                             f"routine-gym saved ({type(exc).__name__})") from None

    # -- the lifecycle: resume, checkpoint, finish ---------------------------------------------

    def routines(self, demo: Any = None, *, meanings: Callable[[], Any] | None = None,
                 env_kwargs: dict[str, Any] | None = None, required: str | None = None
                 ) -> Any:
        """The run's routine library, set up in one call and saved as its `routines.json`
        (`plumbing.loading.run_library`, whose arguments these are)."""
        from routine_gym.plumbing.loading import run_library

        return run_library(self.args, self.checkpoint, self.path, demo, meanings=meanings,
                           env_kwargs=env_kwargs, required=required)

    @property
    def first_video_episode(self) -> int:
        """The number of training env 0's first episode: 0 for a new run, else the episodes
        the resumed checkpoint counted, so that `--capture-video`'s training films go on
        numbering where the run left off instead of overwriting its first leg's."""
        if self.checkpoint is None:
            return 0
        value = self.checkpoint.get("video_episodes", 0)
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise UsageError(f"--resume {self.args.resume}: its video_episodes is not a count "
                             f"({value!r})")
        return value

    def _video_episodes(self) -> int:
        """Env 0's episodes so far, for the checkpoint: counted by its `RecordEpisodeStatistics`
        while this leg films (`--capture-video`), else the resumed count carried on."""
        if self._filmed is not None and getattr(self.args, "capture_video", False):
            return self.first_video_episode + int(self._filmed.get_attr("episode_count")[0])
        return self.first_video_episode
    def routine_demo(self, purpose: str) -> Any:
        """The demo the run's routines are mined from and its evaluation aligns with
        (`plumbing.loading.run_demo`)."""
        from routine_gym.plumbing.loading import run_demo

        return run_demo(self.args, resumed=self.checkpoint is not None, purpose=purpose)

    def resume(self, state: dict[str, Any], *, extra: dict[str, Any] | None = None,
               count: str | None = None, filmed: Any = None, **counters: int) -> Any:
        """Name what the run's checkpoints hold; on `--resume`, put it back where it was.

        Args:
            state: the objects with a `state_dict` (models, optimizers), by checkpoint key.
            extra: values saved as they are (the routine library as JSON, ...); the script reads
                them from `run.checkpoint` itself, before it builds what depends on them.
            count: the counter `--checkpoint-every` counts (default: the first); a script
                with `--budget-unit decisions` names its decision counter.
            filmed: the training vector env whose env 0 `--capture-video` films (made with
                `first_video_episode=run.first_video_episode`): its episode count goes into
                every checkpoint, so a resumed run's films go on numbering.
            counters: the step counters with their start values (`global_step=0,
                iteration=0`); the first is the step counter `finish` reports.

        Returns:
            The counters' values (the saved ones on `--resume`), one int for one counter, else
            a tuple in the order given.
        """
        self._state, self._extra = dict(state), dict(extra or {})
        self._filmed = filmed
        self._counter_names = tuple(counters)
        self._count = count or self._counter_names[0]
        if self._count not in counters:
            raise ValueError(f"count={count!r} is not one of the counters {self._counter_names}")
        values = dict(counters)
        if self.checkpoint is not None:
            for key, target in self._state.items():
                self.restore(target, key)
            values = {name: self.checkpoint[name] for name in counters}
            self.restore_rng()
            step = values[self._counter_names[0]]
            print(f"resumed {self.name} at step {step}")
        self.step = values[self._counter_names[0]]
        self._checkpoints = Every(self.args.checkpoint_every, start=values[self._count])
        out = tuple(values[name] for name in self._counter_names)
        return out[0] if len(out) == 1 else out

    def _check_state(self, counters: dict[str, int]) -> None:
        """Refuse to go on with a non-finite parameter or optimizer state (`TrainingDiverged`)."""
        check_parameters(counters[self._counter_names[0]], self._state)

    def _save_state(self, counters: dict[str, int]) -> None:
        self._check_state(counters)  # a checkpoint never holds a diverged state
        self.writer.flush()  # the scalars up to the checkpoint are on disk before it
        self.save_checkpoint({
            **{key: target.state_dict() for key, target in self._state.items()},
            **{name: counters[name] for name in self._counter_names},
            **self._extra,
            "video_episodes": self._video_episodes(),
        })

    def checkpoint_if_due(self, **counters: int) -> None:
        """Save a checkpoint when the counter `resume` named (its `count`) has passed the next
        multiple of `--checkpoint-every`; `counters` are the values of `resume`'s counters."""
        self.step = counters[self._counter_names[0]]
        if self._checkpoints.due(counters[self._count]):
            self._save_state(counters)

    def finish(self, policy: Callable[..., int], *, model: Any, method: str,
               demo: Any = None, routines: Any = None, env_kwargs: dict[str, Any] | None = None,
               max_steps: int | None = None, summary: dict[str, Any] | None = None,
               stop_rule: Any = None, **counters: int) -> dict[str, Any] | None:
        """End the run: the last checkpoint (with `--checkpoint-every`), the model
        (`--save-model`), the evaluation in `eval.json` (`--eval-episodes`; with
        `--capture-video` its episodes filmed into `{run}/videos/`), the evaluations of
        `--extra-evals`, the demo of `--record-demo`, and the writer closed (and the W&B run
        of `--track` ended).

        Args:
            policy: the trained policy, as `evaluate_policy` takes it.
            model: what `save_model` saves (a module, or modules by name).
            demo: the demo the evaluation aligns with (None: no alignment).
            routines: the routines the policy can choose.
            env_kwargs: the evaluation levels (None: `evaluate_policy`'s default).
            max_steps: `--eval-max-steps`, where the script has it.
            method: the method's name in `eval.json`.
            summary: what the script adds to `eval.json` after `method` and `global_step`
                (the step counter's final value).
            stop_rule: the stop rule the policy was trained under (`--interrupt`): every
                evaluation and `--record-demo` acts under it too, as training did (None: none).
            counters: the final values of `resume`'s counters.

        Returns:
            The evaluation's summary (None without `--eval-episodes`).
        """
        from routine_gym.plumbing.evaluation import evaluate_policy, save_evaluation

        args, step = self.args, counters[self._counter_names[0]]
        self.step = step
        self._check_state(counters)  # no model saved nor evaluated once it is broken
        if args.checkpoint_every > 0:
            self._save_state(counters)
        if args.save_model:
            self.save_model(model)
        result = None
        if args.eval_episodes > 0:
            # --capture-video: the evaluation episodes as GIFs, the routine executed named.
            videos = os.path.join(self.path, "videos") \
                if getattr(args, "capture_video", False) else None
            result = evaluate_policy(args.env_id, policy, args.eval_episodes,
                                     seed=eval_seed(args.seed, getattr(args, "seed_stride", 1)),
                                     demo=demo, routines=routines,
                                     env_kwargs=env_kwargs, max_steps=max_steps,
                                     video_folder=videos, stop_rule=stop_rule)
            result.update(method=method, global_step=step, **(summary or {}))
            save_evaluation(result, self.path, self.writer, step)
            for levels in getattr(args, "extra_evals", ()):
                other = evaluate_policy(args.env_id, policy, args.eval_episodes,
                                        seed=eval_seed(args.seed, getattr(args, "seed_stride", 1)),
                                        routines=routines,
                                        env_kwargs=level_env_kwargs(args, levels),
                                        max_steps=max_steps, stop_rule=stop_rule)
                other.update(method=method, global_step=step, **(summary or {}), levels=levels)
                save_evaluation(other, self.path, self.writer, step, name=f"eval-{levels}")
        if getattr(args, "record_demo", None):
            self._record_demo(policy, routines, step, stop_rule)
        self.writer.close()
        if self.tracking is not None:
            self.tracking.finish()
        if self.release is not None:
            self.release()
            self.release = None
        return result

    def _record_demo(self, policy: Callable[..., int], routines: Any, step: int,
                     stop_rule: Any = None) -> None:
        """`--record-demo`: the best of `--demo-episodes` games of the trained agent, on the
        training levels, saved without observations."""
        import gymnasium as gym

        from routine_gym.demo import record_agent_demo
        from routine_gym.envs.factory import default_env_kwargs, preprocess

        args = self.args

        def wrap(env):
            return preprocess(gym.wrappers.RecordEpisodeStatistics(env), args.env_id,
                              training=False)

        # The demo marks the agent's decisions (each step of a chosen routine included) apart
        # from the steps the preprocessing injects (no-op start, FIRE, served lives).
        demo = record_agent_demo(
            args.env_id, policy, num_episodes=args.demo_episodes,
            seed=demo_seed(args.seed, getattr(args, "seed_stride", 1)),
            env_kwargs={**default_env_kwargs(args.env_id), **train_env_kwargs(args)},
            wrap_env=wrap, routines=routines, stop_rule=stop_rule,
            meta={"trained_steps": step, "command": " ".join(sys.argv),
                  "mode": getattr(args, "mode", None), "run": self.name},
        )
        demo.save(args.record_demo, include_observations=False)
        print(f"demo saved to {args.record_demo}: score {demo.score:g}, {len(demo)} steps")

    def save_model(self, model: torch.nn.Module | dict[str, torch.nn.Module]) -> str:
        """Save `model`'s weights (or each named model's) to `{run}/model.pt` atomically."""
        buffer = io.BytesIO()
        if isinstance(model, dict):
            torch.save({name: m.state_dict() for name, m in model.items()}, buffer)
        else:
            torch.save(model.state_dict(), buffer)
        path = os.path.join(self.path, "model.pt")
        atomic_write_bytes(path, buffer.getvalue())
        print(f"model saved to {path}")
        return path


def _with_stride_checks(extra: ExtraChecks) -> Callable[[Any], list]:
    """A script's own argument rules and `--seed-stride`'s (`plumbing.seeds.stride_checks`)."""
    return lambda args: [*(extra(args) if callable(extra) else extra), *stride_checks(args)]


def start_run(args: Any, script: str, checkpoint_keys: Iterable[str], *,
              budget: str = "total_timesteps", lower_budget: bool = False,
              extra_checks: ExtraChecks = (), preset: Callable[[Any], None] | None = None
              ) -> Run:
    """Check `args`, resume or make the run folder, open the writer, seed, pick the device.

    With `--track` the W&B run starts too (or, on `--resume`, the checkpoint's W&B run goes
    on), and the writer sends it every scalar it writes (`routine_gym.plumbing.tracking`).

    Args:
        args: the script's `Args` (with `exp_name`, `seed`, `env_id`, `run_dir`, `resume`,
            `torch_deterministic`, `torch_threads`, `cuda`, and `track`,
            `wandb_project_name`, `wandb_entity` where it has `--track`).
        script: the script's file name, for error messages (`"rapl_a2c.py"`).
        checkpoint_keys: what the script's checkpoints hold (`--resume` checks for each).
        budget: the `Args` field of the run's budget (`--resume` may change it).
        lower_budget: a lower budget on `--resume` is taken as it is (to go straight to
            evaluation); by default it may only be raised.
        extra_checks: the script's own argument rules (see `check_args`); give a function of
            the `Args` so that the settings a `--resume` restores are checked by them too.
        preset: sets the flags a preset flag stands for (`rapl_a2c.py --authors`) on a new
            run's `Args`, before they are checked; a resumed run's saved settings hold them.
    """
    if preset is not None and not args.resume:
        preset(args)
    extra_checks = _with_stride_checks(extra_checks)
    if not args.resume:
        profile_reward_scale(args)
    check_args(args, extra_checks)
    if getattr(args, "record_demo", None):
        check_writable(args.record_demo, "--record-demo", ".npz")  # before training, not after
    saved_budget = None
    if args.resume:
        args, checkpoint, path = resume_settings(args, checkpoint_keys, script,
                                                 lower_budget=lower_budget, budget=budget,
                                                 given=given_flags(args) or None)
        saved_budget = json.loads(checkpoint["args"]).get(budget)
        # The saved settings are a file's content: checked as if typed on the command line.
        try:
            check_args(args, extra_checks)
        except UsageError as exc:
            raise UsageError(f"--resume {args.resume}: its saved settings are not valid "
                             f"({exc})") from None
        name = os.path.basename(path)
        check_env(args.env_id)
        check_tracking_now(args)
        os.makedirs(path, exist_ok=True)
        # Before anything is written: a second process on the run (another --resume, or the
        # run itself still training) is refused, naming it.
        release = hold_folder(path, what="run", named=f"--resume {args.resume}")
    else:
        checkpoint = None
        check_env(args.env_id)
        check_tracking_now(args)
        check_demo_source(args)
        mode = getattr(args, "mode", None)
        experiment = args.exp_name if mode is None else f"{args.exp_name}-{mode}"
        name, path = new_run_folder(
            args.run_dir, f"{args.env_id.replace('/', '-')}__{experiment}__{args.seed}")
        # Held from its making, so that a --resume of it while it trains is refused.
        release = hold_folder(path, what="run", named=f"--run-dir {args.run_dir}")
    from routine_gym.plumbing.scalars import ScalarWriter

    wandb_run_id = None if checkpoint is None else checkpoint.get("wandb_run_id")
    tracking = None
    if getattr(args, "track", False):
        from routine_gym.plumbing.tracking import start_tracking

        try:
            tracking = start_tracking(args, name, wandb_run_id)
        except UsageError:
            release()
            if checkpoint is None:
                with contextlib.suppress(OSError):
                    os.remove(os.path.join(path, LOCK_FILE))
                    os.rmdir(path)  # the new run's folder, still empty
            raise
        wandb_run_id = tracking.run_id
        _TRACKED.append(tracking)
    # A SummaryWriter writing each step's scalars as one event, and to W&B with --track.
    writer = ScalarWriter(path, mirror=tracking)
    writer.add_text(
        "hyperparameters",
        "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items()),
    )
    seed_and_tune(args.seed, args.torch_threads)
    rng = np.random.default_rng(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    run = Run(args=args, name=name, path=path, writer=writer, device=device, rng=rng,
              checkpoint=checkpoint, budget=budget, saved_budget=saved_budget,
              tracking=tracking, wandb_run_id=wandb_run_id, release=release)
    if checkpoint is None:
        _NEW_RUNS.append(run)
    _RUNS.append(run)
    return run


#: The new runs this process started: `run_script` removes the folder of one that failed
#: before it had a checkpoint or a result.
_NEW_RUNS: list[Run] = []
#: Every run this process started (`run_script` names the last one's step in a report).
_RUNS: list[Run] = []
#: The W&B runs this process started (`--track`): `run_script` ends those of a failed run.
_TRACKED: list[Any] = []


def _end_tracking(exit_code: int) -> None:
    """End the W&B run of a run that failed (wandb would at exit, printing after the error)."""
    for tracking in _TRACKED:
        tracking.finish(exit_code=exit_code)
