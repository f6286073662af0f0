"""Resumable checkpoints of the training scripts: written atomically, read without unpickling.

Every script in `algos/` saves a dict of tensors, numbers and strings (its `Args` as JSON, RNG
states from :mod:`routine_gym.plumbing.rng`) with :func:`write_checkpoint`, and `--resume` reads it
back with :func:`resume_settings`. Its :func:`load_checkpoint` accepts a checkpoint file or the run
folder holding one and turns every way of getting it wrong into an error that names the path.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from collections.abc import Iterable
from dataclasses import fields
from typing import Any

import torch

from routine_gym.atomic import atomic_write_bytes
from routine_gym.errors import UsageError

__all__ = ["CHECKPOINT_NAME", "load_checkpoint", "resume_settings", "write_checkpoint"]

#: The file name of a run's checkpoint inside its run folder.
CHECKPOINT_NAME = "checkpoint.pt"


def write_checkpoint(state: dict[str, Any], path: str | os.PathLike) -> None:
    """`torch.save(state, path)` atomically: a kill mid-write keeps the previous checkpoint."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def _reason(exc: Exception) -> str:
    """torch's error in a few words, without its advice to retry unsafely (weights_only=False)."""
    text = str(exc).split("\n")[0]
    if "weights_only" in str(exc) or "Weights only load failed" in text:
        return "it holds objects that are not plain tensors, numbers or strings"
    return f"{type(exc).__name__}: {text}"[:200]


def load_checkpoint(resume: str | os.PathLike, keys: Iterable[str],
                    script: str) -> tuple[str, dict[str, Any]]:
    """The path and contents of the checkpoint `--resume` names (a file or a run folder).

    Raises `FileNotFoundError` when there is no checkpoint there, and `UsageError` (naming the
    file) when it is not one torch can read without unpickling arbitrary objects, lacks any of
    `keys` (another script's, say), or holds keys of the wrong kind (saved settings that are
    not JSON, a step count that is not an integer).
    """
    resume = os.fspath(resume)
    path = os.path.join(resume, CHECKPOINT_NAME) if os.path.isdir(resume) else resume
    if not os.path.isfile(path):
        raise FileNotFoundError(f"--resume {resume}: no checkpoint at {path}")
    if not zipfile.is_zipfile(path):
        raise UsageError(f"--resume {path} is not a checkpoint routine-gym reads (not a file "
                         "torch.save wrote; truncated or another kind of file)")
    try:
        checkpoint = torch.load(path, weights_only=True)
    except Exception as e:  # torch raises anything from KeyError to UnpicklingError here
        raise UsageError(f"--resume {path} is not a checkpoint routine-gym reads "
                         f"({_reason(e)})") from None
    missing = set(keys) - (checkpoint.keys() if isinstance(checkpoint, dict) else set())
    if missing:
        raise UsageError(f"--resume {path} is not a checkpoint of {script} "
                         f"(missing {', '.join(sorted(missing))})")
    for key in ("global_step", "iteration", "step", "updates"):
        value = checkpoint.get(key)
        if key in checkpoint and (isinstance(value, bool) or not isinstance(value, int)
                                  or value < 0):
            raise UsageError(f"--resume {path}: its {key} is {value!r}, not a step count")
    if not isinstance(checkpoint.get("args"), str):
        raise UsageError(f"--resume {path}: its saved settings are not a JSON string")
    return path, checkpoint


def _same_kind(value: Any, default: Any) -> bool:
    """Whether a saved setting has the kind of its field's default (a JSON file may hold
    anything): a bool for a bool, a number for a float, an int for an int, a string for a
    string; fields without a plain default (None, tuples) take any JSON value but an object."""
    if isinstance(default, bool):
        return isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, int) and not isinstance(value, bool)
    if isinstance(default, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if isinstance(default, str):
        return isinstance(value, str)
    return not isinstance(value, dict)


#: Settings a resumed run may change: its budget, how it is run and reported.
RESUMABLE_CHANGES = frozenset({
    "resume", "run_dir", "checkpoint_every", "log_every", "torch_threads", "save_model",
    "eval_episodes", "eval_max_steps", "eval_greedy", "record_demo", "demo_episodes", "cuda",
    "capture_video", "track", "wandb_project_name", "wandb_entity",
})


def resume_settings(args: Any, keys: Iterable[str], script: str, *,
                    lower_budget: bool = False, budget: str = "total_timesteps",
                    given: set[str] | None = None) -> tuple[Any, dict[str, Any], str]:
    """For `--resume`: the run's saved `Args`, its checkpoint and its run folder.

    The run continues as it was configured; a budget (`--total-timesteps`, or the field named
    by `budget`) other than the default sets a new one. By default the budget may only be
    raised (a lower one finishes the run as it was set up); with `lower_budget=True` a lower
    one is taken as it is, so a script can go straight to evaluation (the checkpoint keeps the
    saved budget). A bare `--resume` keeps the saved budget. Settings of how the run is run
    and reported (`RESUMABLE_CHANGES`) may change; any other flag given with a value that
    contradicts the saved run (another env, mode, number of envs) is refused. `given` names
    the fields set on the command line (without it, a field counts as given when it differs
    from its default). The run folder is the checkpoint's own, wherever the script is run
    from.
    """
    path, checkpoint = load_checkpoint(args.resume, keys, script)
    try:
        saved_fields = json.loads(checkpoint["args"])
    except json.JSONDecodeError as exc:
        raise UsageError(f"--resume {path}: its saved settings are not JSON ({exc})") from None
    if not isinstance(saved_fields, dict):
        raise UsageError(f"--resume {path}: its saved settings are not a JSON object")
    known = {f.name for f in fields(args)}
    unknown = sorted(set(saved_fields) - known)
    if unknown:
        raise UsageError(f"--resume {path}: its saved settings have fields {script} does not "
                         f"know ({', '.join(unknown)}): a checkpoint of another version?")
    for f in fields(args):
        if f.name in saved_fields and not _same_kind(saved_fields[f.name], f.default):
            raise UsageError(f"--resume {path}: its saved setting {f.name} is "
                             f"{saved_fields[f.name]!r}, not a value of the kind "
                             f"{type(f.default).__name__}")
    saved = type(args)(**saved_fields)
    defaults = {f.name: f.default for f in fields(args)}
    def is_given(name: str) -> bool:
        return name in given if given is not None else getattr(args, name) != defaults[name]

    for name in sorted(known - RESUMABLE_CHANGES - {budget}):
        value = getattr(args, name)
        if is_given(name) and value != getattr(saved, name):
            raise UsageError(
                f"--resume {path}: the run was started with --{name.replace('_', '-')} "
                f"{getattr(saved, name)}, not {value}; drop the flag or start a new run"
            )
    for name in RESUMABLE_CHANGES & known - {"resume"}:
        if is_given(name):
            setattr(saved, name, getattr(args, name))
    asked, before = getattr(args, budget), getattr(saved, budget)
    if is_given(budget):
        setattr(saved, budget, asked if lower_budget else max(before, asked))
    saved.resume = path
    return saved, checkpoint, os.path.dirname(os.path.abspath(path))
