"""A full disk is one line, not a traceback, and loses nothing already written (issue 46 case
12). Each test writes into a tmpfs of a few kilobytes (mounting one needs root: skipped
otherwise), as a user's command would fill a disk."""

from __future__ import annotations

import shutil
import subprocess
import uuid
from pathlib import Path

import pytest
from test_as_a_user import REPO, ok, user

DEMO = REPO / "demos" / "MiniQbert-v0.npz"
LINE = "no space left on device while writing "
LOST = "nothing written before was lost"


@pytest.fixture()
def small_disk(tmp_path, request):
    """A folder on a tmpfs of 64 KiB (or `@pytest.mark.disk_kib(N)`), unmounted afterwards."""
    marker = request.node.get_closest_marker("disk_kib")
    size = marker.args[0] if marker else 64
    mount = tmp_path / f"disk-{uuid.uuid4().hex[:6]}"
    mount.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}k", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


def fill(folder: Path, leave: int = 0) -> None:
    """Fill the disk of `folder` up to `leave` free bytes (blocks of 4 KiB)."""
    usage = shutil.disk_usage(folder)
    (folder / "filler").write_bytes(b"x" * max(0, usage.free - leave))


def assert_disk_full_line(proc: subprocess.CompletedProcess, *names: str) -> str:
    """The error line (the last of stderr: the miner's warnings may come before it)."""
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 1, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert [line for line in lines if "error:" in line] == lines[-1:], proc.stderr[-3000:]
    for name in (LINE, LOST, *names):
        assert name in lines[-1], (name, lines[-1])
    return lines[-1]


def test_a_cli_output_on_a_full_disk_is_one_line(small_disk, tmp_path):
    fill(small_disk)
    proc = user("routine-gym", "mine", DEMO, "--out", small_disk / "lib.json", cwd=tmp_path)
    assert_disk_full_line(proc, str(small_disk / "lib.json"))
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler"]  # no temporary left


def test_a_run_on_a_full_disk_is_one_line(small_disk, tmp_path):
    proc = user("python", REPO / "algos" / "rapl_a2c.py", "--env-id", "MiniQbert-v0",
                "--num-envs", "2", "--total-timesteps", "2000", "--checkpoint-every", "500",
                "--eval-episodes", "1", "--run-dir", small_disk / "runs", cwd=tmp_path)
    assert_disk_full_line(proc, str(small_disk / "runs"))


@pytest.mark.disk_kib(4096)
def test_a_resumed_run_stopped_by_a_full_disk_keeps_its_checkpoint(small_disk, tmp_path):
    ok(user("python", REPO / "algos" / "rapl_a2c.py", "--env-id", "MiniQbert-v0",
            "--num-envs", "2", "--total-timesteps", "64", "--checkpoint-every", "32",
            "--eval-episodes", "0", "--run-dir", "runs", cwd=tmp_path))
    (run,) = (tmp_path / "runs").iterdir()
    moved = small_disk / run.name
    shutil.copytree(run, moved)
    before = (moved / "checkpoint.pt").read_bytes()
    fill(small_disk, leave=32 * 1024)  # room for the lock and the log, not a checkpoint
    proc = user("python", REPO / "algos" / "rapl_a2c.py", "--resume", moved,
                "--total-timesteps", "2000", "--eval-episodes", "1", cwd=tmp_path)
    assert_disk_full_line(proc, str(moved))
    assert (moved / "checkpoint.pt").read_bytes() == before  # intact
    (small_disk / "filler").unlink()  # space again: the run goes on from its checkpoint
    proc = user("python", REPO / "algos" / "rapl_a2c.py", "--resume", moved,
                "--total-timesteps", "128", "--eval-episodes", "0", cwd=tmp_path)
    assert "resumed " in ok(proc)
