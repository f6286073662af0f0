"""Every bad input a one-line error with exit code 2, and nothing lost or half-written.

Each test feeds a real bad file, flag, env or checkpoint to a real script or the CLI in a
subprocess and checks: exit code 2, exactly one line on stderr, no traceback, and the name of
the file or flag in the message.
"""

from __future__ import annotations

import io
import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from one_line import assert_one_line_error

from routine_gym.atomic import atomic_write_bytes, temporary_path
from routine_gym.demo import Demo, shipped_demo_path
from routine_gym.errors import UsageError
from routine_gym.library import RoutineLibrary

REPO = Path(__file__).resolve().parent.parent
MINIQBERT_DEMO = shipped_demo_path("MiniQbert-v0")


def run(args: list[str], cwd: Path, env: dict | None = None, timeout: int = 180):
    return subprocess.run(args, capture_output=True, text=True, cwd=cwd, timeout=timeout,
                          env={**os.environ, **(env or {})})


def script(name: str, *args: str, cwd: Path, env: dict | None = None):
    return run([sys.executable, str(REPO / "algos" / f"{name}.py"), *args], cwd, env)


def cli(*args: str, cwd: Path):
    return run([sys.executable, "-m", "routine_gym.cli", *args], cwd)


# -- bad files --------------------------------------------------------------------------------


def test_a_bad_demo_file_is_named(tmp_path):
    (tmp_path / "notes.npz").write_text("not a demo")
    for proc in (cli("show", "notes.npz", cwd=tmp_path),
                 script("bc", "--env-id", "MiniQbert-v0", "--demo", "notes.npz", cwd=tmp_path)):
        assert_one_line_error(proc, "notes.npz", "not a routine-gym demo")
    proc = script("rapl_sqil", "--env-id", "MiniQbert-v0", "--demo", "missing.npz", cwd=tmp_path)
    assert_one_line_error(proc, "missing.npz")


def test_an_oversized_demo_is_refused_under_the_documented_limit(tmp_path):
    # 2 MiB of JSON metadata that compresses to a few kB.
    demo = Demo.load(MINIQBERT_DEMO)
    meta = {**demo.meta, "padding": "x" * (2 << 20)}
    buffer = io.BytesIO()
    np.savez_compressed(buffer, actions=demo.actions, rewards=demo.rewards,
                        terminated=demo.terminated, truncated=demo.truncated,
                        decisions=demo.decisions, episode_lengths=demo.episode_lengths,
                        meta=np.array(json.dumps(meta)))
    (tmp_path / "big.npz").write_bytes(buffer.getvalue())
    assert (tmp_path / "big.npz").stat().st_size < 100_000
    assert_one_line_error(cli("show", "big.npz", cwd=tmp_path), "big.npz", "over the limit",
                          "1 MiB of metadata")


