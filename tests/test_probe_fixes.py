"""What the probe of issue 46's surfaces (`bench/probe_issue46.py`) found after the issue's fixes,
each run as a user runs it: an empty text flag taken as unset (`--record-demo ''` recorded
nothing and exited 0), a `--record-demo` over the run's own `--demo`, `--num-routines 0` with
routines (a KeyError mid-run), `rapl_ppo.py --prim-epochs` outside `--mode rapl` (ignored), a
`WANDB_MODE` W&B refuses (a pydantic traceback), `experiment run --jobs 1000000` (a process a
job, unbounded), a bad `ROUTINE_GYM_NATIVE` for `python -m routine_gym._native` (a traceback),
and the local Minari folder: relative (every export failed), a file or empty (a traceback), or
an id part longer than a file name (an OSError traceback)."""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from one_line import assert_one_line_error
from script_loader import load_script
from test_as_a_user import BIN, REPO, ok

from routine_gym.errors import UsageError
from routine_gym.plumbing.arguments import check_args

DEMO = REPO / "demos" / "MiniQbert-v0.npz"
TINY = ["--env-id", "MiniQbert-v0", "--total-timesteps", "500", "--eval-episodes", "1",
        "--num-envs", "2"]


def run(*words: str | Path, cwd: Path, **env: str) -> subprocess.CompletedProcess:
    """A user's command (`routine-gym ...`, or a script of algos/ by its name) in a shell with
    PATH, HOME and the variables given, nothing else."""
    words = [str(w) for w in words]
    if words[0] == "routine-gym":
        argv = [str(BIN / "routine-gym"), *words[1:]]
    else:
        argv = [str(BIN / "python"), str(REPO / "algos" / f"{words[0]}.py"), *words[1:]]
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL,
                          env={"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd),
                               "LANG": "C.UTF-8", **env})


# -- an empty text flag ---------------------------------------------------------------------


@pytest.mark.parametrize("script", ["rapl_a2c", "rapl_ppo", "rapl_sqil", "option_critic",
                                    "compile_a2c", "gail", "bc"])
def test_every_scripts_text_flags_refuse_an_empty_value(script):
    module = load_script(script)
    texts = [f.name for f in dataclasses.fields(module.Args)
             if f.type in ("str", "str | None") and f.name != "env_id"]
    assert "run_dir" in texts and "exp_name" in texts
    for name in texts:
        args = module.Args(env_id="MiniQbert-v0", **{name: ""})
        with pytest.raises(UsageError, match=f"--{name.replace('_', '-')} needs a value"):
            check_args(args, getattr(module, "extra_checks", ()))


@pytest.mark.parametrize("flag", ["--record-demo", "--resume", "--demo"])
def test_an_empty_output_or_input_is_one_line_and_no_run(flag, tmp_path):
    # `--record-demo ''` trained, recorded nothing and exited 0; `--resume ''` started anew.
    proc = run("rapl_a2c", *TINY, flag, "", cwd=tmp_path)
    assert_one_line_error(proc, flag, "needs a value", prefix="rapl_a2c.py: error:")
    assert not (tmp_path / "runs").exists()


# -- an output over an input ----------------------------------------------------------------


def test_record_demo_over_the_runs_own_demo_is_refused_before_training(tmp_path):
    shutil.copy(DEMO, tmp_path / "mine.npz")
    before = hashlib.sha256((tmp_path / "mine.npz").read_bytes()).hexdigest()
    (tmp_path / "link.npz").symlink_to("mine.npz")
    for recorded in ("mine.npz", "./mine.npz", "link.npz"):
        proc = run("rapl_a2c", *TINY, "--demo", "mine.npz", "--record-demo", recorded,
                   cwd=tmp_path)
        assert_one_line_error(proc, f"--record-demo {recorded} is the input mine.npz",
                              "would be overwritten")
    assert hashlib.sha256((tmp_path / "mine.npz").read_bytes()).hexdigest() == before
    assert not (tmp_path / "runs").exists()


# -- K = 0 with routines --------------------------------------------------------------------


@pytest.mark.parametrize(("script", "plain"), [("rapl_a2c", "a2c"), ("rapl_ppo", "ppo")])
def test_num_routines_0_needs_the_mode_without_routines(script, plain):
    module = load_script(script)
    for mode in ("rapl", "macro"):
        args = module.Args(env_id="MiniQbert-v0", mode=mode, num_routines=0)
        with pytest.raises(UsageError, match=rf"--num-routines needs to be ≥ 1 with --mode "
                                             rf"\{{rapl,macro\}} \(--mode {plain} has"):
            check_args(args, module.extra_checks)
        check_args(module.Args(env_id="MiniQbert-v0", mode=mode, num_routines=1),
                   module.extra_checks)


def test_num_routines_0_is_one_line_not_a_key_error_mid_run(tmp_path):
    proc = run("rapl_a2c", *TINY, "--num-routines", "0", cwd=tmp_path)
    assert_one_line_error(proc, "--num-routines needs to be ≥ 1 with --mode {rapl,macro}",
                          "actual value: 0")
    assert not (tmp_path / "runs").exists()


def test_prim_epochs_needs_mode_rapl_as_prim_coef_does():
    module = load_script("rapl_ppo")
    for mode in ("ppo", "macro"):
        args = module.Args(env_id="MiniQbert-v0", mode=mode, prim_epochs=2)
        with pytest.raises(UsageError, match="--prim-epochs needs to be 1 \\(unset\\) unless "
                                             "--mode rapl, actual value: 2"):
            check_args(args, module.extra_checks)
        for unset in (None, 1):  # 1: what family_defaults gives every new run
            check_args(module.Args(env_id="MiniQbert-v0", mode=mode, prim_epochs=unset),
                       module.extra_checks)
    check_args(module.Args(env_id="MiniQbert-v0", mode="rapl", prim_epochs=2, update_epochs=4),
               module.extra_checks)


