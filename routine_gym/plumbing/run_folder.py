"""A run's folder: the checks made before it exists, the folder itself, and its removal when
the run fails before it wrote anything of its own (`routine_gym.plumbing.run.start_run`)."""

from __future__ import annotations

import os
import shutil
import time
from typing import Any

from routine_gym.atomic import check_folder
from routine_gym.errors import UsageError
from routine_gym.plumbing.folder_lock import LOCK_FILE

__all__ = ["check_demo_source", "check_tracking_now", "new_run_folder", "remove_failed_run"]


def new_run_folder(run_dir: str, stem: str) -> tuple[str, str]:
    """`{run_dir}/{stem}__{time}`, made now; a second run in the same second gets `-2`, ..."""
    check_folder(run_dir, "--run-dir")  # a file on the way, a read-only place
    try:
        os.makedirs(run_dir, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--run-dir {run_dir}: cannot make it ({exc.strerror})") from None
    stamp = int(time.time())
    for k in range(1, 10_000):
        name = f"{stem}__{stamp}" + ("" if k == 1 else f"-{k}")
        path = os.path.join(run_dir, name)
        try:
            os.mkdir(path)  # atomic: two runs never get the same folder
        except FileExistsError:
            continue
        except OSError as exc:
            raise UsageError(f"--run-dir {run_dir}: cannot make a run folder there "
                             f"({exc.strerror})") from None
        return name, path
    raise UsageError(f"--run-dir {run_dir}: no free run folder name for {stem}")


def check_demo_source(args: Any) -> None:
    """`--demo minari:ID` that cannot be read here (no such dataset, Minari's hdf5 format
    without h5py, ...): a one-line error before the run's folder is made."""
    from routine_gym.demo.minari import check_minari_dataset, minari_dataset_id

    dataset_id = minari_dataset_id(getattr(args, "demo", None))
    if dataset_id is not None:
        check_minari_dataset(dataset_id)


def check_tracking_now(args: Any) -> None:
    """`--track` without wandb installed, with a project W&B refuses or without W&B
    credentials (`check_tracking`): a one-line error before the run's folder is made."""
    if getattr(args, "track", False):
        from routine_gym.plumbing.tracking import check_tracking

        check_tracking(args.wandb_project_name, args.wandb_entity)


def remove_failed_run(run: Any) -> None:
    """Remove a new run's folder when it holds nothing but TensorBoard's first event file."""
    run.writer.close()
    if run.release is not None:
        run.release()
        run.release = None
    path = run.path
    if not os.path.isdir(path):
        return
    entries = os.listdir(path)
    if all(e.startswith("events.out.tfevents.") or e in ("routines.json", LOCK_FILE)
           for e in entries):
        shutil.rmtree(path, ignore_errors=True)
