"""`MinAtarVectorEnv` returns what the Python path (a `SyncVectorEnv` of `make_env`s) returns."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers the MinAtar ids)
from routine_gym.envs.factory import make_vector_env
from routine_gym.envs.minatar_vector import MinAtarVectorEnv


def _flat(info: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in info.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}/"))
        elif f"{prefix}{key}" not in ("final_info/episode/t", "final_info/episode/_t"):
            out[f"{prefix}{key}"] = value  # (an episode's wall time differs, of course)
    return out


def _assert_same_steps(env_id, routines, record, env_kwargs, steps, num_envs=6, seed=3):
    batched = make_vector_env(env_id, num_envs, routines=routines, record_observations=record,
                              env_kwargs=env_kwargs)
    python = make_vector_env(env_id, num_envs, routines=routines, record_observations=record,
                             env_kwargs=env_kwargs, batched=False)
    assert isinstance(batched, MinAtarVectorEnv)
    assert isinstance(python, gym.vector.SyncVectorEnv)
    assert batched.single_observation_space == python.single_observation_space
    assert batched.single_action_space == python.single_action_space
    obs_b, info_b = batched.reset(seed=seed)
    obs_p, info_p = python.reset(seed=seed)
    assert obs_b.dtype == obs_p.dtype and np.array_equal(obs_b, obs_p) and info_b == info_p
    rng = np.random.default_rng(seed)
    ends = truncations = 0
    for t in range(steps):
        actions = rng.integers(0, batched.single_action_space.n, num_envs)
        out_b, out_p = batched.step(actions), python.step(actions)
        for name, b, p in zip(("obs", "reward", "terminated", "truncated"), out_b, out_p,
                                  strict=False):
            assert b.dtype == p.dtype and np.array_equal(b, p), (t, name)
        flat_b, flat_p = _flat(out_b[4]), _flat(out_p[4])
        assert flat_b.keys() == flat_p.keys(), (t, sorted(flat_b.keys() ^ flat_p.keys()))
        for key in flat_b:
            if key == "final_obs":
                for i in range(num_envs):
                    b, p = flat_b[key][i], flat_p[key][i]
                    assert (b is None) == (p is None), (t, i)
                    assert b is None or (b.dtype == p.dtype and np.array_equal(b, p)), (t, i)
            else:
                assert flat_b[key].dtype == flat_p[key].dtype, (t, key)
                assert np.array_equal(flat_b[key], flat_p[key]), (t, key)
        ends += int((out_b[2] | out_b[3]).sum())
        truncations += int(out_b[3].sum())
    batched.close()
    python.close()
    return ends, truncations


@pytest.mark.parametrize("env_id,routines,record,env_kwargs,steps", [
    ("MinAtar/Breakout-v1", None, False, {}, 600),
    ("MinAtar/Breakout-v1", [[1, 1, 2], [0, 0, 0, 0]], True, {"max_episode_steps": 25}, 400),
    ("MinAtar/Seaquest-v1", [[1, 5], [3, 3, 3]], False, {"max_episode_steps": 40}, 300),
    ("MinAtar/SpaceInvaders-v1", [[1, 1], [2, 2, 2, 2, 2]], True, {}, 300),
    ("MinAtar/Asterix-v1", None, False, {"max_episode_steps": 10}, 100),
    ("MinAtar/Freeway-v1", [[1, 1, 1]], True,
     {"sticky_action_prob": 0.5, "max_episode_steps": 30}, 200),
])
def test_the_batched_env_returns_what_the_python_path_returns(env_id, routines, record,
                                                               env_kwargs, steps):
    ends, truncations = _assert_same_steps(env_id, routines, record, env_kwargs, steps)
    assert ends > 0  # episode ends (autoreset, final_obs, final_info) were compared
    if env_kwargs.get("max_episode_steps"):
        assert truncations > 0  # and so were truncations


def test_a_routine_cut_by_the_time_limit_counts_its_executed_steps():
    # Time limit 5, sticky actions off: routine [NOOP NOOP NOOP] twice runs 3 steps, then 2
    # (truncated at the episode's 5th step), in both envs; the episode is 5 steps long.
    envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 2, routines=[[0, 0, 0]],
                            env_kwargs={"max_episode_steps": 5, "sticky_action_prob": 0.0})
    envs.reset(seed=0)
    _, _, terminated, truncated, info = envs.step(np.array([3, 3]))
    assert info["routine_length"].tolist() == [3, 3] and not truncated.any()
    assert info["routine_actions"].tolist() == [[0, 0, 0], [0, 0, 0]]
    _, _, terminated, truncated, info = envs.step(np.array([3, 0]))
    assert truncated.tolist() == [True, False] and not terminated.any()
    final = info["final_info"]
    assert final["_routine_length"].tolist() == [True, False]
    assert final["routine_length"][0] == 2
    assert final["routine_actions"][0].tolist() == [0, 0, -1]
    assert final["routine_truncated"][0].tolist() == [False, True, False]
    assert final["episode"]["l"][0] == 5 and final["_episode"].tolist() == [True, False]
    assert info["_routine_length"].tolist() == [False, True]  # env 0 reports its reset
    assert info["routine_length"][1] == 1 and info["routine_index"][1] == -1


def test_the_factory_keeps_the_python_path_where_the_batched_env_cannot_go():
    assert isinstance(make_vector_env("MinAtar/Breakout-v1", 2), MinAtarVectorEnv)
    assert isinstance(make_vector_env("MinAtar/Breakout-v1", 2, batched=False),
                      gym.vector.SyncVectorEnv)
    assert isinstance(make_vector_env("CartPole-v1", 2), gym.vector.SyncVectorEnv)


def test_bad_input_gets_a_one_line_error():
    envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 2, routines=[[1, 2]])
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="outside the action space Discrete"):
        envs.step(np.array([0, 4]))
    with pytest.raises(ValueError, match="needs 2 actions"):
        envs.step(np.array([0, 1, 2]))
    with pytest.raises(ValueError, match="outside the env's primitive actions"):
        MinAtarVectorEnv("MinAtar/Breakout-v1", 2, routines=[[7]])
    with pytest.raises(ValueError, match="runs MinAtar's games, not 'CartPole-v1'"):
        MinAtarVectorEnv("CartPole-v1", 2)
