"""Running a script of `bench/` as a user runs it: its own process, this interpreter, nothing of
the suite's set-up but the environment it inherits."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent.parent / "bench"


def run_bench(script: str, *words, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`python bench/{script} WORDS…` from `cwd`, its output captured as text (300 s at most)."""
    return subprocess.run([sys.executable, str(BENCH_DIR / script), *map(str, words)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)
