"""Where and for how long a run ran, kept in its `result.json` as `provenance`: a run of the
long budget trains for hours, resumed after kills, lost sessions and on other machines, so the
wall time of its last process alone (`seconds`) says little.

An attempt is one process of the run's script (its start, or a resume from its checkpoint).
The sweep notes each attempt in the run's folder, `OUT/runs/KEY/attempts.json`, when it starts
and every `NOTE_EVERY` seconds while it runs (`Attempts`), so an attempt killed with its sweep
loses at most that much of its count. The finished run's `provenance`:

    wall_seconds    the wall time of the attempts its training is made of: the last start
                    and the resumes after it (an attempt killed before its first checkpoint
                    was started over, and its time is not the run's)
    machine         the machine of the attempt that finished it (`machine()`)
    attempts        every attempt: `started` (UTC), `resumed`, `seconds`, `machine`
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import socket
import time
from pathlib import Path
from typing import Any

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import UsageError
from routine_gym.experiments import read_json_object, utc_now

__all__ = ["NOTE_EVERY", "Attempts", "machine", "wall_seconds"]

#: Seconds between the notes of a running attempt's wall time.
NOTE_EVERY = 60.0


def _cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (Linux), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict[str, Any]:
    """This machine: its host name, CPU model, cores (all, and usable by this process), OS and
    Python."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {"host": socket.gethostname(), "cpu": _cpu_model(), "cores": os.cpu_count(),
            "usable_cores": usable, "platform": platform.platform(),
            "python": platform.python_version()}


def _attempt_rows(value: Any) -> bool:
    return isinstance(value, list) and all(
        isinstance(a, dict) and isinstance(a.get("seconds"), int | float) for a in value)


class Attempts:
    """The attempts of one run, noted in `folder/attempts.json` (see the module docstring).

    A record that cannot be read (corrupt, of another shape) is started afresh: it is
    provenance, and never stops a run.
    """

    def __init__(self, folder: Path, resumed: bool) -> None:
        self.path = folder / "attempts.json"
        self.rows: list[dict[str, Any]] = []
        if self.path.exists():
            try:
                rows = read_json_object(self.path).get("attempts")
            except UsageError:
                rows = None
            self.rows = rows if _attempt_rows(rows) else []
        self.start = time.time()
        self.rows.append({"started": utc_now(), "resumed": resumed, "seconds": 0.0,
                          "machine": machine()})
        self.note()

    def note(self) -> None:
        """Write this attempt's wall time so far (a folder that cannot be written now keeps
        the older note: the run goes on)."""
        self.rows[-1]["seconds"] = round(time.time() - self.start, 1)
        with contextlib.suppress(OSError):
            atomic_write_text(self.path, json.dumps({"attempts": self.rows}, indent=2) + "\n")

    def record(self) -> dict[str, Any]:
        """The run's `provenance` (noting this attempt's time first)."""
        self.note()
        return {"wall_seconds": wall_seconds(self.rows), "machine": self.rows[-1]["machine"],
                "attempts": self.rows}


def wall_seconds(attempts: list[dict[str, Any]]) -> float:
    """The seconds of the last attempt that started afresh and of the resumes after it.

    Example (killed before its first checkpoint, started over, killed, resumed):
        >>> wall_seconds([{"resumed": False, "seconds": 50.0},
        ...               {"resumed": False, "seconds": 3600.0},
        ...               {"resumed": True, "seconds": 1800.5}])
        5400.5
    """
    fresh = max((i for i, a in enumerate(attempts) if not a.get("resumed")), default=0)
    return round(sum(a["seconds"] for a in attempts[fresh:]), 1)
