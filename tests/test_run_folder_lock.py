"""One process writes a run folder at a time (issue 46 case 9): two `--resume` of one run both
trained it to the end. Every script holds its run folder's lock (`routine_gym.plumbing.
folder_lock`, the sweep folders' lock) from its start, a new run or a resumed one, so a second
process on the folder is refused at once with one line naming the holder."""

from __future__ import annotations

import json
import signal
import subprocess
import time

import pytest
from one_line import assert_one_line_error
from test_as_a_user import BIN, REPO

from routine_gym.errors import UsageError
from routine_gym.plumbing.folder_lock import LOCK_FILE, hold_folder, lock_holder


def script(name: str, *words: str) -> list[str]:
    return [str(BIN / "python"), str(REPO / "algos" / f"{name}.py"), *words]


def _env(tmp_path) -> dict[str, str]:
    return {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path), "LANG": "C.UTF-8"}


@pytest.mark.parametrize("name", ["rapl_a2c", "option_critic"])
def test_a_second_process_on_a_training_run_is_refused_naming_the_first(name, tmp_path):
    first = subprocess.Popen(
        script(name, "--env-id", "MiniQbert-v0", "--total-timesteps", "100000000",
               "--checkpoint-every", "256", "--eval-episodes", "1"),
        cwd=tmp_path, env=_env(tmp_path), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True)
    try:
        deadline = time.monotonic() + 240
        checkpoints = []
        while not checkpoints and time.monotonic() < deadline and first.poll() is None:
            time.sleep(0.5)
            checkpoints = list((tmp_path / "runs").glob("*/checkpoint.pt"))
        assert checkpoints, first.stderr.read() if first.poll() is not None else "no checkpoint"
        run = checkpoints[0].parent
        assert json.loads((run / LOCK_FILE).read_text())["pid"] == first.pid
        # Paused, it holds its lock but leaves the CPU to the processes the test starts.
        first.send_signal(signal.SIGSTOP)
        for target in (run, run / "checkpoint.pt"):  # a folder or its checkpoint: one run
            start = time.monotonic()
            second = subprocess.run(
                script(name, "--resume", str(target), "--eval-episodes", "1"),
                cwd=tmp_path, env=_env(tmp_path), capture_output=True, text=True, timeout=240)
            assert_one_line_error(second, f"{run.name} is in use by another run (pid "
                                  f"{first.pid} on ", "wait for it to end, or stop it")
            assert time.monotonic() - start < 60  # at once, not after training
        assert first.poll() is None  # the first one is still there (paused), its lock held
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)
    # The kernel dropped the killed run's lock: a --resume goes on (straight to evaluation).
    third = subprocess.run(
        script(name, "--resume", str(run), "--total-timesteps", "256", "--eval-episodes", "1"),
        cwd=tmp_path, env=_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert third.returncode == 0, third.stderr[-3000:]
    assert (run / "eval.json").is_file()
    assert lock_holder(run) is None and (run / LOCK_FILE).read_text() == ""  # released


def test_the_lock_is_reentrant_in_one_process_and_released_by_the_last_hold(tmp_path):
    release = hold_folder(tmp_path, what="run", named="--resume R")
    again = hold_folder(tmp_path, what="run", named="--resume R")
    again()
    assert lock_holder(tmp_path) is not None  # still held by the first hold
    code = ("import sys\nfrom routine_gym.plumbing.folder_lock import hold_folder\n"
            "hold_folder(sys.argv[1], what='run', named='--resume R')\n")
    other = subprocess.run([str(BIN / "python"), "-c", code, str(tmp_path)],
                           capture_output=True, text=True, timeout=120)
    assert other.returncode == 1 and "is in use by another run" in other.stderr
    release()
    assert lock_holder(tmp_path) is None
    other = subprocess.run([str(BIN / "python"), "-c", code, str(tmp_path)],
                           capture_output=True, text=True, timeout=120)
    assert other.returncode == 0, other.stderr
    with pytest.raises(UsageError, match="cannot write there"):
        hold_folder(tmp_path / "missing", what="run", named="--resume R")
