"""The atomic writer under concurrent writers: unique temporary names, whole files only."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from routine_gym.atomic import atomic_write_bytes, check_writable, temporary_path
from routine_gym.errors import UsageError

WRITERS = 6
WRITES = 150
SIZE = 200_000  # large enough that a write is not one page: a torn read would show

# Writer `i` writes SIZE copies of byte i, WRITES times, to the same target.
_WRITER = textwrap.dedent("""
    import sys
    from routine_gym.atomic import atomic_write_bytes
    target, i, writes, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    payload = bytes([i]) * size
    for _ in range(writes):
        atomic_write_bytes(target, payload)
""")


def test_temporary_names_are_unique_per_writer(tmp_path):
    target = tmp_path / "result.json"
    names = {temporary_path(target) for _ in range(100)}
    assert len(names) == 100
    assert all(Path(n).parent == tmp_path and Path(n).name.startswith(".result.json.")
               for n in names)


def test_many_processes_writing_one_file_never_show_a_reader_a_partial_or_empty_file(tmp_path):
    target = tmp_path / "shared.bin"
    atomic_write_bytes(target, bytes([255]) * SIZE)
    writers = [subprocess.Popen([sys.executable, "-c", _WRITER, str(target), str(i),
                                 str(WRITES), str(SIZE)], stderr=subprocess.PIPE, text=True)
               for i in range(WRITERS)]
    reads, seen = 0, set()
    while any(w.poll() is None for w in writers):
        data = target.read_bytes()
        reads += 1
        # A whole file of one writer: the right size, one byte value throughout.
        assert len(data) == SIZE, f"read {len(data)} bytes"
        assert data.count(data[:1]) == SIZE, "a file mixing two writers' bytes"
        seen.add(data[0])
    for w in writers:
        _, err = w.communicate(timeout=60)
        assert w.returncode == 0, err  # no writer died on another's temporary file
    assert reads > 10
    assert len(seen) >= 2  # the reader did see the writers take turns
    assert target.read_bytes()[0] in range(WRITERS)
    assert [p.name for p in tmp_path.iterdir()] == ["shared.bin"]  # no temporary file left


def test_threads_writing_one_file_all_succeed(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    target = tmp_path / "out.json"
    with ThreadPoolExecutor(8) as pool:
        list(pool.map(lambda i: atomic_write_bytes(target, str(i).encode() * 1000), range(200)))
    text = target.read_text()
    assert text in {str(i) * 1000 for i in range(200)}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_the_written_file_gets_the_umask_permissions(tmp_path):
    old = os.umask(0o027)
    try:
        atomic_write_bytes(tmp_path / "f", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "f").stat().st_mode & 0o777 == 0o640


def test_a_folder_that_is_a_file_is_refused_by_name(tmp_path):
    (tmp_path / "notes").write_text("a file")
    for call in (lambda: atomic_write_bytes(tmp_path / "notes" / "sub" / "x.json", b"{}"),
                 lambda: check_writable(tmp_path / "notes" / "x.json", "--out")):
        with pytest.raises(UsageError, match=rf"{tmp_path / 'notes'} is a file, not a folder"):
            call()


def test_a_read_only_filesystem_is_refused_before_any_work():
    # Nobody, root included, may create a file in /sys (a chmod would not stop root).
    with pytest.raises(UsageError, match=r"--out /sys/x.npz: cannot write there"):
        check_writable("/sys/x.npz", "--out")


def test_a_missing_folder_is_fine_and_is_made_only_when_the_file_is_written(tmp_path):
    target = tmp_path / "new" / "deeper" / "x.json"
    check_writable(target, "--out")
    assert not (tmp_path / "new").exists()  # the check creates nothing
    atomic_write_bytes(target, b"{}")
    assert target.read_bytes() == b"{}"
