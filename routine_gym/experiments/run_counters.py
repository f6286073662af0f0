"""What a run counted, kept in its `result.json` so a snapshot explains itself without the
TensorBoard logs (issue: why RAPL-A2C loses to A2C).

The scripts log `counters/*` at every update (`routine_gym.plumbing.counters`); the sweep
reads them back (`counter_record`) into `result.json`'s `counters`:

    decisions, updates, primitive_steps     the run's totals
    steps_per_decision                      primitive_steps / decisions
    interruptions, interrupted_share        with a stop rule (`--interrupt`): the routines it
                                            stopped early, and their share of the routine
                                            calls (absent without one)
    primitive_share, shares                 the share of all decisions that chose a primitive
                                            action, and each routine (option)
    episode_length                          the mean length of its training episodes
    bins                                    the same on the training curve's grid: the totals
                                            at each bin's end, the rates within each bin

The grid is `CURVE_BINS` equal bins of primitive steps from 0 to `total_steps` (bin `b` is
`(b·w, (b+1)·w]`), the grid of the run's kept training curve.

The report reads them back with `run_counter` (a total or rate of one run), `mean_bins` (a
binned counter's mean over runs) and `mean_routine_shares` (each routine's binned share).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.training_curves import CURVE_BINS, curve_bins

__all__ = ["COUNTER_TAG_PREFIXES", "counter_record", "mean_bins", "mean_routine_shares",
           "run_counter"]

#: The tags the sweep reads for `counter_record`.
COUNTER_TAG_PREFIXES = ("counters/", "charts/episodic_length")

_Series = tuple[np.ndarray, np.ndarray]


def _number(value: float) -> float | None:
    """A JSON number: None for NaN."""
    return None if value is None or math.isnan(value) else round(float(value), 6)


def _bin_index(steps: np.ndarray, total_steps: int, bins: int) -> np.ndarray:
    edges = np.linspace(0.0, float(total_steps), bins + 1)
    return np.clip(np.searchsorted(edges[1:], steps.astype(np.float64), side="left"), 0,
                   bins - 1)


def _weighted(values: np.ndarray, weights: np.ndarray, index: np.ndarray, bins: int
              ) -> np.ndarray:
    """The `weights`-weighted mean of `values` in each bin (NaN for a bin without weight)."""
    total = np.bincount(index, weights=weights, minlength=bins)
    summed = np.bincount(index, weights=weights * values, minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0, summed / np.where(total > 0, total, 1), np.nan)


def _last_in_bins(values: np.ndarray, index: np.ndarray, bins: int) -> np.ndarray:
    """Each bin's last value, carried forward over bins without one (0 before the first)."""
    out = np.zeros(bins)
    for b, v in zip(index, values, strict=True):
        out[b] = v  # steps come sorted, so the last write of a bin is its last value
    seen = np.zeros(bins, dtype=bool)
    seen[index] = True
    for b in range(1, bins):
        if not seen[b]:
            out[b] = out[b - 1]
    return out


