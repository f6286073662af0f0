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


def _install(repo_root: Path, root: Path, env: dict[str, str] | None = None) -> dict:
    """Build a wheel from a clean copy of the repository (under `env`) and install it into a
    folder: the folder, a cwd elsewhere, and the build's output."""
    # A clean checkout: nothing from an earlier build (`build/lib` keeps every file it ever
    # held) can stand in for a file the package data misses.
    src = root / "src"
    shutil.copytree(repo_root, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "runs", "logs", "*.egg-info", "__pycache__", "*.so",
        ".*cache", ".hypothesis"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    # -v: pip shows the build's own lines (which cores it skipped) only when verbose.
    build = subprocess.run([*pip, "wheel", "--no-deps", "--no-build-isolation", "-v", "-w",
                            str(root / "wheel"), str(src)], capture_output=True, text=True,
                           timeout=600, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    (wheel,) = (root / "wheel").glob("routine_gym-*.whl")
    site = root / "site"
    subprocess.run([*pip, "install", "--no-deps", "--no-compile", "-q", "--target", str(site),
                    str(wheel)], check=True, timeout=600)
    elsewhere = root / "elsewhere"  # the cwd: neither the repository nor the source copy
    elsewhere.mkdir()
    return {"site": site, "cwd": elsewhere, "build": build.stdout + build.stderr}


@pytest.fixture(scope="module")
def installed(repo_root, tmp_path_factory) -> dict[str, Path]:
    """Build a wheel from a clean copy of the repository and install it into a folder."""
    return _install(repo_root, tmp_path_factory.mktemp("install"))


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
    assert lines[0] == (f"{len(SHIPPED_ENV_IDS)} demo(s) in {demos_dir} (demo set `current`: "
                        "what every script reads by default)")
    # The older set `first` follows the current one, from the install's package data too.
    older = next(i for i, line in enumerate(lines) if "of the older demo set `first`" in line)
    assert lines[older].startswith(f"5 demo(s) of the older demo set `first` in {demos_dir}")
    # Each demo's first line starts with its env id; its details are indented below it.
    listed = [line.split()[0] for line in lines[1:older] if line and not line.startswith(" ")]
    assert sorted(listed) == sorted(SHIPPED_ENV_IDS)
    older_listed = [line.split()[0] for line in lines[older + 1:]
                    if line and not line.startswith(" ")]
    assert sorted(older_listed) == sorted(e for e in SHIPPED_ENV_IDS if e.startswith("MinAtar/"))
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


def test_without_a_compiler_the_install_skips_every_core_and_the_twins_run(repo_root, tmp_path):
    """`CC=false CXX=false`: no C++ compiler. The wheel builds, the build names the cores it
    skipped, and the installed package mines, steps MinAtar and fits CompILE's GRU in Python,
    with one warning per core it wanted."""
    env = {**os.environ, "CC": "false", "CXX": "false"}
    install = _install(repo_root, tmp_path, env)
    assert ("routine-gym: skipped the compiled cores sequitur, minatar_core, masked_gru; their "
            "Python twins run instead") in install["build"]
    out = _python(install, (
        "import json, os, warnings\n"
        "os.environ.pop('ROUTINE_GYM_NATIVE', None)  # the cores wanted: none there\n"
        "warnings.simplefilter('always')\n"
        "import numpy as np, torch\n"
        "from routine_gym import _native\n"
        "from routine_gym.sequitur import induce\n"
        "from routine_gym.envs.minatar_vector import MinAtarVectorEnv\n"
        "from routine_gym.baselines.compile.masked_gru import masked_gru\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    rules = induce([0, 1, 0, 1]).rules\n"
        "    envs = MinAtarVectorEnv('MinAtar/Breakout-v1', 2)\n"
        "    envs.reset(seed=0)\n"
        "    shape = envs.step(np.array([0, 1]))[0].shape\n"
        "    gru = masked_gru(torch.zeros(1, 2, 6, requires_grad=True), torch.ones(1, 2),\n"
        "                     torch.zeros(6, 2), torch.zeros(6)).grad_fn.name()\n"
        "print(json.dumps({'cores': [_native.core(n) for n in _native.CORES],\n"
        "    'rules': str(rules), 'compiled': envs.compiled, 'shape': list(shape), 'gru': gru,\n"
        "    'warnings': sorted(str(w.message).split(' (')[0] for w in caught)}))"
    ))
    assert out["cores"] == [None, None, None]
    assert out["rules"] == "[(R1, R1), (0, 1)]"
    assert not out["compiled"] and out["shape"] == [2, 4, 10, 10]
    assert out["gru"].startswith("_TorchMaskedGRU")
    assert out["warnings"] == [f"the compiled core '{name}' is not built"
                               for name in ("masked_gru", "minatar_core", "sequitur")]


def test_installed_package_carries_the_compiled_cores(installed):
    """The wheel carries each core this machine's compiler builds, and it loads from the
    install (whatever `ROUTINE_GYM_NATIVE` says: it is the files that are checked)."""
    import importlib.util

    from routine_gym import _native

    if any(importlib.util.find_spec(f"routine_gym._native._{n}") is None for n in _native.CORES):
        pytest.skip("this checkout's own install has no compiled cores (no C++17 compiler)")
    out = _python(installed, (
        "import json, importlib.util\n"
        "from routine_gym import _native\n"
        "files = {n: importlib.util.find_spec(f'routine_gym._native._{n}').origin\n"
        "         for n in _native.CORES}\n"
        "print(json.dumps({'files': files}))"
    ))
    assert sorted(out["files"]) == ["masked_gru", "minatar_core", "sequitur"]
    for name, file in out["files"].items():
        assert Path(file).is_relative_to(installed["site"]) and file.endswith(".so"), name
