"""Atomic file writes: a crash, a kill or a full disk never leaves half a file behind.

A file is written to a temporary file beside it, `.{name}.{pid}-{random}.tmp`, flushed to disk,
then renamed over the target in one step. The temporary name is unique to the writer, so any
number of processes (or threads) may write the same target at once: each rename replaces the
target with one complete file, and a reader only ever sees a whole file, the old one or one of
the new ones, never a partial or an empty one. The remains a killed writer leaves (a
`SIGKILL` gives it no time to clean up) are removed by the next write of the same target once
their process is gone, so they never pile up. Only regular files are replaced: a folder, a
device (`/dev/null`), a pipe or a link to one is refused. `check_writable` tells, before any
work, whether a path could be written at all (a missing folder, a read-only place, a folder
that is a file), so that nobody plays or trains for an output that cannot be saved; it and
`check_folder` refuse a name no output should have too (`check_name`: an empty one, one that
names a Minari dataset, `minari:ID`, or starts with another scheme, `xyz:`), and
`check_writable` a file name without the extension of the format written there.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import secrets
import stat
from collections.abc import Iterable

from routine_gym.errors import UsageError

__all__ = [
    "atomic_write_bytes",
    "atomic_write_chunks",
    "atomic_write_text",
    "check_folder",
    "check_not_an_input",
    "check_name",
    "check_writable",
    "temporary_path",
]

_TEMPORARY = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)-[0-9a-f]{12}\.tmp$")
#: `minari:ID`, `s3:bucket`, `https://...`: a name that is not a local path (a file of such a
#: name is written as `./minari:ID`).
_SCHEME = re.compile(r"^(?P<scheme>[A-Za-z][A-Za-z0-9+.\-]*):")


def check_name(path: str | os.PathLike, flag: str = "") -> None:
    """Refuse a name no routine-gym output should have: an empty one, or one that starts with
    a scheme, `minari:ID` (a Minari dataset: `routine-gym export` writes those) or any other
    `xyz:`, which would otherwise become a file of that literal name in the current folder.
    A file of such a name is still written when asked for as `./xyz:name`.

    Args:
        path: the output as the user gave it.
        flag: the option that named it, for the message (`"--out"`).

    Raises:
        UsageError: one line naming the flag and the value.
    """
    text = os.fspath(path)
    what = f"{flag} " if flag else ""
    if not text.strip():
        raise UsageError(f"{what}needs a path, actual value: {text!r}")
    match = _SCHEME.match(text)
    if match is None:
        return
    if match["scheme"] == "minari":
        raise UsageError(f"{what}{text} names a Minari dataset, not a local path (a dataset "
                         f"is written by `routine-gym export DEMO --minari ID`; ./{text} is a "
                         "local path of that name)")
    raise UsageError(f"{what}{text} starts with a scheme ({match['scheme']}:), not a local "
                     f"path: routine-gym writes local files (./{text} is a local path of that "
                     "name)")


def temporary_path(path: str | os.PathLike) -> str:
    """A fresh temporary name for `path`: `.{name}.{pid}-{random}.tmp` in the same folder."""
    path = os.path.abspath(os.fspath(path))
    name = f".{os.path.basename(path)}.{os.getpid()}-{secrets.token_hex(6)}.tmp"
    return os.path.join(os.path.dirname(path), name)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _remove_stale_temporaries(path: str) -> None:
    """Delete the temporary files of `path` whose writer no longer runs (a killed write)."""
    folder, base = os.path.split(path)
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            match = _TEMPORARY.match(entry.name)
            if match and match["name"] == base and not _pid_alive(int(match["pid"])):
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)


def _refuse_irregular(path: str, what: str) -> None:
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file"
        raise UsageError(f"{what}{path} is {kind}; routine-gym only writes regular files")


def _first_file_above(folder: str) -> str | None:
    """The nearest existing ancestor of `folder` that is not a folder, if any."""
    here = folder
    while True:
        if os.path.lexists(here):
            return None if os.path.isdir(here) else here
        parent = os.path.dirname(here)
        if parent == here:
            return None
        here = parent


def check_writable(path: str | os.PathLike, flag: str = "", suffix: str | None = None) -> None:
    """Refuse, before any work, a path that cannot be written as a regular file.

    The rule of every routine-gym output: missing folders are made when the file is written
    (as `mkdir -p` would), so they are fine here as long as they can be made; nothing is
    created by the check itself.

    Args:
        path: the output file.
        flag: the option that named it, for the message (`"--out"`).
        suffix: the extension of the format written there (`".npz"`), when it is fixed.

    Raises:
        UsageError: the name is not one an output should have (`check_name`), the path is a
            folder or not a regular file, a folder on its way is a file, nothing can be
            created there (read-only, no permission), or it lacks `suffix`.
    """
    check_name(path, flag)
    path = os.fspath(path)
    what = f"{flag} " if flag else ""
    if path.endswith(("/", os.sep)):
        raise UsageError(f"{what}{path} names a folder; it needs a file name")
    _check_place(os.path.dirname(os.path.abspath(path)), f"{what}{path}")
    _refuse_irregular(path, what)
    if suffix is not None and not path.lower().endswith(suffix.lower()):
        raise UsageError(f"{what}needs a file name ending in {suffix} (the format written "
                         f"there), actual value: {path}")


def check_not_an_input(out: str | os.PathLike | None, flag: str,
                       *inputs: str | os.PathLike | None) -> None:
    """Refuse an output that is one of the command's inputs, by name or through a link: it
    would be overwritten (`mine X.npz --out X.npz`, a script's `--record-demo` over its
    `--demo`). Unset inputs and outputs (None) pass.

    Raises:
        UsageError: `FLAG OUT is the input IN; it would be overwritten: choose another file`.
    """
    if out is None:
        return
    for given in inputs:
        if given is None:
            continue
        same = os.path.realpath(out) == os.path.realpath(given)
        with contextlib.suppress(OSError):
            same = same or os.path.samefile(out, given)
        if same:
            raise UsageError(f"{flag} {os.fspath(out)} is the input {os.fspath(given)}; it "
                             "would be overwritten: choose another file")


def check_folder(folder: str | os.PathLike, flag: str = "") -> None:
    """Refuse, before any work, a folder that is a file, lies under one, or cannot be made or
    written (the run folders of `--run-dir`, a sweep's `--out`); nothing is created."""
    check_name(folder, flag)
    folder = os.fspath(folder)
    what = f"{flag} " if flag else ""
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise UsageError(f"{what}{folder} is a file, not a folder")
    _check_place(os.path.abspath(folder), f"{what}{folder}")


def _check_place(folder: str, named: str) -> None:
    """Whether files can be made in `folder`, which may not exist yet (then in the nearest
    folder above it that does, where the missing ones would be made)."""
    blocker = _first_file_above(folder)
    if blocker is not None:
        raise UsageError(f"{named}: {blocker} is a file, not a folder")
    existing = folder
    while not os.path.isdir(existing):
        existing = os.path.dirname(existing)
    probe = temporary_path(os.path.join(existing, "probe"))
    try:
        with open(probe, "xb"):
            pass
        os.unlink(probe)
    except OSError as exc:
        raise UsageError(f"{named}: cannot write there ({exc.strerror})") from None


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write `text` to `path` through a temporary file in the same folder and a rename."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a temporary file of its own and a rename.

    The folder is made when missing. The file gets the permissions `open()` would give it.

    Raises:
        UsageError: `path` exists and is not a regular file (a folder, a device, a pipe), a
            folder on its way is a file, or it is no name for a file (`check_name`).
    """
    atomic_write_chunks(path, (data,))


def atomic_write_chunks(path: str | os.PathLike, chunks: Iterable[bytes]) -> None:
    """`atomic_write_bytes` of the concatenated `chunks`, written as they come, so a large
    file (a long video) is never whole in memory."""
    check_name(path)
    path = os.path.abspath(os.fspath(path))
    folder = os.path.dirname(path)
    blocker = _first_file_above(folder)
    if blocker is not None:
        raise UsageError(f"{path}: {blocker} is a file, not a folder")
    _refuse_irregular(path, "")
    os.makedirs(folder, exist_ok=True)
    _remove_stale_temporaries(path)
    tmp = temporary_path(path)
    try:
        # open() applies the umask itself; os.umask would change it for every thread.
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f:
            for chunk in chunks:
                f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            # A write's error names no file: name the target, for the one-line report.
            raise OSError(exc.errno, exc.strerror, path) from exc
        raise
