"""What every benchmark reports beside its figures: the machine, the date and the load.

The benchmarks are scripts run as `python bench/NAME.py`, so this folder is on `sys.path` and
they import this module as `common`.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def fail(message: str) -> None:
    """Stop the benchmark with one line on stderr, `NAME.py: error: MESSAGE`, and exit code 2
    (as argparse's errors)."""
    print(f"{Path(sys.argv[0]).name}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def load_average() -> str:
    """The 1-, 5- and 15-minute load averages, e.g. `2.10 1.85 1.40`."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def timed_training_run(command: list[str], code: Path, cwd: str) -> dict:
    """Run a training script's `command` with `code` on PYTHONPATH (nothing else of the caller's
    environment) in `cwd`, and read its last progress line: `sps` (its training loop's steps per
    second), `routine_use` and `return` (its recent return; "?" where the line has none), with
    the process's `wall` seconds and the `load` averages before it. A failed run ends the
    benchmark with its command and the end of its stderr."""
    load = load_average()
    start = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True, cwd=cwd,
                          env={"PYTHONPATH": str(code), "PATH": "/usr/bin:/bin"})
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"{' '.join(command)} failed:\n{proc.stderr[-2000:]}")
    sps = [int(m) for m in re.findall(r"SPS\s+(\d+)", proc.stdout)]
    use = re.findall(r"routine use\s+([\d.]+%)", proc.stdout)
    returns = re.findall(r"return\(last 20\)\s+(\S+)", proc.stdout)
    return {"sps": sps[-1], "wall": wall, "load": load, "routine_use": use[-1] if use else "?",
            "return": returns[-1] if returns else "?"}


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def base_machine_info() -> dict[str, str]:
    """Date, CPU, cores, Python and NumPy: the part of the machine every benchmark reports."""
    return {
        "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "cpu": cpu_model(),
        "cores": f"{os.cpu_count()} (usable: {len(os.sched_getaffinity(0))})",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
    }


def memory() -> str:
    """The machine's memory from /proc/meminfo (Linux), e.g. `23.5 GiB`."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                return f"{int(line.split()[1]) / 2**20:.1f} GiB"
    except OSError:
        pass
    return "unknown"


#: The environment variables that change a benchmark's speed: threads, OpenMP's spin
#: (`routine_gym.plumbing.openmp`: a benchmark that loads a script gets the script's) and
#: malloc's handling of freed memory (`routine_gym.plumbing.memory`).
TUNING_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "GOMP_SPINCOUNT", "OMP_WAIT_POLICY",
               "ROUTINE_GYM_KEEP_MEMORY", "MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")


def tuning_env_vars() -> str:
    """The thread-count and memory environment variables set for this process (`TUNING_VARS`),
    or `none set`."""
    return ", ".join(f"{k}={os.environ[k]}" for k in TUNING_VARS if k in os.environ) \
        or "none set"


def git_head(repo: Path, paths: list[str]) -> str:
    """HEAD of `repo`, and which of `paths` (the code the benchmark runs) differ from it."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=repo,
                              capture_output=True, text=True, check=True).stdout.strip()
        status = subprocess.run(["git", "status", "--porcelain", "--", *paths], cwd=repo,
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    changed = [line[3:] for line in status.splitlines() if line.strip()]
    return head + (f" (modified: {', '.join(changed)})" if changed else "")


def descendants(pid: int) -> list[int]:
    """Every living process below `pid` (children, their children, ...), read from /proc."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:  # gone while we looked
            continue
        # `pid (comm) state ppid ...`: comm may hold spaces and parentheses, so split after it.
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if state != "Z":
            children.setdefault(int(ppid), []).append(int(entry))
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            found.append(child)
            todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _signal_all(pids: list[int], signum: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass


def children_die_with_me(grace: float = 3.0) -> None:
    """Make this benchmark's worker processes die with it on SIGTERM or SIGHUP.

    A benchmark runs the scripts as subprocesses (often from a thread pool), and they start
    their own (vector-env workers); killed by the default SIGTERM, the benchmark would leave
    them running at full CPU. The handler takes the whole tree below this process at once
    (a grandchild whose parent dies first is re-parented and could no longer be found),
    sends it SIGTERM, SIGKILLs what is still alive after `grace` seconds, and exits with
    128 + the signal at once (`os._exit`), so no thread of the pool starts another run.
    SIGINT needs nothing: a terminal's Ctrl-C reaches the whole foreground group. A SIGKILL
    of the benchmark cannot be caught; its workers then run to their end.
    """
    def handler(signum: int, frame: object) -> None:
        signal.signal(signum, signal.SIG_IGN)  # a second signal must not cut the clean-up short
        for _ in range(3):  # a pool thread may have started a run while we looked
            tree = descendants(os.getpid())
            if not tree:
                break
            _signal_all(tree, signal.SIGTERM)
            deadline = time.monotonic() + grace
            while time.monotonic() < deadline and any(_alive(p) for p in tree):
                time.sleep(0.05)
            _signal_all([p for p in tree if _alive(p)], signal.SIGKILL)
        os._exit(128 + signum)

    for signum in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, handler)