# -- bad flags --------------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "args", "message"), [
    ("rapl_a2c", ["--gamma", "1.5"], "--gamma needs to be in (0, 1], actual value: 1.5"),
    ("rapl_a2c", ["--num-envs", "0"], "--num-envs needs to be ≥ 1, actual value: 0"),
    ("rapl_sqil", ["--learning-rate", "-1"], "--learning-rate needs to be > 0"),
    ("rapl_sqil", ["--alpha", "0"], "--alpha needs to be ≥ 1, actual value: 0"),
    ("gail", ["--total-timesteps", "0"], "--total-timesteps needs to be ≥ 1"),
    ("bc", ["--total-timesteps", "10"], "--total-timesteps was renamed: use --gradient-steps"),
    ("bc", ["--batch-size", "abc"], "--batch-size"),
    ("option_critic", ["--num-envz", "3"], "--num-envz"),
])
def test_a_bad_flag_is_named_before_any_work(name, args, message, tmp_path):
    proc = script(name, "--env-id", "MiniQbert-v0", "--run-dir", "runs", *args, cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").iterdir())


def test_debug_shows_the_traceback(tmp_path):
    proc = script("rapl_a2c", "--gamma", "1.5", "--debug", cwd=tmp_path)
    assert proc.returncode != 0 and "Traceback" in proc.stderr and "UsageError" in proc.stderr
    proc = script("rapl_a2c", "--gamma", "1.5", cwd=tmp_path, env={"ROUTINE_GYM_DEBUG": "1"})
    assert "Traceback" in proc.stderr
    proc = cli("show", "missing.npz", "--debug", cwd=tmp_path)
    assert "Traceback" in proc.stderr


# -- environments the scripts cannot handle --------------------------------------------------

ODD_ENVS = textwrap.dedent('''
    """Envs of shapes routine-gym's scripts refuse, registered under this module's name."""
    import gymnasium as gym
    import numpy as np
    from gymnasium import spaces


    class Odd(gym.Env):
        def __init__(self, action_space, observation_space):
            self.action_space, self.observation_space = action_space, observation_space

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            return self.observation_space.sample(), {}

        def step(self, action):
            return self.observation_space.sample(), 0.0, True, False, {}


    BOX = spaces.Box(0, 1, (3,), np.float32)
    gym.register("Continuous-v0", entry_point=lambda: Odd(spaces.Box(-1, 1, (2,)), BOX))
    gym.register("MultiDiscrete-v0", entry_point=lambda: Odd(spaces.MultiDiscrete([2, 3]), BOX))
    gym.register("Shifted-v0", entry_point=lambda: Odd(spaces.Discrete(3, start=1), BOX))
    gym.register("DictObs-v0",
                 entry_point=lambda: Odd(spaces.Discrete(2), spaces.Dict({"x": BOX})))
''')


@pytest.mark.parametrize(("env_id", "message"), [
    ("NoSuchGame-v0", "Gymnasium does not know this env"),
    ("oddenvs:Continuous-v0", "action space Box"),
    ("oddenvs:MultiDiscrete-v0", "action space MultiDiscrete"),
    ("oddenvs:Shifted-v0", "starts at 1"),
    ("oddenvs:DictObs-v0", "FlattenObservation"),
])
def test_an_env_the_scripts_cannot_handle_is_refused_by_name(env_id, message, tmp_path):
    (tmp_path / "oddenvs.py").write_text(ODD_ENVS)
    for name in ("rapl_a2c", "option_critic"):
        proc = script(name, "--env-id", env_id, "--run-dir", "runs", cwd=tmp_path,
                      env={"PYTHONPATH": str(tmp_path)})
        assert_one_line_error(proc, env_id, message)
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").iterdir())


# -- routine libraries ------------------------------------------------------------------------


def _write_library(path: Path, routines, meanings=None) -> None:
    data = RoutineLibrary(routines=((2, 3, 2),), source={"env_id": "MiniQbert-v0"}).to_dict()
    data.update(routines=routines, scores=[1.0], frequencies=[1], occurrences=[[]],
                action_meanings=meanings)
    path.write_text(json.dumps(data))


def test_a_routine_with_a_non_integer_action_is_refused(tmp_path):
    _write_library(tmp_path / "frac.json", [[2, 2.7, 3]])
    for proc in (cli("show", "frac.json", cwd=tmp_path),
                 script("rapl_a2c", "--env-id", "MiniQbert-v0", "--routine-library", "frac.json",
                        "--run-dir", "runs", cwd=tmp_path)):
        assert_one_line_error(proc, "frac.json", "non-integer action 2.7")


def test_a_routine_outside_the_action_space_is_refused_by_every_reader(tmp_path):
    meanings = ["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"]
    _write_library(tmp_path / "named.json", [[2, 9]], meanings)
    assert_one_line_error(cli("show", "named.json", cwd=tmp_path), "named.json", "action 9")
    _write_library(tmp_path / "bare.json", [[2, 9]])  # no names: the env's space decides
    for name in ("rapl_a2c", "rapl_sqil"):
        proc = script(name, "--env-id", "MiniQbert-v0", "--routine-library", "bare.json",
                      "--run-dir", "runs", cwd=tmp_path)
        assert_one_line_error(proc, "bare.json", "outside MiniQbert-v0's Discrete(6)")


# -- checkpoints ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A real rapl_a2c checkpoint of a short MiniQbert run (budget 400)."""
    folder = tmp_path_factory.mktemp("ckpt")
    proc = script("rapl_a2c", "--env-id", "MiniQbert-v0", "--mode", "a2c", "--num-envs", "2",
                  "--total-timesteps", "400", "--checkpoint-every", "200", "--eval-episodes", "0",
                  "--run-dir", "runs", cwd=folder)
    assert proc.returncode == 0, proc.stderr
    (path,) = (folder / "runs").glob("*/checkpoint.pt")
    return path


@pytest.mark.parametrize(("change", "message"), [
    (lambda c: c.update(args="{not json"), "saved settings are not JSON"),
    (lambda c: c.update(args=json.dumps({**json.loads(c["args"]), "warp": 9})), "warp"),
    (lambda c: c.update(global_step="many"), "global_step is 'many', not a step count"),
    (lambda c: c["model"].update({k: torch.zeros(3) for k in list(c["model"])[:1]}),
     "its model does not fit this run"),
])
def test_a_checkpoint_with_bad_contents_is_refused_by_name(checkpoint, change, message,
                                                           tmp_path):
    state = torch.load(checkpoint, weights_only=True)
    change(state)
    torch.save(state, tmp_path / "bad.pt")
    proc = script("rapl_a2c", "--resume", "bad.pt", cwd=tmp_path)
    assert_one_line_error(proc, "bad.pt", message)
    assert "weights_only" not in proc.stderr


def test_a_checkpoint_of_pickled_objects_is_refused_without_the_unsafe_hint(tmp_path):
    torch.save({"args": object()}, tmp_path / "pickled.pt")
    proc = script("bc", "--resume", "pickled.pt", cwd=tmp_path)
    line = assert_one_line_error(proc, "pickled.pt", "not plain tensors")
    assert "weights_only" not in line


def test_flags_that_contradict_the_saved_run_are_refused(checkpoint, tmp_path):
    for flag, value in (("--env-id", "CartPole-v1"), ("--mode", "rapl"), ("--num-envs", "16")):
        proc = script("rapl_a2c", "--resume", str(checkpoint), flag, value, cwd=tmp_path)
        assert_one_line_error(proc, str(checkpoint), f"started with {flag}")


def test_a_lower_budget_on_resume_does_not_overwrite_the_saved_one(checkpoint, tmp_path):
    import shutil

    run_dir = tmp_path / "run"
    shutil.copytree(checkpoint.parent, run_dir)
    # Straight to evaluation at 300 steps (below the 400 done): the run keeps its budget.
    proc = script("rapl_a2c", "--resume", str(run_dir), "--total-timesteps", "300",
                  "--eval-episodes", "1", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    saved = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    assert json.loads(saved["args"])["total_timesteps"] == 400
    assert json.loads((run_dir / "eval.json").read_text())["episodes"] == 1


# -- nothing lost -----------------------------------------------------------------------------


@pytest.mark.parametrize(("out", "message"), [
    (".", "is a folder"),
    ("notes.txt/demo.npz", "notes.txt is a file, not a folder"),
    ("/proc/demo.npz", "cannot write there"),
    ("/dev/null", "not a regular file"),
])
def test_an_output_that_cannot_be_written_is_refused_before_recording(out, message, tmp_path):
    (tmp_path / "notes.txt").write_text("a file, where a folder of the path should be")
    start = time.monotonic()
    for command in (["record", "MiniQbert-v0", "--episodes", "50", "--out", out],
                    ["play", "MiniQbert-v0", "--out", out]):
        assert_one_line_error(cli(*command, cwd=tmp_path), "--out", message)
    assert time.monotonic() - start < 60
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)  # still the device


def test_the_atomic_writer_refuses_to_replace_a_device_and_clears_a_killed_writers_remains(
        tmp_path):
    with pytest.raises(UsageError, match="not a regular file"):
        atomic_write_bytes("/dev/null", b"x")
    target = tmp_path / "file.bin"
    # The remains of a write whose process was killed: a pid that no longer runs.
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    remains = tmp_path / f".file.bin.{dead.pid}-0123456789ab.tmp"
    remains.write_bytes(b"remains of a killed write")
    # A live writer's temporary file (this process's) is left alone.
    live = Path(temporary_path(target))
    live.write_bytes(b"being written")
    atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["file.bin", live.name])


