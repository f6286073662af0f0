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

`keep_freed_memory()` does that where the C library is glibc (Linux) and nothing elsewhere; the
variables `MALLOC_MMAP_THRESHOLD_` and `MALLOC_TRIM_THRESHOLD_`, when set, win (glibc's own
tuning names), and `ROUTINE_GYM_KEEP_MEMORY=0` leaves malloc as it is.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

__all__ = ["keep_freed_memory"]

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
