"""What every benchmark reports beside its figures: the machine, the date and the load.

The benchmarks are scripts run as `python bench/NAME.py`, so this folder is on `sys.path` and
they import this module as `common`.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
from pathlib import Path

import numpy as np


def load_average() -> str:
    """The 1-, 5- and 15-minute load averages, e.g. `2.10 1.85 1.40`."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


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
