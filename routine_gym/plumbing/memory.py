"""Keep the memory torch frees for the next minibatch instead of giving it back to the OS.

glibc's `malloc` serves a large block (a minibatch's activations: MinAtar PPO's 1,024 states ×
1,024 features are 4 MiB) by `mmap` and returns it to the OS on `free`, and trims the top of
its heap once more than a few hundred KiB there are free. The next minibatch asks for the same
blocks again, and the kernel zero-fills them page by page. On MinAtar's small network a
1,500-state forward and backward pass took 26 ms by default and 19.5 ms with the blocks kept
(one thread; 14–20 ms and 12.8 ms on two), and whole runs of `bench/bench_ppo_speed.py` gained
17 % for PPO and 6 % for RAPL-PPO (A2C's small batches: nothing). Raising both thresholds keeps
the blocks in the heap for reuse; the numbers computed are the same, the process holds on to its
peak memory.

`check_memory(nbytes, what)` refuses, with one line, storage that could not fit: the rollout or
replay storage a script is about to allocate, sized by its flags at the env's real observation
size (the flags' own upper bounds are in `routine_gym.plumbing.arguments.DOMAINS`).

`keep_freed_memory()` does that where the C library is glibc (Linux) and nothing elsewhere; the
variables `MALLOC_MMAP_THRESHOLD_` and `MALLOC_TRIM_THRESHOLD_`, when set, win (glibc's own
tuning names), and `ROUTINE_GYM_KEEP_MEMORY=0` leaves malloc as it is.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
from typing import Any

__all__ = ["available_memory", "check_memory", "check_rollout_memory", "keep_freed_memory"]

#: `mallopt`'s parameters (glibc's malloc.h).
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
#: Blocks up to this size come from the heap (glibc accepts at most 32 MiB on 64-bit).
MMAP_THRESHOLD = 32 << 20
#: Free memory kept at the top of the heap before glibc gives it back.
TRIM_THRESHOLD = 512 << 20


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds for this process; True if they were set."""
    if os.environ.get("ROUTINE_GYM_KEEP_MEMORY", "1") == "0":
        return False
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):  # not glibc (macOS, musl, Windows)
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    done = True
    if "MALLOC_MMAP_THRESHOLD_" not in os.environ:
        done &= mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        done &= mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
    return bool(done)


def available_memory() -> int | None:
    """The bytes the machine can still give a process (Linux's `MemAvailable`; else the free
    physical pages), or None where neither is known."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _size(nbytes: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if nbytes < 1000:
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1000
    return f"{nbytes:,.0f} TB"


def check_memory(nbytes: int, what: str) -> None:
    """Refuse storage of `nbytes` bytes that exceeds the memory available now.

    Args:
        nbytes: the bytes about to be allocated.
        what: what they are, with the flags that size them (`"the rollout storage
            (--num-steps 4,096 × --num-envs 1,024)"`).

    Raises:
        UsageError: `{what} needs {size}, more than the {size} of memory available`.
    """
    from routine_gym.plumbing.errors import UsageError

    available = available_memory()
    if available is not None and nbytes > available:
        raise UsageError(f"{what} needs {_size(nbytes)}, more than the {_size(available)} of "
                         "memory available")


def check_rollout_memory(obs_space: Any, num_steps: int, num_envs: int, *,
                         observations: int = 1, numbers: int = 8) -> None:
    """`check_memory` for a rollout of `num_steps × num_envs` steps, each keeping
    `observations` observations of `obs_space` and `numbers` 8-byte numbers (rewards, values,
    actions, flags), named by the flags that size it."""
    import numpy as np

    obs_bytes = int(np.prod(obs_space.shape)) * np.dtype(obs_space.dtype).itemsize
    nbytes = num_steps * num_envs * (observations * obs_bytes + 8 * numbers)
    check_memory(nbytes, f"the rollout storage (--num-steps {num_steps:,} × --num-envs "
                         f"{num_envs:,} × {observations:,} observation(s) of {_size(obs_bytes)})")
