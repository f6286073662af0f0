"""Errors a user can make, and how every script and CLI command reports them.

`UsageError` is a user's mistake (a bad file, a bad flag or value, an env the scripts cannot handle,
a bad checkpoint). It subclasses `ValueError`, so library callers that catch `ValueError` still do.
The scripts in `algos/` (through `routine_gym.plumbing.run.run_script`) and the `routine-gym`
command print it as one line on stderr, `SCRIPT: error: MESSAGE`, and exit with code 2, without a
traceback; so do Gymnasium's own errors (an unknown env id) and a missing file. `--debug` (or
`ROUTINE_GYM_DEBUG=1` in the environment) shows the traceback instead. Anything else is a bug and
keeps its traceback. A training run that diverges (`routine_gym.plumbing.divergence`) is one line
too, with exit code 3: the command was valid, the run diverged. A full disk (or quota)
(`disk_full`) is one line with exit code 1, saying that nothing already written was lost
(every file is written whole through `routine_gym.atomic`, so the last checkpoint is intact).
"""

from __future__ import annotations

import errno
import os
import sys

__all__ = ["UsageError", "debug_requested", "disk_full", "expected_errors", "one_line"]

#: The exit code of a run or command stopped by a full disk (2 is a user's mistake).
DISK_FULL_EXIT = 1

#: The exit code of a training run that diverged (`routine_gym.plumbing.divergence`).
DIVERGED_EXIT = 3

#: The environment variable that turns one-line errors back into tracebacks.
DEBUG_VARIABLE = "ROUTINE_GYM_DEBUG"


class UsageError(ValueError):
    """A user's mistake, reported as one line naming the file, flag or value."""


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (continuation lines joined with "; ")."""
    text = str(exc) or type(exc).__name__
    return "; ".join(part.strip() for part in text.splitlines() if part.strip())


def disk_full(exc: BaseException) -> str | None:
    """The one line that reports `exc` when it is a full disk or an exhausted quota
    (`ENOSPC`, `EDQUOT`), naming the file being written; None for anything else."""
    if not isinstance(exc, OSError) or exc.errno not in (errno.ENOSPC, errno.EDQUOT):
        return None
    where = f" while writing {exc.filename}" if exc.filename else ""
    return (f"{os.strerror(exc.errno).lower()}{where}; nothing written before was lost "
            "(files are written whole or not at all: the last checkpoint, if any, is intact); "
            "free some space and run the command again (--resume RUN goes on from the "
            "checkpoint)")


def expected_errors() -> tuple[type[BaseException], ...]:
    """The exception types reported as one line: ours, a missing file, Gymnasium's."""
    kinds: list[type[BaseException]] = [UsageError, FileNotFoundError]
    gym_error = sys.modules.get("gymnasium.error")
    if gym_error is not None:
        kinds.append(gym_error.Error)
    return tuple(kinds)


def debug_requested(argv: list[str]) -> bool:
    """Whether `--debug` is in `argv` (it is removed) or `ROUTINE_GYM_DEBUG` is set."""
    found = "--debug" in argv
    while "--debug" in argv:
        argv.remove("--debug")
    return found or os.environ.get(DEBUG_VARIABLE, "") not in ("", "0")
