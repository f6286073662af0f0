"""One sweep writes a sweep folder at a time (SPEC §8).

A sweep holds an exclusive `flock` on `OUT/.lock` from before it writes anything to its end, and
a second sweep on the folder is refused at once, naming the holder (pid, host, start, command,
written into the file). The kernel drops the lock when the holder's process dies, however it
dies (a SIGKILL too), so the file a killed sweep leaves behind never blocks the next one.
`report` takes no lock: it only reads, and says when a sweep holds the folder (`lock_holder`).
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
from pathlib import Path
from typing import Any

from routine_gym.experiments import os_problem, utc_now
from routine_gym.plumbing.atomic import check_name
from routine_gym.plumbing.errors import UsageError

__all__ = ["LOCK_FILE", "lock_holder", "sweep_folder", "sweep_lock"]

LOCK_FILE = ".lock"
#: Seconds the reachability check of `--address` waits for the Ray head.


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


_HELD: dict[str, list[Any]] = {}  # real path of a sweep folder → [fd, depth]
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
    real = os.path.realpath(path)
    with _HELD_GUARD:
        held = _HELD.get(real)
        if held is not None:
            held[1] += 1
    if held is not None:
        try:
            yield path
        finally:
            with _HELD_GUARD:
                held[1] -= 1
        return
    lock = path / LOCK_FILE
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        raise UsageError(f"--out {os.fspath(out)}: cannot write there: {lock}: "
                         f"{os_problem(exc)}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _read_holder(fd)
            holder = _describe_holder(info) if info else "its pid is not written yet"
            raise UsageError(f"{path} is in use by another sweep ({holder}); one sweep writes "
                             "a folder at a time: wait for it to end, or stop it") from None
        except OSError as exc:
            raise UsageError(f"{lock}: cannot lock it ({os_problem(exc)}); the sweep folder "
                             "needs a filesystem with file locks") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(), "started": utc_now(),
                "command": command or shlex.join(sys.argv)}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        with _HELD_GUARD:
            _HELD[real] = [fd, 1]
        try:
            yield path
        finally:
            with _HELD_GUARD:
                del _HELD[real]
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # released: the file names no holder
    finally:
        os.close(fd)  # drops the lock (the kernel drops it too if this process dies)


def lock_holder(out: str | os.PathLike) -> str | None:
    """Who holds the sweep folder `out` (`_describe_holder`), or None when no sweep appears to:
    read from `out/.lock` without locking it (a sweep killed without releasing it leaves its
    holder written there; its pid is checked on this host)."""
    lock = Path(out) / LOCK_FILE
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
            return None  # a killed sweep's file
        except OSError:
            pass
    return _describe_holder(info)
