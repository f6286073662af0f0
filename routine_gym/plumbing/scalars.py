"""`ScalarWriter`: TensorBoard's `SummaryWriter`, one event per step for the scalars of a step.

A training script logs a dozen scalars after every update, all at the same `global_step`
(losses, learning rate, SPS, the counters). `SummaryWriter.add_scalar` makes one event per
scalar: a protobuf `Summary`, an `Event`, a queue put and a record write each, about 40 µs. On
MinAtar, where an update is 80 agent steps of a small network, that was a tenth of the time. This
writer keeps the scalars of the current step and writes them as one event (one `Summary` with
several values) when the step changes, on `flush()` and on `close()`: about 4 µs per scalar.
TensorBoard (and `EventAccumulator`, `tbparse`, ...) reads back the same tags, steps and float32
values; only the events' wall times are shared by the scalars of one step.

`mirror`, when given, is called with each event's step and its `(tag, value)` pairs as the
event is written, the values as TensorBoard stores them: `--track` logs them to Weights &
Biases this way (`routine_gym.plumbing.tracking`), so both sinks hold the same scalars.

The events go to the file in the training loop's own thread (`EventFile`), not through
TensorBoard's writer thread: that thread took every event from a queue and framed it with a
CRC computed in Python, and each hand-over made the training thread wait for the GIL, 3-5 % of
a MinAtar A2C run (a dozen events every few milliseconds). `EventFile` frames a record in C++
(`routine_gym/_records.cpp`; TensorBoard's Python CRC where it is not built), keeps the records
in memory and writes them every `flush_secs` (SummaryWriter's, 120 s by default), on `flush()`
and `close()`, and when 1 MiB is pending. The file is the one TensorBoard's writer makes: same
name pattern, same first event, same records.

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

import itertools
import os
import socket
import struct
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from tensorboard.compat.proto import event_pb2
from tensorboard.compat.proto.summary_pb2 import Summary
from tensorboard.compat.tensorflow_stub.pywrap_tensorflow import masked_crc32c
from torch.utils.tensorboard import SummaryWriter
from torch.utils.tensorboard.writer import FileWriter


def _python_frame(data: bytes) -> bytes:
    """One TFRecord as TensorBoard's `RecordWriter` frames it (its CRC in Python)."""
    header = struct.pack("<Q", len(data))
    return (header + struct.pack("<I", masked_crc32c(header)) + data
            + struct.pack("<I", masked_crc32c(data)))


try:
    from routine_gym._records import frame as _frame
except ImportError:  # not built (a source checkout without `pip install`)
    _frame = _python_frame

__all__ = ["EventFile", "ScalarWriter"]

#: Pending bytes that make `EventFile.add_event` write to the file before `flush_secs`.
_MAX_PENDING = 1 << 20
_file_numbers = itertools.count()  # the last part of an event file's name, as TensorBoard's


class EventFile:
    """TensorBoard's `EventFileWriter`, written in the caller's thread (see the module doc).

    Args:
        logdir: the folder of the event file (made if missing).
        flush_secs: the longest time an event waits in memory before it is written.
        filename_suffix: appended to the file's name, as `SummaryWriter`'s.
    """

    def __init__(self, logdir: str, flush_secs: float = 120, filename_suffix: str = "") -> None:
        self._logdir = str(logdir)
        self._flush_secs = flush_secs
        self._suffix = filename_suffix
        self._open()

    def _open(self) -> None:
        os.makedirs(self._logdir, exist_ok=True)
        self._file_name = os.path.join(
            self._logdir,
            f"events.out.tfevents.{int(time.time()):010d}.{socket.gethostname()}."
            f"{os.getpid()}.{next(_file_numbers)}{self._suffix}")
        self._file = open(self._file_name, "wb")  # noqa: SIM115 (closed by close())
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        self._next_write = time.monotonic() + self._flush_secs
        self.add_event(event_pb2.Event(
            wall_time=time.time(), file_version="brain.Event:2",
            source_metadata=event_pb2.SourceMetadata(writer="routine_gym.plumbing.scalars")))
        self.flush()

    def get_logdir(self) -> str:
        return self._logdir

    def add_event(self, event: event_pb2.Event) -> None:
        if self._file is None:
            raise OSError(f"the event file {self._file_name} is closed")
        record = _frame(event.SerializeToString())
        self._pending.append(record)
        self._pending_bytes += len(record)
        if self._pending_bytes >= _MAX_PENDING or time.monotonic() >= self._next_write:
            self._write()

    def _write(self) -> None:
        if self._pending:
            self._file.write(b"".join(self._pending))
            self._pending, self._pending_bytes = [], 0
        self._file.flush()
        self._next_write = time.monotonic() + self._flush_secs

    def flush(self) -> None:
        if self._file is not None:
            self._write()

    def close(self) -> None:
        if self._file is not None:
            self._write()
            self._file.close()
            self._file = None

    def reopen(self) -> None:
        """After `close()`, go on in a new event file (as TensorBoard's writer does)."""
        if self._file is None:
            self._open()


class _FileWriter(FileWriter):
    """torch's `FileWriter` (its `add_summary`, `add_event`, `add_graph`, ...) over an
    `EventFile` instead of TensorBoard's threaded `EventFileWriter`."""

    def __init__(self, log_dir: str, flush_secs: float = 120, filename_suffix: str = "") -> None:
        self.event_writer = EventFile(str(log_dir), flush_secs, filename_suffix)


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

    def _get_file_writer(self) -> FileWriter:
        """SummaryWriter's, with an `EventFile` (created on first use, again after close)."""
        if self.all_writers is None or self.file_writer is None:
            self.file_writer = _FileWriter(self.log_dir, self.flush_secs, self.filename_suffix)
            self.all_writers = {self.file_writer.get_logdir(): self.file_writer}
            if self.purge_step is not None:  # as SummaryWriter restarts a purged run
                self.file_writer.add_event(event_pb2.Event(step=self.purge_step,
                                                           file_version="brain.Event:2"))
                self.file_writer.add_event(event_pb2.Event(
                    step=self.purge_step,
                    session_log=event_pb2.SessionLog(status=event_pb2.SessionLog.START)))
                self.purge_step = None
        return self.file_writer

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
        # `SummaryWriter.add_scalar` stores float(value) as the proto's float32 simple_value.
        self._values.append(Summary.Value(tag=tag, simple_value=float(scalar_value)))

    def _write_pending(self) -> None:
        if self._values:
            self._get_file_writer().add_summary(Summary(value=self._values), self._step,
                                                time.time())
            if self.mirror is not None:
                self.mirror(self._step, [(v.tag, v.simple_value) for v in self._values])
            self._values = []

    def flush(self) -> None:
        self._write_pending()
        super().flush()

    def close(self) -> None:
        self._write_pending()
        super().close()
