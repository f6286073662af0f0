"""The package a user installs: a wheel built from a clean copy of the repository, used from
another folder, exports the user API and finds the demos shipped in `demos/`.

The wheel goes into a `--target` folder put on PYTHONPATH rather than into a fresh venv, so that
the dependencies (torch, ALE, ...) come from the test's own environment instead of being
reinstalled; every check asserts that `routine_gym` was imported from that folder, not from this
repository (whose editable install is on the test's path too).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from routine_gym.demo import DEMO_SUITE

SHIPPED_ENV_IDS = (*DEMO_SUITE, "MiniQbert-v0")
USER_API = ("RoutineActionWrapper", "SequiturMiner", "DemoRecorder", "RoutineLibrary", "Demo")


@pytest.fixture(scope="module")
def installed(repo_root, tmp_path_factory) -> dict[str, Path]:
    """Build a wheel from a clean copy of the repository and install it into a folder."""
    root = tmp_path_factory.mktemp("install")
    # A clean checkout: nothing from an earlier build (`build/lib` keeps every file it ever
    # held) can stand in for a file the package data misses.
    src = root / "src"
    shutil.copytree(repo_root, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "runs", "logs", "*.egg-info", "__pycache__", "*.so",
        ".*cache", ".hypothesis"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(root / "wheel"), str(src)], check=True, timeout=600)
    (wheel,) = (root / "wheel").glob("routine_gym-*.whl")
    site = root / "site"
    subprocess.run([*pip, "install", "--no-deps", "--no-compile", "-q", "--target", str(site),
                    str(wheel)], check=True, timeout=600)
    elsewhere = root / "elsewhere"  # the cwd: neither the repository nor the source copy
    elsewhere.mkdir()
    return {"site": site, "cwd": elsewhere}


def _run(installed: dict[str, Path], *cmd: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(installed["site"])}
    return subprocess.run(cmd, cwd=installed["cwd"], env=env, capture_output=True, text=True,
                          timeout=300)


def _python(installed: dict[str, Path], code: str) -> dict:
    proc = _run(installed, sys.executable, "-c", code)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_installed_package_exports_the_user_api(installed):
    out = _python(installed, (
        "import json, routine_gym\n"
        f"from routine_gym import {', '.join(USER_API)}\n"
        "import gymnasium as gym\n"
        "import sys\n"
        "own = 'MiniQbert-v0' in gym.registry and 'procgen/CoinRun-v0' in gym.registry\n"
        "light = 'ale_py' not in sys.modules and 'procgen' not in sys.modules\n"
        "routine_gym.register_envs()\n"
        "print(json.dumps({'file': routine_gym.__file__, 'all': routine_gym.__all__,\n"
        "    'own': own, 'light': light, 'ale': 'ALE/Qbert-v5' in gym.registry}))"
    ))
    assert Path(out["file"]).is_relative_to(installed["site"])
    assert set(USER_API) <= set(out["all"])
    assert out["own"]  # importing routine_gym registers its envs ...
    assert out["light"]  # ... without loading ALE or Procgen
    assert out["ale"]  # register_envs() adds ALE's


@pytest.mark.slow
def test_installed_shipped_demo_path_finds_each_suite_demo_in_the_install(installed):
    out = _python(installed, (
        "import json, routine_gym\n"
        "from routine_gym.demo import DEMOS_DIR, shipped_demo_path\n"
        f"ids = {list(SHIPPED_ENV_IDS)!r}\n"
        "print(json.dumps({'file': routine_gym.__file__, 'dir': DEMOS_DIR,\n"
        "    'paths': {env_id: shipped_demo_path(env_id) for env_id in ids}}))"
    ))
    package = installed["site"] / "routine_gym"
    assert Path(out["file"]).is_relative_to(package)
    assert Path(out["dir"]) == package / "demos"
    assert (package / "demos" / "README.md").is_file()
    for env_id, path in out["paths"].items():
        assert path is not None, f"the install has no demo for {env_id}"
        assert Path(path).is_file() and Path(path).is_relative_to(package / "demos")


@pytest.mark.slow
def test_installed_show_demos_lists_the_eight_shipped_demos(installed):
    proc = _run(installed, str(installed["site"] / "bin" / "routine-gym"), "show-demos")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    demos_dir = installed["site"] / "routine_gym" / "demos"
    assert lines[0] == f"{len(SHIPPED_ENV_IDS)} demo(s) in {demos_dir}"
    # Each demo's first line starts with its env id; its details are indented below it.
    listed = [line.split()[0] for line in lines[1:] if line and not line.startswith(" ")]
    assert sorted(listed) == sorted(SHIPPED_ENV_IDS)
    assert "no demo in" not in proc.stdout


def test_an_editable_install_reads_the_repositorys_demos_folder_in_place(repo_root):
    import routine_gym.demo

    if not Path(routine_gym.demo.__file__).is_relative_to(repo_root):
        pytest.skip("routine_gym is not imported from this repository")
    assert Path(routine_gym.demo.DEMOS_DIR) == repo_root / "demos"


@pytest.mark.slow
def test_installed_experiment_runs_the_scripts_shipped_in_the_package(installed, tmp_path):
    out = tmp_path / "sweep"
    proc = _run(installed, str(installed["site"] / "bin" / "routine-gym"), "experiment", "run",
                "rl", "--budget", "smoke", "--out", str(out), "--jobs", "2")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    results = sorted(out.glob("runs/*/result.json"))
    assert len(results) == 5  # A2C, RAPL-A2C (rapl_a2c.py), PPO, RAPL-PPO, MacroAction-PPO
    scripts = []
    for result in results:
        log = (result.parent / "log.txt").read_text()
        script = json.loads((result.parent / "config.json").read_text())["script"]
        assert str(installed["site"] / "routine_gym" / "algos" / f"{script}.py") in log
        scripts.append(script)
    assert sorted(scripts) == ["rapl_a2c"] * 2 + ["rapl_ppo"] * 3

def test_installed_package_carries_the_compiled_cores(installed):
    """The wheel's extensions load from the install, and the wrapper steps through its core."""
    out = _python(installed, (
        "import json, importlib\n"
        "import gymnasium as gym\n"
        "from routine_gym import RoutineActionWrapper\n"
        "names = ['_sequitur', '_minatar_core', '_records', '_masked_gru', '_wrapper_core']\n"
        "files = {n: importlib.import_module('routine_gym.' + n).__file__ for n in names}\n"
        "env = RoutineActionWrapper(gym.make('CartPole-v1'), [[0, 1]])\n"
        "env.reset(seed=0)\n"
        "info = env.step(2)[4]\n"
        "print(json.dumps({'files': files, 'core': type(env.step.__self__).__name__,\n"
        "    'actions': info['routine_actions'].tolist()}))"
    ))
    for name, file in out["files"].items():
        assert Path(file).is_relative_to(installed["site"]), name
    assert out["core"] == "Stepper"
    assert out["actions"] == [0, 1]
