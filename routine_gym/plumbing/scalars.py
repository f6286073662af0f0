"""`ScalarWriter`: TensorBoard's `SummaryWriter`, one event per step for the scalars of a step.

A training script logs a dozen scalars after every update, all at the same `global_step`
(losses, learning rate, SPS, the counters). `SummaryWriter.add_scalar` makes one event per
scalar: a protobuf `Summary`, an `Event`, a queue put and a record write each, about 40 µs. On
MinAtar, where an update is 80 agent steps of a small network, that was a tenth of the time. This
writer keeps the scalars of the current step and writes them as one event (one `Summary` with
several values) when the step changes, on `flush()` and on `close()`. A scalar is kept as a
`(tag, float)` pair; the event is serialized and framed in C++ (`routine_gym/_records.cpp`'s
`scalar_event`: the bytes protobuf writes for it, checked against protobuf in the tests;
protobuf's classes where it is not built). Between two network passes, where the caches are
cold, protobuf's objects cost ~23 µs an event; the compiled event ~3 µs, ~0.2 µs a scalar.
TensorBoard (and `EventAccumulator`, `tbparse`, ...) reads back the same tags, steps and float32
values; only the events' wall times are shared by the scalars of one step.

`mirror`, when given, is called with each event's step and its `(tag, value)` pairs as the
event is written, the values as TensorBoard stores them: `--track` logs them to Weights &
Biases this way (`routine_gym.plumbing.tracking`), so both sinks hold the same scalars.

The events go to the file in the training loop's own thread (`EventFile`), not through
TensorBoard's writer thread: that thread took every event from a queue and framed it with a
CRC computed in Python, and each hand-over made the training thread wait for the GIL, 3-5 % of
a MinAtar A2C run (a dozen events every few milliseconds). `EventFile` frames a record in C++
(`routine_gym/_records.cpp`; TensorBoard's Python CRC where it is not built) and writes it into
the file's buffer, flushed every `flush_secs` (SummaryWriter's, 120 s by default, as
TensorBoard's thread flushes), on `flush()` and `close()`, and at exit. The file is the one
TensorBoard's writer makes: the same name pattern and counter, the same records, the same first
event but for the writer's name in it.

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
import threading
import time
import weakref
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


def _python_scalar_event(wall_time: float, step: int, values: list[tuple[str, float]]) -> bytes:
    """The record of one `Event` of scalars at `step`, built with protobuf's classes."""
    summary = Summary(value=[Summary.Value(tag=tag, simple_value=value) for tag, value in values])
    event = event_pb2.Event(summary=summary, wall_time=wall_time, step=step)
    return _frame(event.SerializeToString())


try:
    from routine_gym._records import frame as _frame
    from routine_gym._records import scalar_event as _scalar_event
except ImportError:  # not built (a source checkout without `pip install`)
    _frame, _scalar_event = _python_frame, _python_scalar_event

__all__ = ["EventFile", "ScalarWriter"]

try:  # TensorBoard's own file counter: no name shared with its writers in this process
    from tensorboard.summary.writer.event_file_writer import _global_uid

    def _file_number() -> int:
        return _global_uid.get()
except ImportError:  # pragma: no cover (a TensorBoard without it)
    _file_number = itertools.count().__next__


class EventFile:
    """TensorBoard's `EventFileWriter`, written in the caller's thread (see the module doc).

    Each record goes into the file's buffer at once; the buffer reaches the file when it fills
    (8 KiB), every `flush_secs`, on `flush()` and on `close()`, and a file still open when the
    interpreter exits (a run ended by an exception) is closed then, with its buffer. Local
    folders only (TensorBoard's writer also takes `gs://` and `s3://` paths).

    Args:
        logdir: the folder of the event file (made if missing).
        flush_secs: the longest time between two flushes while events come in.
        filename_suffix: appended to the file's name, as `SummaryWriter`'s.
    """

    def __init__(self, logdir: str, flush_secs: float = 120, filename_suffix: str = "") -> None:
        self._logdir = str(logdir)
        self._flush_secs = flush_secs
        self._suffix = filename_suffix
        self._lock = threading.Lock()  # as TensorBoard's writer, safe to share between threads
        self._file = None
        self._open()

    def _open(self) -> None:
        os.makedirs(self._logdir, exist_ok=True)
        while True:  # "xb": never truncate another writer's file
            self._file_name = os.path.join(
                self._logdir,
                f"events.out.tfevents.{int(time.time()):010d}.{socket.gethostname()}."
                f"{os.getpid()}.{_file_number()}{self._suffix}")
            try:
                self._file = open(self._file_name, "xb")  # noqa: SIM115 (closed by close())
                break
            except FileExistsError:
                continue
        self._closer = weakref.finalize(self, self._file.close)  # at exit, if not before
        self._next_flush = time.monotonic() + self._flush_secs
        self.add_event(event_pb2.Event(
            wall_time=time.time(), file_version="brain.Event:2",
            source_metadata=event_pb2.SourceMetadata(writer="routine_gym.plumbing.scalars")))
        self.flush()

    def get_logdir(self) -> str:
        return self._logdir

    def add_event(self, event: event_pb2.Event) -> None:
        self.add_record(_frame(event.SerializeToString()))

    def add_record(self, record: bytes) -> None:
        """Write a record already framed (`frame`, `scalar_event`)."""
        with self._lock:
            if self._file is None:
                raise OSError(f"the event file {self._file_name} is closed")
            self._file.write(record)
            if time.monotonic() >= self._next_flush:
                self._flush()

    def _flush(self) -> None:
        self._file.flush()
        self._next_flush = time.monotonic() + self._flush_secs

    def flush(self) -> None:
        with self._lock:
            if self._file is not None:
                self._flush()

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                try:
                    self._file.close()
                finally:
                    self._closer.detach()
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
        self._values: list[tuple[str, float]] = []
        # A run that ends on an exception does not close its writer: the last step's scalars
        # still go to the file at exit (before the file itself is closed, made earlier).
        weakref.finalize(self, _write_pending_at_exit, weakref.ref(self))

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
        # An ASCII str tag is kept as it is; any other (bytes, non-ASCII text, not text) takes
        # SummaryWriter's own path, so protobuf accepts or refuses it here, at the call.
        if global_step is None or walltime is not None or new_style or double_precision \
                or type(tag) is not str or not tag.isascii():
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
        self._values.append((tag, float(scalar_value)))

    def _write_pending(self) -> None:
        if self._values:
            # The event `add_summary` writes (`SummaryWriter.add_scalar`'s summaries in one),
            # serialized in C++ (`scalar_event`) instead of through protobuf's classes.
            self._get_file_writer().event_writer.add_record(
                _scalar_event(time.time(), int(self._step), self._values))
            if self.mirror is not None:  # the values as the event stores them: float32
                self.mirror(self._step, [(tag, float(np.float32(value)))
                                         for tag, value in self._values])
            self._values = []

    def flush(self) -> None:
        self._write_pending()
        super().flush()

    def close(self) -> None:
        self._write_pending()
        super().close()


def _write_pending_at_exit(writer_ref: weakref.ref) -> None:
    writer = writer_ref()
    if writer is not None:
        try:
            writer._write_pending()
        except (OSError, ValueError):  # its file was closed already
            pass
