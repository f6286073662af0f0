"""MinAtar: the five games registered on import, their profile, replayable demos, and every
script and CLI command running on them."""

from __future__ import annotations

import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
import torch

import routine_gym  # noqa: F401  (registers the MinAtar games)
from routine_gym.demo import record_agent_demo, record_human_demo, replay
from routine_gym.envs import profile_for
from routine_gym.envs.factory import make_env
from routine_gym.envs.minatar import GAMES, MAX_EPISODE_STEPS
from routine_gym.networks import ObservationEncoder

IDS = [f"MinAtar/{name}-v1" for name in GAMES]
#: MinAtar's minimal action sets (its games' `minimal_action_set`), in ALE's names.
MINIMAL = {
    "Asterix": ["NOOP", "LEFT", "UP", "RIGHT", "DOWN"],
    "Breakout": ["NOOP", "LEFT", "RIGHT"],
    "Freeway": ["NOOP", "UP", "DOWN"],
    "Seaquest": ["NOOP", "LEFT", "UP", "RIGHT", "DOWN", "FIRE"],
    "SpaceInvaders": ["NOOP", "LEFT", "RIGHT", "FIRE"],
}
CHANNELS = {"Asterix": 4, "Breakout": 4, "Freeway": 7, "Seaquest": 10, "SpaceInvaders": 6}


@pytest.mark.parametrize("name", list(GAMES))
def test_each_game_is_registered_with_minatar_defaults(name):
    env = gym.make(f"MinAtar/{name}-v1")
    assert env.spec.max_episode_steps == MAX_EPISODE_STEPS
    game = env.unwrapped.game
    assert game.sticky_action_prob == 0.1 and env.unwrapped.difficulty_ramping is True
    assert getattr(game.env, "ramping", True) is True  # Breakout and Freeway have none
    assert env.unwrapped.get_action_meanings() == MINIMAL[name]
    assert env.action_space == gym.spaces.Discrete(len(MINIMAL[name]))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (10, 10, CHANNELS[name]) and obs.dtype == np.bool_


@pytest.mark.parametrize("env_id", IDS)
def test_the_profile_gives_channels_first_floats_and_the_minatar_network(env_id):
    profile = profile_for(env_id)
    assert profile.family == "minatar" and profile.frame_stack == 1
    assert profile.network == "minatar" and profile.score_key(env_id) is None
    env = make_env(env_id, 0, 0, training=True)()
    obs, _ = env.reset(seed=1)
    c = obs.shape[0]
    assert obs.shape == (c, 10, 10) and obs.dtype == np.float32
    assert set(np.unique(obs)) <= {0.0, 1.0}
    # Training and evaluation views are the same (no life tricks, no reward clipping).
    obs, reward, *_ = env.step(0)
    assert isinstance(reward, float)
    eval_obs, _ = make_env(env_id, 0, 0, training=False)().reset(seed=1)
    np.testing.assert_array_equal(make_env(env_id, 0, 0)().reset(seed=1)[0], eval_obs)
    # One 3×3 convolution of 16 channels over the 10×10 frame, then 128 units.
    encoder = ObservationEncoder(env_id, (c, 10, 10), np.float32)
    conv, linear = encoder.torso[0], encoder.torso[3]
    assert (conv.in_channels, conv.out_channels, conv.kernel_size) == (c, 16, (3, 3))
    assert (linear.in_features, linear.out_features, encoder.num_features) == (16 * 8 * 8, 128,
                                                                               128)
    assert encoder(torch.as_tensor(obs[None])).shape == (1, 128)


def test_an_episode_replays_from_its_seed_whatever_came_before():
    # MinAtar keeps the last (sticky) action across episodes; routine-gym's reset forgets it,
    # so a demo's episode replays from its seed alone.
    rng = np.random.default_rng(0)
    demo = record_agent_demo("MinAtar/SpaceInvaders-v1", lambda obs: int(rng.integers(4)),
                             num_episodes=3, seed=5, keep="all", progress=False,
                             record_observations=True)
    for episode in range(3):
        assert replay(demo, episode=episode).matched
    assert replay(demo).matched


def test_minatar_renders_rgb_and_is_playable_with_the_keyboard(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    env = gym.make("MinAtar/Seaquest-v1", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (160, 160, 3) and frame.dtype == np.uint8 and frame.any()
    keys = env.unwrapped.get_keys_to_action()
    assert keys == {("a",): 1, ("w",): 2, ("d",): 3, ("s",): 4, (" ",): 5}
    # A real pygame play loop with no key pressed: NOOP until Breakout's ball is lost.
    demo = record_human_demo("MinAtar/Breakout-v1", seed=3, fps=5000)
    assert demo.meta["source"] == "human" and demo.decisions.all()
    assert set(demo.actions.tolist()) == {0} and replay(demo).matched


@pytest.fixture(scope="module")
def breakout_demo(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("minatar") / "breakout.npz"
    proc = subprocess.run(
        [sys.executable, "-m", "routine_gym.cli", "record", "MinAtar/Breakout-v1",
         "--policy", "random", "--episodes", "10", "--keep", "all", "--seed", "0",
         "--out", str(path)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    return str(path)


def test_the_cli_records_replays_mines_and_shows_a_minatar_demo(breakout_demo):
    def cli(*args):
        proc = subprocess.run([sys.executable, "-m", "routine_gym.cli", *args],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout

    assert "matches the recording" in cli("replay", breakout_demo)
    assert "RoutineLibrary" in cli("mine", breakout_demo, "--num-routines", "2")
    shown = cli("show", breakout_demo)
    assert "MinAtar/Breakout-v1" in shown and "NOOP" in shown


# rapl_a2c --mode rapl and gail on MinAtar run in tests/test_as_a_user.py.
@pytest.mark.parametrize(("script", "extra"), [
    ("rapl_a2c", ["--mode", "a2c"]), ("rapl_a2c", ["--mode", "macro"]), ("rapl_sqil", []),
    ("bc", []),
])
def test_every_script_runs_on_minatar(script, extra, breakout_demo, tmp_path, repo_root):
    budget = ["--gradient-steps", "50"] if script == "bc" else ["--total-timesteps", "400"]
    if script == "rapl_sqil":
        budget += ["--learning-starts", "100"]
    proc = subprocess.run(
        [sys.executable, str(repo_root / "algos" / f"{script}.py"), "--env-id",
         "MinAtar/Breakout-v1",
         # --mode a2c reads no demo (and refuses one)
         *([] if extra == ["--mode", "a2c"] else ["--demo", breakout_demo]), *budget, *extra,
         "--eval-episodes", "2", "--run-dir", str(tmp_path)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    (summary_path,) = tmp_path.glob("*/eval.json")
    summary = json.loads(summary_path.read_text())
    assert summary["env_id"] == "MinAtar/Breakout-v1" and len(summary["returns"]) == 2
    assert "human_normalized_score" not in summary
