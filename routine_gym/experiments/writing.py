"""Writing a report's files: CSVs and PNGs written atomically (`Writer`, which remembers what it
wrote), and the markdown of `report.md` (tables and how numbers read)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.atomic import atomic_write_bytes, atomic_write_text
from routine_gym.experiments.reference import Reference

__all__ = ["Writer", "interval", "num", "pct", "table"]


def _cell(value: Any) -> Any:
    if isinstance(value, float | np.floating):
        return "" if not math.isfinite(value) else repr(float(value))
    return value


@dataclass
class Writer:
    """Writes the report's files atomically and remembers them; sections read the
    references, bootstrap resamples and seed of the report from it."""

    folder: Path
    references: Mapping[str, Reference]
    reps: int
    seed: int
    written: list[Path] = field(default_factory=list)

    def csv(self, name: str, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
        """`{name}.csv`: the header, then the rows (a non-finite float is an empty cell)."""
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(header)
        writer.writerows([_cell(v) for v in row] for row in rows)
        path = self.folder / f"{name}.csv"
        atomic_write_text(path, buffer.getvalue())
        self.written.append(path)

    def png(self, fig: Any, name: str) -> None:
        """`{name}.png`: the matplotlib figure `fig` at 120 dpi."""
        path = self.folder / f"{name}.png"
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=120)
        atomic_write_bytes(path, buffer.getvalue())
        self.written.append(path)


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """A markdown table, as lines, with a blank line after it."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines + [""]


def num(x: float, digits: int = 2) -> str:
    """`x` with `digits` decimals; – for none (None, NaN), n/a for an infinity (a division by
    a score of 0 or nearly)."""
    if x is None or math.isnan(x):
        return "–"
    return "n/a" if math.isinf(x) else f"{x:.{digits}f}"


def pct(x: float, digits: int = 1) -> str:
    """`x` as a percentage (`0.25` → `25.0 %`); – or n/a as `num` says."""
    text = num(None if x is None else 100 * x, digits)
    return text if text in ("–", "n/a") else f"{text} %"


def interval(estimate: tuple[float, float, float] | None, percent: bool = True,
             digits: int = 2) -> str:
    """`(point, lo, hi)` as `point [lo, hi]` (in % when `percent`, else with `digits`
    decimals); – for none, n/a for a non-finite one."""
    if estimate is None:
        return "–"
    point, lo, hi = estimate
    if not all(math.isfinite(v) for v in (point, lo, hi)):
        return "n/a"
    if percent:
        return f"{100 * point:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"
    return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
