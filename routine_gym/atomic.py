"""Atomic file writes: a crash, a kill or a full disk never leaves half a file behind.

A file is written to a temporary file beside it, `.{name}.tmp` (the same name each time, so
the remains of a killed write are reused by the next one, never piling up), flushed to disk,
then renamed over the target in one step. Only regular files are replaced: a folder, a device
(`/dev/null`), a pipe or a link to one is refused. `check_writable` tells, before any work,
whether a path could be written at all (a missing folder, a read-only place), so that nobody
plays or trains for an output that cannot be saved.
"""

from __future__ import annotations

import os
import stat

from routine_gym.errors import UsageError

__all__ = ["atomic_write_bytes", "atomic_write_text", "check_writable", "temporary_path"]


def temporary_path(path: str | os.PathLike) -> str:
    """Where `atomic_write_bytes` stages `path`: `.{name}.tmp` in the same folder."""
    path = os.path.abspath(os.fspath(path))
    return os.path.join(os.path.dirname(path), f".{os.path.basename(path)}.tmp")


def _refuse_irregular(path: str, what: str) -> None:
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file"
        raise UsageError(f"{what}{path} is {kind}; routine-gym only writes regular files")


def check_writable(path: str | os.PathLike, flag: str = "") -> None:
    """Refuse, before any work, a path that cannot be written as a regular file.

    Args:
        path: the output file.
        flag: the option that named it, for the message (`"--out"`).

    Raises:
        UsageError: the path is a folder or not a regular file, its folder does not exist, or
            nothing can be created there (read-only, no permission).
    """
    path = os.fspath(path)
    what = f"{flag} " if flag else ""
    _refuse_irregular(path, what)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UsageError(f"{what}{path}: its folder {folder} does not exist")
    probe = temporary_path(path)
    try:
        with open(probe, "wb"):
            pass
        os.unlink(probe)
    except OSError as exc:
        raise UsageError(f"{what}{path}: cannot write there ({exc.strerror})") from None


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder and a rename."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same folder and a rename.

    The folder is made when missing. The file gets the permissions `open()` would give it.

    Raises:
        UsageError: `path` exists and is not a regular file (a folder, a device, a pipe).
    """
    path = os.fspath(path)
    _refuse_irregular(path, "")
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    tmp = temporary_path(path)
    try:
        umask = os.umask(0)
        os.umask(umask)
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