def counter_record(scalars: dict[str, _Series], total_steps: int | None = None,
                   bins: int = CURVE_BINS) -> dict[str, Any] | None:
    """A run's counters from its TensorBoard scalars (`read_scalars`): None when it logged none.

    Args:
        scalars: `{tag: (steps, values)}` with at least `counters/decisions` and
            `counters/updates`; the shares, steps per decision and episode lengths where logged.
        total_steps: the grid's end in primitive steps (None: the run's last logged step).
        bins: the number of bins.

    Example (two updates of 4 decisions each, the second with one routine of 3 steps):
        >>> import numpy as np
        >>> s = {"counters/decisions": (np.array([4, 10]), np.array([4.0, 8.0])),
        ...      "counters/updates": (np.array([4, 10]), np.array([1.0, 2.0])),
        ...      "counters/primitive_share": (np.array([4, 10]), np.array([1.0, 0.75])),
        ...      "counters/share_0": (np.array([4, 10]), np.array([0.0, 0.25]))}
        >>> r = counter_record(s, total_steps=10, bins=2)
        >>> r["decisions"], r["updates"], r["primitive_steps"], r["steps_per_decision"]
        (8, 2, 10, 1.25)
        >>> r["primitive_share"], r["shares"]
        (0.875, [0.125])
        >>> r["bins"]["steps_per_decision"], r["bins"]["updates"], r["bins"]["shares"]
        ([1.0, 1.5], [1, 2], [[0.0, 0.25]])
        >>> "interruptions" in r  # no stop rule, no interruptions
        False

    With a stop rule that stopped that one routine call, 1 of the run's 0·4 + 0.25·4 calls:
        >>> s["counters/interruptions"] = (np.array([4, 10]), np.array([0.0, 1.0]))
        >>> r = counter_record(s, total_steps=10, bins=2)
        >>> r["interruptions"], r["interrupted_share"]
        (1, 1.0)
    """
    if "counters/decisions" not in scalars or "counters/updates" not in scalars:
        return None
    steps, decisions = scalars["counters/decisions"]
    if steps.size == 0:
        return None
    updates = scalars["counters/updates"][1]
    total = int(total_steps or steps[-1]) or 1
    made = np.diff(np.concatenate([[0.0], decisions])).clip(min=0)  # decisions per window
    ran = np.diff(np.concatenate([[0], steps])).clip(min=0).astype(np.float64)
    index = _bin_index(steps, total, bins)
    window_made = dict(zip(steps.tolist(), made.tolist(), strict=True))

    def share(tag: str) -> tuple[float, np.ndarray]:
        at, values = scalars[tag]
        weights = np.array([window_made.get(s, 0.0) for s in at.tolist()])
        mean = float((weights * values).sum() / weights.sum()) if weights.sum() else math.nan
        return mean, _weighted(values, weights, _bin_index(at, total, bins), bins)

    record: dict[str, Any] = {
        "decisions": int(decisions[-1]), "updates": int(updates[-1]),
        "primitive_steps": int(steps[-1]),
        "steps_per_decision": _number(steps[-1] / decisions[-1]) if decisions[-1] else None,
    }
    num_shares = 0
    while f"counters/share_{num_shares}" in scalars:
        num_shares += 1
    primitive = share("counters/primitive_share") \
        if "counters/primitive_share" in scalars else (math.nan, np.full(bins, np.nan))
    shares = [share(f"counters/share_{k}") for k in range(num_shares)]
    record["primitive_share"] = _number(primitive[0])
    record["shares"] = [_number(mean) for mean, _ in shares]
    if "counters/interruptions" in scalars and scalars["counters/interruptions"][1].size:
        stops = float(scalars["counters/interruptions"][1][-1])
        at, values = scalars.get("counters/primitive_share", (np.zeros(0), np.zeros(0)))
        calls = sum(window_made.get(step, 0.0) * (1.0 - value)  # the windows' routine calls
                    for step, value in zip(at.tolist(), values.tolist(), strict=True))
        record["interruptions"] = int(stops)
        record["interrupted_share"] = _number(stops / calls) if calls > 0 else None
    lengths = scalars.get("charts/episodic_length")
    record["episode_length"] = _number(float(lengths[1].mean())) \
        if lengths is not None and lengths[1].size else None

    with np.errstate(invalid="ignore", divide="ignore"):
        per_bin_made = np.bincount(index, weights=made, minlength=bins)
        per_bin_ran = np.bincount(index, weights=ran, minlength=bins)
        steps_per_decision = np.where(per_bin_made > 0, per_bin_ran / per_bin_made, np.nan)
    if lengths is not None and lengths[1].size:
        sums, counts = curve_bins(lengths[0], lengths[1], total, bins)
        with np.errstate(invalid="ignore", divide="ignore"):
            episode_length = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    else:
        episode_length = np.full(bins, np.nan)
    record["bins"] = {
        "total_steps": total, "bins": bins,
        "decisions": [int(v) for v in _last_in_bins(decisions, index, bins)],
        "updates": [int(v) for v in _last_in_bins(updates, index, bins)],
        "steps_per_decision": [_number(v) for v in steps_per_decision],
        "primitive_share": [_number(v) for v in primitive[1]],
        "shares": [[_number(v) for v in per_bin] for _, per_bin in shares],
        "episode_length": [_number(v) for v in episode_length],
    }
    return record


def run_counter(run: RunRecord, field: str) -> float:
    """A counter of the run's `result.json` (NaN for a run that predates the counters)."""
    value = (run.result.get("counters") or {}).get(field)
    return math.nan if value is None else float(value)


def _nanmean_rows(rows: list[list[float | None]]) -> np.ndarray:
    """The mean over rows of equal length, bin by bin, leaving out None and NaN (NaN where no
    row has a value)."""
    values = np.array([[math.nan if v is None else v for v in row] for row in rows],
                      dtype=np.float64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a bin no run has: NaN
        return np.nanmean(values, axis=0)


def mean_bins(runs: Sequence[RunRecord], field: str) -> np.ndarray | None:
    """The mean over runs of a counter's bins (`result.json` counters), NaN where none."""
    rows = []
    for run in runs:
        bins = (run.result.get("counters") or {}).get("bins") or {}
        values = bins.get(field)
        if values:
            rows.append(values)
    if not rows:
        return None
    return _nanmean_rows(rows)


def mean_routine_shares(runs: Sequence[RunRecord]) -> np.ndarray | None:
    """`(routines, bins)`: the mean over runs of the share of decisions that chose each routine
    in each bin (`bins.shares`); a routine a run does not have counts as missing there, not as
    0. None when no run has a routine's share (A2C, or runs that predate the counters).

    Example (two runs of one routine and one run of two, over two bins):
        >>> from pathlib import Path
        >>> def run(shares):
        ...     return RunRecord("k", "RAPL-A2C", "g", 1, {}, "main", 4, Path("."),
        ...                      {"counters": {"bins": {"shares": shares}}})
        >>> mean_routine_shares([run([[0.25, 0.5]]), run([[0.75, 0.25], [0.125, None]])]).tolist()
        [[0.5, 0.375], [0.125, nan]]
    """
    tables = [((run.result.get("counters") or {}).get("bins") or {}).get("shares") or []
              for run in runs]
    count = max((len(t) for t in tables), default=0)
    if count == 0:
        return None
    bins = max(len(row) for t in tables for row in t)
    return np.vstack([_nanmean_rows([t[k] for t in tables if k < len(t)] or [[None] * bins])
                      for k in range(count)])