def test_a_killed_record_leaves_neither_output_nor_temporary_file(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "routine_gym.cli", "record", "MinAtar/SpaceInvaders-v1",
         "--episodes", "100000", "--out", "demo.npz"],
        cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while "episode 3/" not in (line := proc.stderr.readline()):  # recording is under way
        assert line or proc.poll() is None, "record ended before it could be killed"
        assert time.monotonic() < deadline
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    proc.stderr.close()
    assert list(tmp_path.iterdir()) == []


def test_two_runs_started_together_get_two_folders_and_both_finish(tmp_path):
    command = [sys.executable, str(REPO / "algos" / "rapl_a2c.py"), "--env-id", "MiniQbert-v0",
               "--mode", "a2c", "--num-envs", "2", "--total-timesteps", "300",
               "--checkpoint-every", "10", "--eval-episodes", "1", "--run-dir", "runs"]
    procs = [subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    for proc in procs:
        _, err = proc.communicate(timeout=180)
        assert proc.returncode == 0, err
    folders = sorted((tmp_path / "runs").iterdir())
    assert len(folders) == 2
    for folder in folders:
        assert (folder / "eval.json").exists() and (folder / "checkpoint.pt").exists()
        assert not [p for p in folder.iterdir() if p.name.endswith(".tmp")]


def test_a_run_that_fails_before_training_leaves_no_folder(tmp_path):
    (tmp_path / "notes.npz").write_text("not a demo")
    proc = script("rapl_sqil", "--env-id", "MiniQbert-v0", "--demo", "notes.npz",
                  "--run-dir", "runs", cwd=tmp_path)
    assert_one_line_error(proc, "notes.npz")
    assert not (tmp_path / "runs").exists() or list((tmp_path / "runs").iterdir()) == []
