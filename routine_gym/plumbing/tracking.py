"""`--track`: a run also logged to Weights & Biases, as CleanRL's scripts do.

TensorBoard stays the run's log and is always written. With `--track` the run's
`ScalarWriter` also hands every event it writes to `WandbScalars`, which logs it to W&B as one
row: the same tags, the float32 values TensorBoard stores, and the event's step as the
`global_step` metric that every other metric is plotted against. The two sinks hold the same
scalars at the same steps (`tests/test_tracking.py` reads both back and compares them).

Why not W&B's `sync_tensorboard=True`: it patches the `EventFileWriter` that `SummaryWriter`
uses, so it does pick up `ScalarWriter`'s files, but it reads them back from disk
asynchronously (on this machine the rows arrived about 10 s after the run ended, in
`run.finish`), and only for writers made after `wandb.init`. Logging each event directly has
neither catch.

Why `global_step` as a metric and not `wandb.log(..., step=...)`: W&B's own step may only
grow, and a run's steps do not always (`compile_a2c.py` logs its compile iterations before
training; a resumed run logs again from its checkpoint's step); W&B would drop those rows.

The W&B run id is saved in the run's checkpoints (`Run.save_checkpoint`), so `--resume`
continues the same W&B run (`wandb.init(id=..., resume="allow")`). Where W&B writes its files
is W&B's choice (`./wandb`, or `WANDB_DIR`); `WANDB_MODE=offline` logs without an account.
"""

from __future__ import annotations

import os
from dataclasses import asdict
from types import ModuleType
from typing import Any

from routine_gym.errors import UsageError

__all__ = ["INSTALL_HINT", "STEP_METRIC", "WandbScalars", "check_tracking", "import_wandb",
           "start_tracking"]

#: `WANDB_MODE`s that log without an account.
_LOCAL_MODES = ("offline", "disabled", "dryrun")

#: How to get W&B, named by the error when it is missing.
INSTALL_HINT = "pip install 'routine-gym[wandb]'"
#: The metric each W&B row carries the TensorBoard step in; the others are plotted against it.
STEP_METRIC = "global_step"


def import_wandb() -> ModuleType:
    """The `wandb` module, or a one-line error naming the extra that installs it."""
    try:
        import wandb
    except ImportError:
        raise UsageError(f"--track needs Weights & Biases (wandb), which is not installed: "
                         f"{INSTALL_HINT}") from None
    return wandb


def check_tracking(project: str | None, entity: str | None) -> None:
    """Refuse, before any run starts, W&B settings that would fail every run's `wandb.init`:
    wandb missing, a project or entity name W&B refuses (`a/b`: no `/\\#?%:`), a `WANDB_MODE`
    it refuses, or no W&B credentials outside offline mode. A sweep otherwise started every
    run, each failed, and the sweep advised the same command again.

    Raises:
        UsageError: one line naming the flag, or saying how to log in.
    """
    wandb = import_wandb()
    for flag, key, value in (("--wandb-project-name", "project", project),
                             ("--wandb-entity", "entity", entity)):
        if value is None:
            continue
        try:
            wandb.Settings(**{key: value})
        except Exception as exc:  # wandb's UsageError, or pydantic's ValidationError
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise UsageError(f"{flag} {value}: W&B refuses it ({first})") from None
    mode = os.environ.get("WANDB_MODE")
    if mode is not None:  # W&B reads it in wandb.init, mid-run: a pydantic traceback there
        try:
            wandb.Settings(mode=mode)
        except Exception as exc:  # pydantic's ValidationError
            lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
            allowed = next((line for line in lines if line.startswith("Input should be")),
                           type(exc).__name__)
            raise UsageError(f"WANDB_MODE={mode}: W&B refuses it "
                             f"({allowed.split(' [type=')[0]})") from None
    if os.environ.get("WANDB_MODE", "").lower() in _LOCAL_MODES or os.environ.get(
            "WANDB_DISABLED", "").lower() in ("1", "true"):
        return
    if not wandb.login(prompt=False, verify=False):
        raise UsageError("--track: not logged in to Weights & Biases (no API key): run "
                         "`wandb login` (or set WANDB_API_KEY), or set WANDB_MODE=offline to "
                         "log locally")


class WandbScalars:
    """Logs the scalar events of a `ScalarWriter` to a W&B run, one row per event.

    Called with an event's step and its `(tag, value)` pairs. An event may hold one tag twice
    (two episodes ending at the same step): each repeat starts a new row, so W&B keeps every
    value TensorBoard keeps.
    """

    def __init__(self, run: Any) -> None:
        self.run = run
        self.finished = False
        run.define_metric(STEP_METRIC)
        run.define_metric("*", step_metric=STEP_METRIC)

    @property
    def run_id(self) -> str:
        return self.run.id

    def __call__(self, step: int, values: list[tuple[str, float]]) -> None:
        rows: list[dict[str, float]] = [{}]
        for tag, value in values:
            if tag in rows[-1]:
                rows.append({})
            rows[-1][tag] = value
        for row in rows:
            self.run.log({STEP_METRIC: int(step), **row})

    def finish(self, exit_code: int | None = None) -> None:
        """End the W&B run (after the writer's last event); a second call does nothing."""
        if not self.finished:
            self.finished = True
            self.run.finish(exit_code=exit_code)


def start_tracking(args: Any, name: str, run_id: str | None = None) -> WandbScalars:
    """Start (or, with the `run_id` of a resumed run, continue) the W&B run of a script's run.

    Args:
        args: the script's `Args` (`wandb_project_name`, `wandb_entity`), saved as the W&B
            run's config.
        name: the run's name (its folder's), the W&B run's name.
        run_id: the W&B run id a checkpoint saved (None: a new run gets a new id).

    Raises:
        UsageError: wandb is not installed, or W&B refused to start the run (not logged in,
            an unknown entity), in one line.
    """
    wandb = import_wandb()
    try:
        run = wandb.init(project=args.wandb_project_name, entity=args.wandb_entity,
                         config=asdict(args), name=name, id=run_id, resume="allow",
                         save_code=True)
    except wandb.errors.Error as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise UsageError(f"--track: W&B could not start the run ({first}); log in with "
                         "`wandb login`, or set WANDB_MODE=offline to log locally") from None
    return WandbScalars(run)
