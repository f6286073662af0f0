"""Resumable checkpoints of the training scripts: written atomically, read without unpickling.

Every script in `algos/` saves a dict of tensors, numbers and strings (its `Args` as JSON, RNG
states from :mod:`routine_gym.rng`) with :func:`write_checkpoint`, and `--resume` reads it back
with :func:`resume_settings`. Its :func:`load_checkpoint` accepts a checkpoint file or the run
folder holding one and turns every way of getting it wrong into an error that names the path.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Iterable
from dataclasses import fields
from typing import Any

import torch

from routine_gym.atomic import atomic_write_bytes

__all__ = ["CHECKPOINT_NAME", "load_checkpoint", "resume_settings", "write_checkpoint"]

#: The file name of a run's checkpoint inside its run folder.
CHECKPOINT_NAME = "checkpoint.pt"


def write_checkpoint(state: dict[str, Any], path: str | os.PathLike) -> None:
    """`torch.save(state, path)` atomically: a kill mid-write keeps the previous checkpoint."""
    buffer = io.BytesIO()
    torch.save(state, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def load_checkpoint(resume: str | os.PathLike, keys: Iterable[str],
                    script: str) -> tuple[str, dict[str, Any]]:
    """The path and contents of the checkpoint `--resume` names (a file or a run folder).

    Raises `FileNotFoundError` when there is no checkpoint there, and `ValueError` when the
    file is not one torch can read safely or lacks any of `keys` (another script's, say).
    """
    resume = os.fspath(resume)
    path = os.path.join(resume, CHECKPOINT_NAME) if os.path.isdir(resume) else resume
    if not os.path.isfile(path):
        raise FileNotFoundError(f"--resume {resume}: no checkpoint at {path}")
    try:
        checkpoint = torch.load(path, weights_only=True)
    except Exception as e:  # torch raises anything from KeyError to UnpicklingError here
        raise ValueError(f"--resume {path} is not a checkpoint torch can read ({e!r})") from e
    missing = set(keys) - (checkpoint.keys() if isinstance(checkpoint, dict) else set())
    if missing:
        raise ValueError(f"--resume {path} is not a checkpoint of {script} "
                         f"(missing {', '.join(sorted(missing))})")
    return path, checkpoint


def resume_settings(args: Any, keys: Iterable[str], script: str, *,
                    lower_budget: bool = False,
                    budget: str = "total_timesteps") -> tuple[Any, dict[str, Any], str]:
    """For `--resume`: the run's saved `Args`, its checkpoint and its run folder.

    The run continues as it was configured; a budget (`--total-timesteps`, or the field named
    by `budget`) other than the default sets a new one. By default the budget may only be
    raised (a lower one finishes the run as it was set up); with `lower_budget=True` a lower
    one is taken as it is, so a script can go straight to evaluation. A bare `--resume` keeps
    the saved budget. The run folder is the checkpoint's own, wherever the script is run from.
    """
    path, checkpoint = load_checkpoint(args.resume, keys, script)
    saved = type(args)(**json.loads(checkpoint["args"]))
    default = next(f.default for f in fields(args) if f.name == budget)
    given, before = getattr(args, budget), getattr(saved, budget)
    if given != default:
        setattr(saved, budget, given if lower_budget else max(before, given))
    saved.resume = path
    return saved, checkpoint, os.path.dirname(os.path.abspath(path))
