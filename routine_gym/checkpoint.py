"""Resumable checkpoints of the training scripts: written atomically, read without unpickling.

Every script in `algos/` saves a dict of tensors, numbers and strings (its `Args` as JSON, RNG
states from :mod:`routine_gym.rng`) with :func:`write_checkpoint`, and `--resume` reads it back
with :func:`load_checkpoint`, which accepts a checkpoint file or the run folder holding one and
turns every way of getting it wrong into an error that names the path.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

import torch

__all__ = ["CHECKPOINT_NAME", "load_checkpoint", "write_checkpoint"]

#: The file name of a run's checkpoint inside its run folder.
CHECKPOINT_NAME = "checkpoint.pt"


def write_checkpoint(state: dict[str, Any], path: str | os.PathLike) -> None:
    """`torch.save(state, path)` atomically: a kill mid-write keeps the previous checkpoint."""
    tmp = f"{os.fspath(path)}.tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)


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
