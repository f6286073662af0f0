"""Nonsense values are refused by name before any work: `inf`, NaN and negative values of the
scripts' and the CLI's flags, a rollout longer than the budget, a checkpoint whose saved
settings were edited into nonsense, and an output that is one of the inputs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from script_loader import load_script

from routine_gym.cli import main as cli_main
from routine_gym.plumbing.errors import UsageError

REPO = Path(__file__).resolve().parent.parent
DEMO = str(REPO / "demos" / "MiniQbert-v0.npz")
SCRIPTS = {name: load_script(name, f"nonsense_{name}")
           for name in ("rapl_a2c", "rapl_sqil", "bc", "gail", "option_critic", "compile_a2c")}


@pytest.mark.parametrize(("script", "setting", "message"), [
    ("option_critic", {"term_coef": float("inf")},
     "--term-coef needs to be a finite number, actual value: inf"),
    ("option_critic", {"deliberation_cost": float("nan")},
     "--deliberation-cost needs to be a finite number, actual value: nan"),
    ("option_critic", {"option_epsilon": -0.5}, "--option-epsilon needs to be in [0, 1]"),
    ("compile_a2c", {"compile_prior_rate": float("inf")},
     "--compile-prior-rate needs to be a finite number, actual value: inf"),
    ("compile_a2c", {"compile_learning_rate": float("inf")},
     "--compile-learning-rate needs to be a finite number, actual value: inf"),
    ("compile_a2c", {"compile_option_steps": -1},
     "--compile-option-steps needs to be ≥ 0, actual value: -1"),
    ("rapl_a2c", {"learning_rate": float("nan")}, "--learning-rate needs to be > 0"),
    ("rapl_a2c", {"ent_coef": float("inf")}, "--ent-coef needs to be ≥ 0, actual value: inf"),
    ("rapl_a2c", {"num_steps": 10**6, "total_timesteps": 500},
     "--num-steps needs to be ≤ --total-timesteps (500), actual value: 1,000,000"),
    ("gail", {"num_steps": 10**6, "total_timesteps": 500}, "--num-steps needs to be ≤"),
    # Past its own upper bound (memory follows from it), whatever the budget.
    ("rapl_a2c", {"num_steps": 10**11, "total_timesteps": 10**12},
     "--num-steps needs to be ≤ 1,048,576, actual value: 100000000000"),
    ("rapl_sqil", {"tau": float("inf")}, "--tau needs to be in (0, 1], actual value: inf"),
    ("bc", {"learning_rate": -1.0}, "--learning-rate needs to be > 0, actual value: -1.0"),
])
def test_nonsense_settings_of_the_scripts_are_refused_by_name(script, setting, message,
                                                              tmp_path):
    module = SCRIPTS[script]
    args = module.Args(env_id="MiniQbert-v0", run_dir=str(tmp_path), **setting)
    with pytest.raises(UsageError) as refused:
        module.main(args)
    assert message in str(refused.value)
    assert os.listdir(tmp_path) == []  # refused before a run folder was made


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory) -> Path:
    """A real rapl_a2c run of a few hundred steps that left a checkpoint."""
    folder = tmp_path_factory.mktemp("run")
    proc = subprocess.run(
        [sys.executable, str(REPO / "algos" / "rapl_a2c.py"), "--env-id", "MiniQbert-v0",
         "--mode", "a2c", "--num-envs", "2", "--total-timesteps", "200",
         "--checkpoint-every", "100", "--eval-episodes", "1", "--run-dir", str(folder)],
        capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (path,) = folder.glob("*/checkpoint.pt")
    return path


@pytest.mark.parametrize(("edit", "message"), [
    ({"gamma": 5.0}, "its saved settings are not valid (--gamma needs to be in (0, 1], "
                     "actual value: 5.0)"),
    ({"ent_coef": float("inf")}, "--ent-coef needs to be ≥ 0, actual value: inf"),
    ({"num_envs": "two"}, "its saved setting num_envs is 'two', not a value of the kind int"),
    ({"anneal_lr": 1}, "its saved setting anneal_lr is 1, not a value of the kind bool"),
    ({"num_steps": 10**6}, "--num-steps needs to be ≤ --total-timesteps"),
    # Issue 46: a checkpoint's 10^7 envs would hang at 2 GB; refused before any work.
    ({"num_envs": 10**7}, "its saved settings are not valid (--num-envs needs to be ≤ 1,024, "
                          "actual value: 10000000)"),
    ({"torch_threads": 100_000}, "--torch-threads needs to be ≤"),
])
def test_settings_restored_by_resume_are_checked(edit, message, checkpoint, tmp_path):
    state = torch.load(checkpoint, weights_only=True)
    state["args"] = json.dumps({**json.loads(state["args"]), **edit})
    run = tmp_path / "edited"
    run.mkdir()
    torch.save(state, run / "checkpoint.pt")
    proc = subprocess.run([sys.executable, str(REPO / "algos" / "rapl_a2c.py"),
                           "--resume", str(run)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith(f"rapl_a2c.py: error: --resume {run / 'checkpoint.pt'}"), line
    assert message in line, line


@pytest.mark.parametrize(("argv", "message"), [
    (["mine", DEMO, "--num-routines", "0"], "--num-routines needs to be ≥ 1, actual value: 0"),
    (["mine", DEMO, "--length-weight", "inf"],
     "--length-weight needs to be a finite number, actual value: inf"),
    (["mine", DEMO, "--length-weight", "nan"], "--length-weight needs to be ≥ 0"),
    (["mine", DEMO, "--alpha", "-1"], "--alpha needs to be ≥ 1, actual value: -1"),
    (["show", DEMO, "--head", "-5"], "--head needs to be ≥ 0, actual value: -5"),
    (["show-demos", "--num-routines", "-2"], "--num-routines needs to be ≥ 1"),
    (["replay", DEMO, "--episode", "-1"], "--episode needs to be ≥ 0, actual value: -1"),
    (["record", "MiniQbert-v0", "--out", "x.npz", "--episodes", "0"],
     "--episodes needs to be ≥ 1, actual value: 0"),
    (["record", "MiniQbert-v0", "--out", "x.npz", "--max-steps", "-3"],
     "--max-steps needs to be ≥ 1, actual value: -3"),
    (["record", "MiniQbert-v0", "--out", "x.npz", "--seed", "-1"], "--seed needs to be ≥ 0"),
    (["record", "MiniQbert-v0", "--out", "x.npz", "--expert-noise", "0.3"],
     "--expert-noise is the scripted expert's noise; --policy random takes none"),
    (["record", "MiniQbert-v0", "--out", "x.npz", "--policy", "expert", "--expert-noise",
      "inf"], "--expert-noise needs to be in [0, 1], actual value: inf"),
    (["play", "MiniQbert-v0", "--out", "x.npz", "--fps", "0"],
     "--fps needs to be ≥ 1, actual value: 0"),
    (["play", "MiniQbert-v0", "--out", "x.npz", "--zoom", "-2"], "--zoom needs to be > 0"),
    (["play", "MiniQbert-v0", "--out", "x.npz", "--episodes", "-1"], "--episodes needs to be"),
])
def test_nonsense_values_of_the_cli_are_refused_by_name(argv, message, capsys, tmp_path,
                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exited:
        cli_main(argv)
    assert exited.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert message in line, line
    assert os.listdir(tmp_path) == []


def test_mine_refuses_to_write_its_library_over_its_demo(tmp_path):
    demo = tmp_path / "X.npz"
    demo.write_bytes(Path(DEMO).read_bytes())
    before = demo.read_bytes()
    (tmp_path / "link.npz").symlink_to(demo)
    for out in ("X.npz", "./X.npz", str(demo), "link.npz"):
        proc = subprocess.run([sys.executable, "-m", "routine_gym.cli", "mine", "X.npz",
                               "--out", out], cwd=tmp_path, capture_output=True, text=True,
                              timeout=60)
        assert proc.returncode == 2, proc.stderr
        (line,) = proc.stderr.strip().splitlines()
        assert f"--out {out} is the input X.npz; it would be overwritten" in line
    assert demo.read_bytes() == before


@pytest.mark.parametrize("script", sorted(SCRIPTS))
def test_a_run_dir_under_a_file_or_on_an_unwritable_place_is_refused_by_name(script,
                                                                             tmp_path):
    (tmp_path / "notes.txt").write_text("a file where a folder should be")
    module = SCRIPTS[script]
    for run_dir, message in ((tmp_path / "notes.txt" / "runs",
                              f"--run-dir {tmp_path / 'notes.txt' / 'runs'}: "
                              f"{tmp_path / 'notes.txt'} is a file, not a folder"),
                             (tmp_path / "notes.txt",
                              f"--run-dir {tmp_path / 'notes.txt'} is a file, not a folder"),
                             ("/sys/runs", "--run-dir /sys/runs: cannot write there")):
        with pytest.raises(UsageError) as refused:
            module.main(module.Args(env_id="MiniQbert-v0", run_dir=str(run_dir)))
        assert message in str(refused.value)
    assert sorted(os.listdir(tmp_path)) == ["notes.txt"]
