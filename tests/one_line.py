"""The one check of a user's mistake reported by a real process: exit code 2, exactly one line
on stderr, no traceback, and every name the message must carry.

The test files import this module by name: pytest puts `tests/` on `sys.path`.
"""

from __future__ import annotations

import subprocess


def stderr_lines(stderr: str) -> list[str]:
    """The non-blank lines of `stderr`, less the one warning (and the source line Python prints
    under it) of each compiled core that was not built: an install without a C++ compiler
    gives it once per core a process wants (`routine_gym._native.core`), beside its error."""
    lines, skip = [], False
    for line in stderr.splitlines():
        if skip and line.startswith(" "):
            skip = False
            continue
        skip = "RuntimeWarning: the compiled core '" in line and "is not built" in line
        if not skip and line.strip():
            lines.append(line)
    return lines


def assert_one_line_error(proc: subprocess.CompletedProcess, *names: str,
                          prefix: str = "") -> str:
    """The one line `proc` printed on stderr; it starts with `prefix` and holds every name."""
    lines = stderr_lines(proc.stderr)
    assert proc.returncode == 2, (proc.returncode, proc.stdout[-2000:], proc.stderr[-3000:])
    assert len(lines) == 1, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    assert lines[0].startswith(prefix), (prefix, lines[0])
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]
