"""ProcgenEnv: Procgen's gym3 games under the Gymnasium API, in the paper's CoinRun setting."""

from __future__ import annotations

import doctest
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import routine_gym  # noqa: F401  (registers procgen/CoinRun-v0)
import routine_gym.envs.procgen as procgen_module
from routine_gym.envs.procgen import PROCGEN_TIMEOUT, ProcgenEnv
from routine_gym.wrapper import RoutineActionWrapper

LEFT, DOWN, UP, RIGHT, NOOP = range(5)


def play(env: ProcgenEnv, seed: int, actions) -> tuple[np.ndarray, list, list]:
    """Frames, rewards and (terminated, truncated) flags of `actions` after `reset(seed)`."""
    obs, _ = env.reset(seed=seed)
    frames, rewards, flags = [obs], [], []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        frames.append(obs)
        rewards.append(reward)
        flags.append((terminated, truncated))
    return np.stack(frames), rewards, flags


def test_registered_coinrun_is_the_papers_setting():
    env = gym.make("procgen/CoinRun-v0")
    assert env.unwrapped.env_name == "coinrun"
    assert env.unwrapped.get_action_meanings() == ["LEFT", "DOWN", "UP", "RIGHT", "NOOP"]
    assert env.action_space == gym.spaces.Discrete(5)
    assert env.observation_space == gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    obs, info = env.reset(seed=0)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    assert isinstance(info["level_seed"], int) and 0 <= info["level_seed"] < 100
    env.close()


def test_minimal_actions_are_procgen_button_combinations():
    env = ProcgenEnv()
    assert env.combos == (("LEFT",), ("DOWN",), ("UP",), ("RIGHT",), ())
    # Procgen's combination table, where LEFT, DOWN, NOOP, UP, RIGHT are entries 1, 3, 4, 5, 7.
    procgen_combos = env._game.combos
    assert [procgen_combos.index(c) for c in env.combos] == [1, 3, 5, 7, 4]


def test_full_action_set_exposes_procgens_15_combinations():
    env = ProcgenEnv(use_minimal_actions=False)
    assert env.action_space == gym.spaces.Discrete(15)
    meanings = env.get_action_meanings()
    assert meanings[:9] == [
        "LEFT+DOWN", "LEFT", "LEFT+UP", "DOWN", "NOOP", "UP", "RIGHT+DOWN", "RIGHT", "RIGHT+UP",
    ]  # fmt: skip
    assert meanings[9:] == ["D", "A", "W", "S", "Q", "E"]


def test_check_env_passes():
    check_env(ProcgenEnv(), skip_render_check=True)


def test_check_env_passes_with_rgb_array_rendering():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*not having a spec.*")
        env = ProcgenEnv(render_mode="rgb_array")
        check_env(env)
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (512, 512, 3) and frame.dtype == np.uint8


def test_seeded_reset_replays_the_episode_exactly():
    actions = np.random.default_rng(0).choice([UP, RIGHT, RIGHT, RIGHT, LEFT], size=300)
    env = ProcgenEnv()
    frames_1, rewards_1, flags_1 = play(env, 7, actions)
    frames_2, rewards_2, flags_2 = play(env, 7, actions)
    np.testing.assert_array_equal(frames_1, frames_2)
    assert rewards_1 == rewards_2 and flags_1 == flags_2
    # ... including after episode ends, and from a fresh env object.
    assert any(terminated or truncated for terminated, truncated in flags_1)
    frames_3, rewards_3, _ = play(ProcgenEnv(), 7, actions)
    np.testing.assert_array_equal(frames_1, frames_3)
    assert rewards_1 == rewards_3
    # Another seed is another level sequence.
    frames_4, _, _ = play(env, 8, actions)
    assert not np.array_equal(frames_1, frames_4)


def test_large_seeds_are_folded_into_procgens_31_bit_range():
    env = ProcgenEnv()
    frames, _, _ = play(env, 5, [RIGHT] * 20)
    folded, _, _ = play(env, 2**31 + 5, [RIGHT] * 20)
    np.testing.assert_array_equal(frames, folded)


def test_velocity_is_not_painted_by_default():
    default, _, _ = play(ProcgenEnv(), 3, [RIGHT] * 5)
    without, _, _ = play(ProcgenEnv(paint_vel_info=False), 3, [RIGHT] * 5)
    painted, _, _ = play(ProcgenEnv(paint_vel_info=True), 3, [RIGHT] * 5)
    np.testing.assert_array_equal(default, without)
    assert not np.array_equal(default, painted)


