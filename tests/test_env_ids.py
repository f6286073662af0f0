"""Env ids are compared by their registered spec: Gymnasium's `module:EnvId` form works end to
end (record a demo, train every script from it) and gets its family's wrappers."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import routine_gym  # noqa: F401  (registers the envs)
from routine_gym.demo import Demo, shipped_demo_path
from routine_gym.envs import canonical_env_id, env_family, same_env
from routine_gym.envs.atari import EpisodicLife
from routine_gym.envs.factory import make_env

MODULE_ID = "routine_gym.envs.miniqbert:MiniQbert-v0"


def _wrapper_types(env) -> list[type]:
    types = []
    while hasattr(env, "env"):
        types.append(type(env))
        env = env.env
    return types


@pytest.mark.parametrize(
    ("env_id", "family", "canonical"),
    [
        ("ALE/Qbert-v5", "atari", "ALE/Qbert-v5"),
        ("ale_py:ALE/Qbert-v5", "atari", "ALE/Qbert-v5"),
        ("QbertNoFrameskip-v4", "atari", "QbertNoFrameskip-v4"),
        ("procgen/CoinRun-v0", "procgen", "procgen/CoinRun-v0"),
        ("MiniQbert-v0", "miniqbert", "MiniQbert-v0"),
        (MODULE_ID, "miniqbert", "MiniQbert-v0"),
        ("CartPole-v1", "generic", "CartPole-v1"),
        ("gymnasium.envs.classic_control:CartPole-v1", "generic", "CartPole-v1"),
    ],
)
def test_family_and_canonical_id_come_from_the_registered_spec(env_id, family, canonical):
    assert env_family(env_id) == family
    assert canonical_env_id(env_id) == canonical
    assert same_env(env_id, canonical)


def test_a_module_id_gets_its_familys_training_wrappers():
    # MiniQbert trains with EpisodicLife (a life loss ends the training episode), whatever the
    # id's spelling; evaluation does not.
    assert EpisodicLife in _wrapper_types(make_env(MODULE_ID, 0, 0, training=True)())
    assert EpisodicLife not in _wrapper_types(make_env(MODULE_ID, 0, 0, training=False)())
    atari = _wrapper_types(make_env("ale_py:ALE/Breakout-v5", 0, 0, training=True)())
    assert EpisodicLife in atari


def test_a_module_id_finds_the_shipped_demo_and_loads_demos_of_its_env():
    assert shipped_demo_path(MODULE_ID) == shipped_demo_path("MiniQbert-v0") is not None
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"), env_id=MODULE_ID)
    assert demo.env_id == "MiniQbert-v0"
    assert not same_env(MODULE_ID, "CartPole-v1")


@pytest.mark.slow
@pytest.mark.parametrize("script", ["rapl_a2c", "rapl_sqil", "bc", "gail"])
def test_every_script_trains_from_a_demo_recorded_with_a_module_id(script, tmp_path, repo_root):
    demo_path = tmp_path / "mq.npz"
    record = subprocess.run(
        [sys.executable, "-m", "routine_gym.cli", "record", MODULE_ID, "--policy", "expert",
         "--expert-noise", "0.1", "--episodes", "2", "--out", str(demo_path)],
        capture_output=True, text=True, timeout=120,
    )
    assert record.returncode == 0, record.stderr
    assert Demo.load(demo_path).env_id == "MiniQbert-v0"
    run = subprocess.run(
        [sys.executable, str(repo_root / "algos" / f"{script}.py"), "--env-id", MODULE_ID,
         "--demo", str(demo_path), "--gradient-steps" if script == "bc" else "--total-timesteps",
         "200", "--eval-episodes", "1",
         "--run-dir", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    evals = list((tmp_path / "runs").glob("*/eval.json"))
    assert len(evals) == 1
    assert json.loads(evals[0].read_text())["mean_return"] >= 0
