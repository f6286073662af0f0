"""A reader that stops reading (`routine-gym experiment list | head -1`) ends the command
quietly, as `ls | head` does: no traceback on stderr."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def test_a_closed_pipe_ends_a_command_without_a_traceback(tmp_path):
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path), "LANG": "C.UTF-8"}
    # The reader (`true`) has exited before the command writes its first line.
    proc = subprocess.run(["bash", "-c", "(sleep 1; exec routine-gym experiment list) | true; "
                           "echo \"rc=${PIPESTATUS[0]}\""], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert "Traceback" not in proc.stderr and "BrokenPipeError" not in proc.stderr
    assert proc.stderr == "" and proc.stdout.strip() == "rc=141"