def test_timeout_is_reported_as_truncation_at_step_1000():
    env = ProcgenEnv()
    env.reset(seed=1)  # standing still at the start of an easy level is safe
    for t in range(1, PROCGEN_TIMEOUT + 1):
        _, reward, terminated, truncated, info = env.step(NOOP)
        assert not terminated and reward == 0.0
        assert truncated == (t == PROCGEN_TIMEOUT)
    assert info["level_complete"] is False


def test_reset_mid_episode_starts_a_new_episode():
    env = ProcgenEnv()
    env.reset(seed=1)
    for _ in range(10):
        env.step(NOOP)
    env.reset()
    # Had Procgen's episode not been restarted, its timeout would fall 10 steps early.
    for t in range(1, PROCGEN_TIMEOUT + 1):
        _, _, terminated, truncated, _ = env.step(NOOP)
        assert not terminated
        assert truncated == (t == PROCGEN_TIMEOUT)


def test_level_completion_terminates_with_the_coin_reward():
    env = ProcgenEnv()
    env.reset(seed=2)
    policy = np.random.default_rng(0)
    completed = died = 0
    for _ in range(600):
        action = int(policy.choice([UP, RIGHT, RIGHT, RIGHT]))
        _, reward, terminated, truncated, info = env.step(action)
        assert not truncated
        if terminated:
            assert reward == (10.0 if info["level_complete"] else 0.0)
            completed += info["level_complete"]
            died += not info["level_complete"]
            env.reset()
        else:
            assert reward == 0.0 and info["level_complete"] is False
    assert completed > 0 and died > 0


def test_terminal_observation_is_the_next_episodes_first_frame():
    env = ProcgenEnv()
    _, first_info = env.reset(seed=1)
    for _ in range(PROCGEN_TIMEOUT):
        terminal_obs, _, _, truncated, info = env.step(NOOP)
    assert truncated
    obs, reset_info = env.reset()
    np.testing.assert_array_equal(obs, terminal_obs)
    # A step's info names the level it was played in; reset's names the level now starting.
    assert info["level_seed"] == first_info["level_seed"]
    assert env.step(NOOP)[4]["level_seed"] == reset_info["level_seed"]


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"env_name": "pong"}, ValueError, r"env_name must be one of .*actual value: 'pong'"),
        ({"distribution_mode": "medium"}, ValueError, r"actual value: 'medium'"),
        ({"num_levels": -1}, ValueError, r"num_levels=-1"),
        ({"render_mode": "human"}, ValueError, r"render_mode .* actual value: 'human'"),
        ({"rand_seed": 3}, TypeError, r"ProcgenEnv sets \['rand_seed'\] itself"),
    ],
)
def test_invalid_arguments_are_rejected(kwargs, error, match):
    with pytest.raises(error, match=match):
        ProcgenEnv(**kwargs)


def test_invalid_action_is_rejected():
    env = ProcgenEnv()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action 5 is outside the action space Discrete\(5\)"):
        env.step(5)


def test_check_env_passes_on_the_routine_wrapper():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*different from the unwrapped version.*")
        check_env(
            RoutineActionWrapper(gym.make("procgen/CoinRun-v0"), [[RIGHT, RIGHT, UP]]),
            skip_render_check=True,
        )


def test_routine_wrapper_on_coinrun_reports_its_primitive_steps():
    env = RoutineActionWrapper(gym.make("procgen/CoinRun-v0"), [[RIGHT, RIGHT, UP], [NOOP] * 4])
    assert env.get_action_meanings()[5:] == ["R0:RIGHT RIGHT UP", "R1:NOOP NOOP NOOP NOOP"]
    env.reset(seed=4)
    obs, reward, terminated, truncated, info = env.step(5)
    assert not (terminated or truncated)
    assert info["routine_length"] == 3
    np.testing.assert_array_equal(info["routine_actions"], [RIGHT, RIGHT, UP, -1])
    assert info["routine_observations"].shape == (4, 64, 64, 3)
    np.testing.assert_array_equal(info["routine_observations"][2], obs)
    assert not info["routine_observations"][3].any()  # padding
    # The same three primitives on the bare env reach the same frame.
    frames, rewards, _ = play(ProcgenEnv(), 4, [RIGHT, RIGHT, UP])
    np.testing.assert_array_equal(info["routine_observations"][:3], frames[1:])
    assert reward == sum(rewards)


def test_docstring_example_runs():
    result = doctest.testmod(procgen_module)
    assert result.attempted > 0 and result.failed == 0
