"""What the kill-and-resume tests share: a script killed (SIGKILL: no clean-up, no final
checkpoint) as soon as it has saved a checkpoint, and exact equality of saved states.

The test files import this module by name: pytest puts `tests/` on `sys.path`.
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import torch


def kill_after_first_checkpoint(command: list[str], run_dir: Path, timeout: float = 60,
                                poll: float = 0.01) -> Path:
    """Run `command`, SIGKILL it once a `checkpoint.pt` appears in a run folder under `run_dir`,
    and return that checkpoint's path. Fails if the script exits first or no checkpoint comes
    within `timeout` seconds, or if the run finished before it could be killed."""
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + timeout
        while not list(run_dir.glob("*/checkpoint.pt")):
            assert proc.poll() is None, proc.stdout.read().decode()
            assert time.monotonic() < deadline, f"no checkpoint within {timeout:g} s"
            time.sleep(poll)
        proc.send_signal(signal.SIGKILL)  # a crash: no clean-up, no final checkpoint
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL, "the run finished before it could be killed"
    (checkpoint_path,) = run_dir.glob("*/checkpoint.pt")
    return checkpoint_path


def assert_same(a, b) -> None:
    """Nested dicts and lists of tensors and numbers are exactly equal."""
    assert type(a) is type(b)
    if isinstance(a, torch.Tensor):
        assert torch.equal(a, b)
    elif isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            assert_same(x, y)
    else:
        assert a == b
