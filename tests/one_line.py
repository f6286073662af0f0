"""The one check of a user's mistake reported by a real process: exit code 2, exactly one line
on stderr, no traceback, and every name the message must carry.

The test files import this module by name: pytest puts `tests/` on `sys.path`.
"""

from __future__ import annotations

import subprocess


def assert_one_line_error(proc: subprocess.CompletedProcess, *names: str,
                          prefix: str = "") -> str:
    """The one line `proc` printed on stderr; it starts with `prefix` and holds every name."""
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2, (proc.returncode, proc.stdout[-2000:], proc.stderr[-3000:])
    assert len(lines) == 1, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    assert lines[0].startswith(prefix), (prefix, lines[0])
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]
