"""One sweep writes a sweep folder at a time (SPEC §8).

A sweep holds the folder's lock (`routine_gym.plumbing.folder_lock`: an exclusive `flock` on
`OUT/.lock` naming the holder) from before it writes anything to its end, and a second sweep on
the folder is refused at once, naming the holder. `report` takes no lock: it only reads, and
says when a sweep holds the folder (`lock_holder`).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

from routine_gym.atomic import check_name
from routine_gym.errors import UsageError
from routine_gym.experiments import os_problem
from routine_gym.plumbing.folder_lock import LOCK_FILE, folder_lock, lock_holder

__all__ = ["LOCK_FILE", "lock_holder", "sweep_folder", "sweep_lock"]


def sweep_folder(out: str | os.PathLike) -> Path:
    """`out` as an absolute path (symbolic links kept: Ray nodes see a shared folder under the
    same name), made with its `runs/` folder when missing.

    Raises:
        UsageError: one line: `out` is empty, a file, under a file, or cannot be made.
    """
    text = os.fspath(out)
    if not str(text).strip():
        raise UsageError("--out needs a folder, actual value: ''")
    check_name(text, "--out")  # minari:ID, xyz:...
    path = Path(os.path.abspath(text))
    for place in (path / "runs", *(path / "runs").parents):
        if place.exists() or place.is_symlink():
            if not place.is_dir():
                what = "--out" if place == path else f"--out {text}:"
                raise UsageError(f"{what} {place} is a file, not a folder")
            break
    try:
        (path / "runs").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out {text}: cannot make the folder {exc.filename or path} "
                         f"({os_problem(exc)})") from None
    return path


@contextlib.contextmanager
def sweep_lock(out: str | os.PathLike, command: str | None = None) -> Any:
    """Own the sweep folder `out` (made when missing) while the block runs: an exclusive
    `flock` on `out/.lock`, which names the holder (pid, host, start, command). Re-entrant in
    one process (`experiment run all` holds it across its experiments). Yields `out` as an
    absolute path.

    Raises:
        UsageError: another process holds the folder (one line naming it), or `out` cannot be
            made or written (`sweep_folder`).
    """
    path = sweep_folder(out)
    with folder_lock(path, what="sweep", named=f"--out {os.fspath(out)}", command=command):
        yield path
