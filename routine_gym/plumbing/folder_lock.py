"""One process writes a folder at a time: a sweep folder (SPEC §8) or a run folder.

A writer holds an exclusive `flock` on `FOLDER/.lock` from before it writes anything to its
end, and a second one on the folder is refused at once, naming the holder (pid, host, start,
command, written into the file). The kernel drops the lock when the holder's process dies,
however it dies (a SIGKILL too), so the file a killed writer leaves behind never blocks the
next one. A reader takes no lock: it says when a writer holds the folder (`lock_holder`).

Who takes it: a sweep (`routine_gym.experiments.folder_lock.sweep_lock`, `experiment run`)
for its whole sweep, and every script of `algos/` for its run folder, a new one or the one
`--resume` goes on in (`routine_gym.plumbing.run.start_run`), so two `--resume` of one run
never both train it.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shlex
import socket
import sys
import threading
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from routine_gym.errors import UsageError, one_line

__all__ = ["LOCK_FILE", "folder_lock", "hold_folder", "lock_holder"]

LOCK_FILE = ".lock"

_HELD: dict[str, list[Any]] = {}  # real path of a held folder → [fd, depth]
_HELD_GUARD = threading.Lock()


def _describe_holder(info: dict[str, Any]) -> str:
    text = (f"pid {info.get('pid', '?')} on {info.get('host', '?')}, "
            f"started {info.get('started', '?')}")
    if info.get("command"):
        text += f": {info['command']}"
    return text


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        info = json.loads(os.pread(fd, 65536, 0).decode("utf-8", errors="replace") or "{}")
    except (OSError, ValueError, RecursionError):
        return {}
    return info if isinstance(info, dict) else {}


def _problem(exc: OSError) -> str:
    return exc.strerror or one_line(exc)


def hold_folder(folder: str | os.PathLike, *, what: str, named: str,
                command: str | None = None) -> Callable[[], None]:
    """Take the lock of the existing folder `folder` and return the function that releases it.
    Re-entrant in one process (each hold released by its own call).

    Args:
        folder: the folder (it exists).
        what: what writes such a folder, for the messages (`"sweep"`, `"run"`).
        named: how the user named it, for the messages (`"--out X"`, `"--resume R"`).
        command: the holder's command line, written for the next one (default: `sys.argv`).

    Raises:
        UsageError: another process holds the folder (one line naming it), or the lock file
            cannot be written or locked there.
    """
    path = Path(folder)
    real = os.path.realpath(path)
    with _HELD_GUARD:
        held = _HELD.get(real)
        if held is not None:
            held[1] += 1
    if held is not None:
        def release_again() -> None:
            with _HELD_GUARD:
                held[1] -= 1
        return release_again
    lock = path / LOCK_FILE
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        raise UsageError(f"{named}: cannot write there: {lock}: {_problem(exc)}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        info = _read_holder(fd)
        os.close(fd)
        holder = _describe_holder(info) if info else "its pid is not written yet"
        raise UsageError(f"{path} is in use by another {what} ({holder}); one {what} writes "
                         "a folder at a time: wait for it to end, or stop it") from None
    except OSError as exc:
        os.close(fd)
        raise UsageError(f"{lock}: cannot lock it ({_problem(exc)}); the {what} folder needs "
                         "a filesystem with file locks") from None
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "started": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "command": command or shlex.join(sys.argv)}
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
    except OSError as exc:  # a full disk: named, and the lock dropped
        os.close(fd)
        raise OSError(exc.errno, exc.strerror, str(lock)) from exc
    entry = [fd, 1]
    with _HELD_GUARD:
        _HELD[real] = entry

    def release() -> None:
        with _HELD_GUARD:
            entry[1] -= 1
            if entry[1] > 0 or _HELD.get(real) is not entry:
                return
            del _HELD[real]
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)  # released: the file names no holder
        os.close(fd)  # drops the lock (the kernel drops it too if this process dies)

    return release


@contextlib.contextmanager
def folder_lock(folder: str | os.PathLike, *, what: str, named: str,
                command: str | None = None) -> Any:
    """Hold the existing folder `folder` while the block runs (`hold_folder`)."""
    release = hold_folder(folder, what=what, named=named, command=command)
    try:
        yield Path(folder)
    finally:
        release()


def lock_holder(folder: str | os.PathLike) -> str | None:
    """Who holds `folder` (`_describe_holder`), or None when nobody appears to: read from
    `folder/.lock` without locking it (a writer killed without releasing it leaves its holder
    written there; its pid is checked on this host)."""
    lock = Path(folder) / LOCK_FILE
    try:
        fd = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        info = _read_holder(fd)
    finally:
        os.close(fd)
    if not info:
        return None
    pid = info.get("pid")
    if info.get("host") == socket.gethostname() and isinstance(pid, int):
        if pid == os.getpid():
            return _describe_holder(info)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None  # a killed writer's file
        except OSError:
            pass
    return _describe_holder(info)
