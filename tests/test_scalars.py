"""`ScalarWriter` and its `EventFile`: TensorBoard's event files, written in the training thread.

TensorBoard's own reader checks both CRCs of every record, so reading a file back checks the
framing too; the compiled framing is also compared byte for byte with TensorBoard's Python one.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.compat.tensorflow_stub.pywrap_tensorflow import masked_crc32c

from routine_gym import _records
from routine_gym.plumbing import scalars
from routine_gym.plumbing.scalars import EventFile, ScalarWriter


def test_crc32c_of_the_standard_check_string():
    # CRC-32C("123456789") = 0xE3069283 (the Castagnoli check value); masked as TensorFlow
    # masks it: rotate right 15 bits, add 0xA282EAD8.
    crc = 0xE3069283
    masked = (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF
    assert _records.masked_crc32c(b"123456789") == masked == masked_crc32c(b"123456789")


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000))
def test_the_compiled_framing_is_tensorboards(data):
    assert _records.masked_crc32c(data) == masked_crc32c(data)
    assert _records.frame(data) == scalars._python_frame(data)  # the fallback's framing


_DOUBLES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from(
    [0.0, -0.0, 3.4028234663852886e38, 3.4028235e38, 3.4028236e38, -1e300, 1e-50, 2.0 ** -149]))


@settings(max_examples=400, deadline=None)
@given(_DOUBLES, st.integers(-2**63, 2**63 - 1),
       st.lists(st.tuples(st.text(max_size=200), _DOUBLES), max_size=20))
def test_the_compiled_scalar_event_is_protobufs(wall_time, step, values):
    # Byte for byte what protobuf serializes for the same Event: zero fields, negative steps,
    # empty and non-ASCII tags, values that round to inf, 0 or a float32 subnormal, NaNs.
    assert _records.scalar_event(wall_time, step, values) \
        == scalars._python_scalar_event(wall_time, step, values)


@pytest.mark.parametrize("event", [_records.scalar_event, scalars._python_scalar_event])
def test_a_scalar_event_refuses_what_protobuf_refuses(event):
    for values, step in [([("a", 1.0, 2.0)], 1), ([("a", "1")], 1), ([("a", 1.0)], 2**63),
                         ([("\ud800", 1.0)], 1), ([(b"\xff", 1.0)], 1), ([(1, 1.0)], 1)]:
        with pytest.raises((TypeError, ValueError, OverflowError)):
            event(1.0, step, values)
    assert event(1.0, 1, [(b"a", 1.0)]) == event(1.0, 1, [("a", 1.0)])  # UTF-8 bytes: a tag


def test_an_odd_tag_is_taken_or_refused_at_the_call_and_the_writer_goes_on(tmp_path):
    # Tags other than ASCII text go through SummaryWriter's own path: protobuf refuses a bad one
    # at add_scalar, not at a later write that would then fail for every step after it.
    writer = ScalarWriter(str(tmp_path))
    writer.add_scalar("losses/a", 1.0, 1)
    with pytest.raises((TypeError, ValueError)):
        writer.add_scalar(7, 2.0, 1)
    with pytest.raises((TypeError, ValueError, UnicodeError)):
        writer.add_scalar("bad\ud800", 2.0, 1)
    writer.add_scalar("écart/ünicode", 3.0, 2)
    writer.add_scalar("losses/a", 4.0, 3)
    writer.close()
    assert _scalars(tmp_path) == {"losses/a": [(1, 1.0), (3, 4.0)], "écart/ünicode": [(2, 3.0)]}


def _scalars(folder: Path) -> dict[str, list[tuple[int, float]]]:
    files = sorted(folder.glob("events.out.tfevents.*"))
    out: dict[str, list[tuple[int, float]]] = {}
    for f in files:
        events = EventAccumulator(str(f), size_guidance={"scalars": 0})
        events.Reload()
        for tag in events.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in events.Scalars(tag))
    return out


def test_tensorboard_reads_back_scalars_histograms_and_text(tmp_path):
    writer = ScalarWriter(str(tmp_path))
    for step in range(1, 301):  # 300 steps: episodes at their own steps, losses grouped
        writer.add_scalar("charts/episodic_return", step * 0.5, step)
        writer.add_scalar("losses/value_loss", 1.0 / step, step)
    writer.add_histogram("weights", np.arange(10.0), 300)
    writer.add_text("notes", "hello", 300)
    writer.close()
    files = list(tmp_path.glob("events.out.tfevents.*"))
    assert len(files) == 1
    events = EventAccumulator(str(files[0]), size_guidance={"scalars": 0})
    events.Reload()
    returns = [(e.step, e.value) for e in events.Scalars("charts/episodic_return")]
    assert returns == [(s, s * 0.5) for s in range(1, 301)]
    losses = [e.value for e in events.Scalars("losses/value_loss")]
    assert losses == [float(np.float32(1.0 / s)) for s in range(1, 301)]
    assert events.Histograms("weights")[0].histogram_value.num == 10
    assert events.Tags()["tensors"] == ["notes/text_summary"]


def test_events_wait_in_memory_until_flush_secs_flush_or_close(tmp_path):
    writer = ScalarWriter(str(tmp_path), flush_secs=3600)
    writer.add_scalar("a", 1.0, 1)
    writer.add_scalar("a", 2.0, 2)  # step 1's event is made now, kept in memory
    assert _scalars(tmp_path) == {}
    writer.flush()  # step 2's event too
    assert _scalars(tmp_path) == {"a": [(1, 1.0), (2, 2.0)]}
    writer.add_scalar("a", 3.0, 3)
    writer.close()
    assert _scalars(tmp_path) == {"a": [(1, 1.0), (2, 2.0), (3, 3.0)]}


def test_flush_secs_writes_events_as_they_come(tmp_path):
    writer = ScalarWriter(str(tmp_path), flush_secs=0)
    writer.add_scalar("a", 1.0, 1)
    writer.add_scalar("a", 2.0, 2)  # step 1's event goes to the file at once
    assert _scalars(tmp_path) == {"a": [(1, 1.0)]}
    writer.close()


def test_a_full_buffer_reaches_the_file_before_flush_secs(tmp_path):
    writer = ScalarWriter(str(tmp_path), flush_secs=3600)
    for step in range(1, 2001):  # ~60 bytes an event: far more than the file's 8 KiB buffer
        writer.add_scalar("a", float(step), step)
    on_disk = _scalars(tmp_path)["a"]
    assert 0 < len(on_disk) < 1999  # some went out before any flush, not all
    assert on_disk == [(s, float(s)) for s in range(1, len(on_disk) + 1)]
    writer.close()


def test_a_run_ended_by_an_exception_keeps_its_scalars(tmp_path):
    # No close(), no flush(): the process ends on an uncaught exception.
    code = (
        "import sys\n"
        "from routine_gym.plumbing.scalars import ScalarWriter\n"
        "w = ScalarWriter(sys.argv[1])\n"
        "for step in range(1, 201):\n"
        "    w.add_scalar('charts/episodic_return', step / 2, step)\n"
        "    w.add_scalar('losses/value_loss', 1.0, step)\n"
        "raise RuntimeError('boom')\n")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                          text=True)
    assert done.returncode == 1 and "RuntimeError: boom" in done.stderr
    scalars_read = _scalars(tmp_path)
    assert scalars_read["charts/episodic_return"] == [(s, s / 2) for s in range(1, 201)]
    assert len(scalars_read["losses/value_loss"]) == 200


def test_two_threads_share_an_event_file(tmp_path):
    from tensorboard.compat.proto.event_pb2 import Event

    events = EventFile(str(tmp_path), flush_secs=0)  # a flush after every event: the most races

    def write(first):
        for step in range(first, first + 3000):
            events.add_event(Event(step=step, file_version="x"))

    threads = [threading.Thread(target=write, args=(k * 10_000,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    events.close()
    path = next(tmp_path.glob("events.out.tfevents.*"))
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

    steps = sorted(e.step for e in EventFileLoader(str(path)).Load())
    assert steps == [0] + list(range(3000)) + list(range(10_000, 13_000))


def test_a_summary_writer_and_a_scalar_writer_in_one_folder_keep_their_own_files(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    theirs, ours = SummaryWriter(str(tmp_path)), ScalarWriter(str(tmp_path))
    theirs.add_scalar("theirs", 1.0, 1)
    ours.add_scalar("ours", 2.0, 2)
    theirs.close()
    ours.close()
    assert len(list(tmp_path.glob("events.out.tfevents.*"))) == 2
    assert _scalars(tmp_path) == {"theirs": [(1, 1.0)], "ours": [(2, 2.0)]}


def test_a_closed_event_file_refuses_events_and_reopens_into_a_new_file(tmp_path):
    events = EventFile(str(tmp_path))
    events.close()
    with pytest.raises(OSError, match="is closed"):
        from tensorboard.compat.proto.event_pb2 import Event
        events.add_event(Event(step=1))
    time.sleep(0.01)
    events.reopen()
    events.close()
    assert len(list(tmp_path.glob("events.out.tfevents.*"))) == 2


def test_a_writer_closed_and_used_again_goes_on_in_a_new_file(tmp_path):
    # As SummaryWriter does: after close(), the next scalar makes a new file writer.
    writer = ScalarWriter(str(tmp_path))
    writer.add_scalar("a", 1.0, 1)
    writer.close()
    writer.add_scalar("a", 2.0, 2)
    writer.close()
    assert len(list(tmp_path.glob("events.out.tfevents.*"))) == 2
    assert sorted(_scalars(tmp_path)["a"]) == [(1, 1.0), (2, 2.0)]
