"""Training curves (Fig. 3): a run's training episodes read from its TensorBoard log and binned
on a common step grid.

The sweep keeps each finished run's binned curve in its `result.json` (`curve_bins`), so a
report of a snapshot needs no TensorBoard log; `run_curve` reads it back, or the log when the
grid differs. TensorBoard loads when a log is read.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from routine_gym.experiments.results import RunRecord

__all__ = ["CURVE_BINS", "RETURN_TAG", "bin_curve", "curve_bins", "curve_folder",
           "curve_values", "read_episodic_returns", "read_scalars", "run_curve"]

#: Step bins of a training curve (Fig. 3) from 0 to the run's budget.
CURVE_BINS = 50
RETURN_TAG = "charts/episodic_return"


def _event_file_order(path: Path) -> tuple[int, str]:
    # events.out.tfevents.{unix time}.{host}...: a resumed run's file is the later one.
    parts = path.name.split(".")
    stamp = int(parts[3]) if len(parts) > 3 and parts[3].isdigit() else 0
    return stamp, path.name


def read_scalars(folder: str | Path, tags: Sequence[str] | None = None
                 ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """`{tag: (steps, values)}` of the scalars a run logged to TensorBoard (every tag, or
    `tags`), read from every event file in `folder`. A resumed run logs into a new file from
    its checkpoint on; what an older file logged at or after the newer file's first step of a
    tag was lost with the killed process and is dropped."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    points: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(Path(folder).glob("events.out.tfevents.*"), key=_event_file_order):
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        for tag in events.Tags()["scalars"]:
            if tags is not None and tag not in tags:
                continue
            new = [(e.step, e.value) for e in events.Scalars(tag)]
            if new:
                first = min(step for step, _ in new)
                points[tag] = [p for p in points.get(tag, []) if p[0] < first] + new
    out = {}
    for tag, kept in points.items():
        kept.sort(key=lambda p: p[0])
        out[tag] = (np.array([p[0] for p in kept], dtype=np.int64),
                    np.array([p[1] for p in kept], dtype=np.float64))
    return out


def read_episodic_returns(folder: str | Path, tag: str = RETURN_TAG
                          ) -> tuple[np.ndarray, np.ndarray]:
    """`(steps, returns)` of the training episodes a run logged to TensorBoard under `tag`
    (`read_scalars`)."""
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.float64))
    return read_scalars(folder, [tag]).get(tag, empty)


def curve_bins(steps: Sequence[int] | np.ndarray, returns: Sequence[float] | np.ndarray,
               total_steps: int, bins: int = CURVE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """`(sums, counts)`: the summed return and the number of the episodes that ended in each of
    `bins` equal step bins from 0 to `total_steps` (bin `b` is `(b·w, (b+1)·w]`,
    `w = total_steps / bins`; episodes past `total_steps` count in the last bin). What a sweep
    keeps of a run's training curve (`result.json`'s `curve`), so the report needs no
    TensorBoard log.

    Example:
        >>> sums, counts = curve_bins([3, 4, 9], [5.0, 7.0, 2.0], total_steps=10, bins=5)
        >>> sums.tolist(), counts.tolist()
        ([0.0, 12.0, 0.0, 0.0, 2.0], [0, 2, 0, 0, 1])
    """
    if bins < 1 or total_steps <= 0:
        raise ValueError(f"bins and total_steps need to be ≥ 1, actual values: {bins}, "
                         f"{total_steps}")
    edges = np.linspace(0.0, float(total_steps), bins + 1)
    steps = np.asarray(steps, dtype=np.float64)
    returns = np.asarray(returns, dtype=np.float64)
    index = np.clip(np.searchsorted(edges[1:], steps, side="left"), 0, bins - 1)
    return (np.bincount(index, weights=returns, minlength=bins),
            np.bincount(index, minlength=bins))


def curve_values(sums: Sequence[float] | np.ndarray, counts: Sequence[int] | np.ndarray
                 ) -> np.ndarray:
    """Each bin's mean return from `curve_bins`' sums and counts; an empty bin carries the
    previous value forward, and bins before the first episode are NaN."""
    values = np.full(len(sums), np.nan)
    last = np.nan
    for b, (total, count) in enumerate(zip(sums, counts, strict=True)):
        if count:
            last = total / count
        values[b] = last
    return values


def bin_curve(steps: Sequence[int] | np.ndarray, returns: Sequence[float] | np.ndarray,
              total_steps: int, bins: int = CURVE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """A training curve on a common grid: `bins` equal step bins from 0 to `total_steps`.

    The value at `x` (a bin's right edge) is the mean return of the episodes that ended in
    `(x − w, x]`, `w = total_steps / bins`; an empty bin carries the previous value forward,
    and bins before the first episode are NaN. Episodes past `total_steps` count in the last
    bin.

    Example:
        >>> x, y = bin_curve([3, 4, 9], [5.0, 7.0, 2.0], total_steps=10, bins=5)
        >>> x.tolist(), y.tolist()
        ([2.0, 4.0, 6.0, 8.0, 10.0], [nan, 6.0, 6.0, 6.0, 2.0])
    """
    sums, counts = curve_bins(steps, returns, total_steps, bins)
    return np.linspace(0.0, float(total_steps), bins + 1)[1:], curve_values(sums, counts)


def run_curve(run: RunRecord, total: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A run's binned curve `(x, values)` on the grid `(0, total]`: from its `result.json` when
    the sweep kept it there on this grid, else from its TensorBoard log (a manifest without
    steps: the grid ends at its last episode); None when it logged no episode."""
    kept = run.result.get("curve")
    if kept and kept.get("bins") == CURVE_BINS and kept.get("total_steps") == total:
        if not any(kept["counts"]):
            return None
        x = np.linspace(0.0, float(total), CURVE_BINS + 1)[1:]
        return x, curve_values(kept["sums"], kept["counts"])
    steps, returns = read_episodic_returns(curve_folder(run))
    if steps.size == 0:
        return None
    return bin_curve(steps, returns, total or max(int(steps.max()), 1))


def curve_folder(run: RunRecord) -> Path:
    """The folder of a run's TensorBoard log: the script's run folder named in `result.json`,
    else the first one holding an event file."""
    run_dir = run.result.get("run_dir")
    if run_dir and (run.folder / run_dir).is_dir():
        return run.folder / run_dir
    found = sorted(run.folder.glob("*/events.out.tfevents.*"))
    return found[0].parent if found else run.folder / (run_dir or "")
