"""`ScalarWriter`: the scalars of a step as one TensorBoard event, through `SummaryWriter`'s own
file writer; read back by TensorBoard as `SummaryWriter` would have written them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from routine_gym.plumbing.scalars import ScalarWriter


def test_an_odd_tag_is_taken_or_refused_at_the_call_and_the_writer_goes_on(tmp_path):
    # protobuf refuses a bad tag at add_scalar, not at a later write that would then fail for
    # every step after it.
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


def test_a_summary_writer_and_a_scalar_writer_in_one_folder_keep_their_own_files(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    theirs, ours = SummaryWriter(str(tmp_path)), ScalarWriter(str(tmp_path))
    theirs.add_scalar("theirs", 1.0, 1)
    ours.add_scalar("ours", 2.0, 2)
    theirs.close()
    ours.close()
    assert len(list(tmp_path.glob("events.out.tfevents.*"))) == 2
    assert _scalars(tmp_path) == {"theirs": [(1, 1.0)], "ours": [(2, 2.0)]}


def test_a_writer_closed_and_used_again_goes_on_in_a_new_file(tmp_path):
    # As SummaryWriter does: after close(), the next scalar makes a new file writer.
    writer = ScalarWriter(str(tmp_path))
    writer.add_scalar("a", 1.0, 1)
    writer.close()
    writer.add_scalar("a", 2.0, 2)
    writer.close()
    assert len(list(tmp_path.glob("events.out.tfevents.*"))) == 2
    assert sorted(_scalars(tmp_path)["a"]) == [(1, 1.0), (2, 2.0)]


def test_the_event_file_is_opened_once_not_once_per_event(tmp_path, monkeypatch):
    # TensorBoard's stand-in GFile appends each record by opening and closing the file; the
    # writer's record writer appends through one handle instead: no append after the first event.
    from tensorboard.compat.tensorflow_stub.io.gfile import LocalFileSystem

    appends = []
    real_append = LocalFileSystem.append
    monkeypatch.setattr(LocalFileSystem, "append",
                        lambda fs, *a, **k: (appends.append(a[0]), real_append(fs, *a, **k)))
    writer = ScalarWriter(str(tmp_path))
    for step in range(1, 501):
        writer.add_scalar("charts/episodic_return", step, step)
    writer.close()
    assert appends == []
    assert _scalars(tmp_path)["charts/episodic_return"] == [(s, s) for s in range(1, 501)]


def test_flush_puts_every_scalar_so_far_on_disk_while_the_writer_stays_open(tmp_path):
    writer = ScalarWriter(str(tmp_path))
    for step in range(1, 101):
        writer.add_scalar("a", step * 2, step)
    writer.flush()
    assert _scalars(tmp_path)["a"] == [(s, s * 2) for s in range(1, 101)]
    writer.add_scalar("a", 0.5, 101)
    writer.close()
    assert _scalars(tmp_path)["a"][-1] == (101, 0.5)


def test_a_tensorboard_laid_out_otherwise_keeps_its_own_file_handle():
    from routine_gym.plumbing.scalars import _append_through_one_handle

    assert _append_through_one_handle(object()) is False
