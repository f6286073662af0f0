"""`ScalarWriter`: TensorBoard's `SummaryWriter`, one event per step for the scalars of a step.

A training script logs a dozen scalars at the same `global_step` (losses, learning rate, SPS,
the counters), every `--scalars-every` updates (`routine_gym.plumbing.run.ScalarsDue`).
`SummaryWriter.add_scalar` makes one event per scalar; this writer keeps the scalars of the
current step and writes them as one event (one `Summary` with several values) when the step
changes, on `flush()`, on `close()` and at exit, through `SummaryWriter`'s own file writer.
TensorBoard (and `EventAccumulator`, `tbparse`, ...) reads back the same tags, steps and float32
values; only the events' wall times are shared by the scalars of one step.

Why one event per step: `mirror`, when given, is called with each event's step and its
`(tag, value)` pairs as the event is written, the values as TensorBoard stores them: `--track`
logs them to Weights & Biases this way (`routine_gym.plumbing.tracking`), one row per step, so
both sinks hold the same scalars. (It was also a speed measure when the scripts logged every
update, about 375 events a second on MinAtar; at one update in 100 the cost is gone either way.)

A run that ends on an exception does not close its writer: its last step's scalars and the
events still queued for TensorBoard's writer thread reach the file at exit all the same.

One file handle per event file: without TensorFlow, TensorBoard's writer thread appends each
event through its stand-in `GFile`, which opens and closes the file for every record (an
`open`/`write`/`close` per episode's scalars, some 7,000 a 200k-step MinAtar Breakout run, that
doubled the run's system time). `ScalarWriter` hands the thread's `RecordWriter` one buffered
file opened once in append mode instead; the records, their checksums and the file's name are
TensorBoard's. With another TensorBoard whose writer is not laid out so, its own is kept.
`flush()` (the scripts' checkpoints call it) puts every event so far on disk.

Example:
    >>> import tempfile
    >>> from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    >>> folder = tempfile.mkdtemp()
    >>> writer = ScalarWriter(folder)
    >>> for step in (10, 20):
    ...     writer.add_scalar("losses/a", step / 4, step)
    ...     writer.add_scalar("losses/b", -step, step)
    >>> writer.close()
    >>> events = EventAccumulator(folder); _ = events.Reload()
    >>> [(e.step, e.value) for e in events.Scalars("losses/a")]
    [(10, 2.5), (20, 5.0)]
    >>> [(e.step, e.value) for e in events.Scalars("losses/b")]
    [(10, -10.0), (20, -20.0)]
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
from tensorboard.compat.proto.summary_pb2 import Summary
from torch.utils.tensorboard import SummaryWriter

__all__ = ["ScalarWriter"]


class ScalarWriter(SummaryWriter):
    """A `SummaryWriter` whose `add_scalar` groups the scalars of one step into one event.

    Args:
        mirror: called as `mirror(step, [(tag, value), ...])` for each scalar event written
            (None: TensorBoard alone). The other arguments are `SummaryWriter`'s.
    """

    def __init__(self, *args: Any,
                 mirror: Callable[[int, list[tuple[str, float]]], None] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.mirror = mirror
        self._step: int | None = None
        self._values: list[Summary.Value] = []
        # A run that ends on an exception does not close its writer: the last step's scalars,
        # and what TensorBoard's writer thread still holds, go to the file at exit.
        weakref.finalize(self, _close_at_exit, weakref.ref(self))

    def add_scalar(self, tag: str, scalar_value: Any, global_step: int | None = None,
                   walltime: float | None = None, new_style: bool = False,
                   double_precision: bool = False) -> None:
        if global_step is None or walltime is not None or new_style or double_precision:
            self._write_pending()
            super().add_scalar(tag, scalar_value, global_step, walltime, new_style,
                               double_precision)
            if self.mirror is not None:  # the event's step is 0 when none is given
                value = float(scalar_value)
                self.mirror(0 if global_step is None else global_step,
                            [(tag, value if double_precision else float(np.float32(value)))])
            return
        if global_step != self._step:
            self._write_pending()
            self._step = global_step
        # `SummaryWriter.add_scalar` stores float(value) as the proto's float32 simple_value;
        # built here, so protobuf refuses a bad tag at this call, not at a later write.
        self._values.append(Summary.Value(tag=tag, simple_value=float(scalar_value)))

    def _write_pending(self) -> None:
        if self._values:
            values, self._values = self._values, []
            self._get_file_writer().add_summary(Summary(value=values), self._step, time.time())
            if self.mirror is not None:  # the values as the event stores them: float32
                self.mirror(self._step, [(v.tag, v.simple_value) for v in values])

    def _get_file_writer(self) -> Any:
        fresh = self.all_writers is None or self.file_writer is None
        writer = super()._get_file_writer()
        if fresh:  # a new event file (the first, or the next after close())
            _append_through_one_handle(writer)
        return writer

    def flush(self) -> None:
        self._write_pending()
        super().flush()

    def close(self) -> None:
        self._write_pending()
        super().close()


def _append_through_one_handle(file_writer: Any) -> bool:
    """Give `file_writer`'s record writer one buffered handle on its event file, opened in
    append mode; True if it was given (False: a TensorBoard laid out otherwise keeps its own)."""
    events = getattr(file_writer, "event_writer", None)
    records = getattr(getattr(events, "_async_writer", None), "_writer", None)
    name = getattr(events, "_file_name", None)
    if not isinstance(name, str) or not hasattr(records, "_writer"):
        return False
    events.flush()  # the file-version event is on disk through TensorBoard's own handle
    records._writer = open(name, "ab")  # noqa: SIM115 (closed by the record writer's close)
    return True


def _close_at_exit(writer_ref: weakref.ref) -> None:
    writer = writer_ref()
    if writer is not None:
        try:
            writer.close()
        except (OSError, ValueError):  # its file went away already
            pass
