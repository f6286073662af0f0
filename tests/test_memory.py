"""`routine_gym.plumbing.memory.keep_freed_memory`: a training step's blocks are reused instead
of being handed back to the OS and page-faulted in again on the next minibatch.

Each case runs in its own interpreter (malloc's settings are per process and cannot be undone)
and asks glibc (`mallinfo2`) where a block came from and what the heap kept of it. (What it
saves in training is measured by `bench/bench_ppo_speed.py` and `bench/bench_a2c_speed.py`;
how many page faults a training step takes by default varies with the heap's history, so it is
not asserted here.)"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

#: An 8 MiB block allocated and freed: mmapped (`hblkhd`, bytes in mmapped blocks) or from the
#: heap, and what the heap keeps at its top after the free (`keepcost`), from glibc's mallinfo2.
STEPS = textwrap.dedent("""
    import ctypes, json
    from routine_gym.plumbing.memory import keep_freed_memory

    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
            "uordblks", "fordblks", "keepcost")]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, (ctypes.c_size_t,)
    libc.free.argtypes = (ctypes.c_void_p,)
    kept = keep_freed_memory()
    before = libc.mallinfo2().hblkhd
    block = libc.malloc(8 << 20)
    mmapped = libc.mallinfo2().hblkhd - before
    libc.free(block)
    print(json.dumps({"kept": kept, "mmapped": mmapped, "keepcost": libc.mallinfo2().keepcost}))
""")


def malloc_8_mib(**env: str) -> dict:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                          "ROUTINE_GYM_KEEP_MEMORY")}
    out = subprocess.run([sys.executable, "-c", STEPS], env={**clean, **env}, check=True,
                         capture_output=True, text=True, timeout=120)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_a_freed_block_stays_in_the_heap_for_the_next_one():
    kept, default = malloc_8_mib(), malloc_8_mib(ROUTINE_GYM_KEEP_MEMORY="0")
    assert kept["kept"] is True and default["kept"] is False
    # glibc's default maps a fresh 8 MiB block from the OS (its first mmap threshold is
    # 128 KiB) and unmaps it on free: the next one is faulted in page by page again.
    assert default["mmapped"] >= 8 << 20
    # Kept: the block comes from the heap and is still at its top after the free.
    assert kept["mmapped"] == 0
    assert kept["keepcost"] >= 8 << 20


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_glibc_variables_set_by_the_user_win():
    # The user's 1 MiB mmap threshold holds: the 8 MiB block is mmapped as by default.
    mine = malloc_8_mib(MALLOC_MMAP_THRESHOLD_="1048576")
    assert mine["kept"] is True
    assert mine["mmapped"] >= 8 << 20