def test_prim_epochs_with_mode_ppo_is_one_line_as_a_user(tmp_path):
    proc = run("rapl_ppo", *TINY, "--mode", "ppo", "--prim-epochs", "2", cwd=tmp_path)
    assert_one_line_error(proc, "--prim-epochs needs to be 1 (unset) unless --mode rapl")
    assert not (tmp_path / "runs").exists()


# -- WANDB_MODE -----------------------------------------------------------------------------


def test_a_wandb_mode_wandb_refuses_is_one_line_before_the_run_folder(tmp_path):
    pytest.importorskip("wandb")
    proc = run("rapl_a2c", *TINY, "--track", cwd=tmp_path, WANDB_MODE="garbage")
    assert_one_line_error(proc, "WANDB_MODE=garbage: W&B refuses it", "'offline'")
    assert "[type=" not in proc.stderr
    assert not (tmp_path / "runs").exists()
    proc = run("routine-gym", "experiment", "run", "rl", "--budget", "smoke", "--out", "sw",
               "--track", cwd=tmp_path, WANDB_MODE="garbage")
    assert_one_line_error(proc, "WANDB_MODE=garbage")
    assert not (tmp_path / "sw").exists()


# -- processes and cores --------------------------------------------------------------------


def test_jobs_has_an_upper_bound_before_the_sweep_folder(tmp_path):
    from routine_gym.plumbing.arguments import MAX_TORCH_THREADS, usable_cpus

    proc = run("routine-gym", "experiment", "run", "rl", "--budget", "smoke", "--out", "sw",
               "--jobs", "1000000", cwd=tmp_path)
    assert_one_line_error(proc, f"--jobs needs to be ≤ {MAX_TORCH_THREADS:,} (4 × the "
                          f"{usable_cpus()} CPUs", "actual value: 1,000,000")
    assert not (tmp_path / "sw").exists()


def test_a_bad_native_variable_is_one_line_for_the_cores_report(tmp_path):
    proc = subprocess.run([str(BIN / "python"), "-m", "routine_gym._native"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120,
                          env={"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path),
                               "ROUTINE_GYM_NATIVE": "bogus"})
    assert_one_line_error(proc, "ROUTINE_GYM_NATIVE=bogus: bogus is not a compiled core",
                          prefix="python -m routine_gym._native: error:")


# -- the local Minari folder ----------------------------------------------------------------


def test_a_relative_minari_folder_exports_and_reads_back(tmp_path):
    pytest.importorskip("minari")
    shutil.copy(DEMO, tmp_path / "mq.npz")
    # Minari joined a relative folder onto itself when writing: every export failed.
    out = ok(run("routine-gym", "export", "mq.npz", "--minari", "rg/mq-v0", cwd=tmp_path,
                 MINARI_DATASETS_PATH="datasets"))
    assert f"at {tmp_path / 'datasets' / 'rg' / 'mq-v0'}" in out
    assert (tmp_path / "datasets" / "rg" / "mq-v0" / "data" / "metadata.json").is_file()
    assert sorted(os.listdir(tmp_path / "datasets")) == ["rg"]  # no staging folder left
    mined = ok(run("routine-gym", "mine", "minari:rg/mq-v0", cwd=tmp_path,
                   MINARI_DATASETS_PATH="datasets"))
    assert "[0] len=4" in mined


@pytest.mark.parametrize("where", ["file", "file/below", ""])
def test_a_minari_folder_that_cannot_be_one_is_one_line(where, tmp_path):
    pytest.importorskip("minari")
    shutil.copy(DEMO, tmp_path / "mq.npz")
    (tmp_path / "file").write_text("x")
    for words in (["export", "mq.npz", "--minari", "rg/x-v0"], ["mine", "minari:rg/x-v0"]):
        proc = run("routine-gym", *words, cwd=tmp_path, MINARI_DATASETS_PATH=where)
        if where:
            assert_one_line_error(proc, f"MINARI_DATASETS_PATH={where}:",
                                  f"{tmp_path / 'file'} is a file, not a folder")
        else:
            assert_one_line_error(proc, "MINARI_DATASETS_PATH is empty")
    assert (tmp_path / "file").read_text() == "x"
    proc = run("rapl_a2c", *TINY, "--demo", "minari:rg/x-v0", cwd=tmp_path,
               MINARI_DATASETS_PATH=where)
    assert_one_line_error(proc, "MINARI_DATASETS_PATH")
    assert not (tmp_path / "runs").exists()


def test_a_minari_id_longer_than_a_file_name_is_one_line(tmp_path):
    pytest.importorskip("minari")
    shutil.copy(DEMO, tmp_path / "mq.npz")
    name = "a" * 256 + "-v0"  # 259 characters: over the 255 bytes of a file name
    for words in (["mine", f"minari:rg/{name}"], ["export", "mq.npz", "--minari", name]):
        proc = run("routine-gym", *words, cwd=tmp_path, MINARI_DATASETS_PATH="m")
        assert_one_line_error(proc, "a part of 259 characters",
                              "longer than a file name may be (255 bytes)")
    ok(run("routine-gym", "export", "mq.npz", "--minari", "a" * 251 + "-v0", cwd=tmp_path,
           MINARI_DATASETS_PATH="m"))  # 255 exactly: a file name
