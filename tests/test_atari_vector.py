"""`ALEVectorEnv` (ale-py's C++ games) returns what the Python path (a `SyncVectorEnv` of
`make_env`s: `AtariEnv` and routine-gym's Atari wrappers) returns, on fixed seeds and actions.

The two differences the module names are the only ones allowed here: a seed whose ALE seed is
negative (`_positive_seed` picks seeds without one, so sticky actions are compared too), and the
last frame of ``final_obs`` at a game over (the C++ game stops mid frame skip).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers ALE's ids)
from routine_gym.envs.atari_vector import ALEVectorEnv, unsupported_kwargs
from routine_gym.envs.factory import make_vector_env


def _flat(info: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in info.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}/"))
        elif f"{prefix}{key}" not in ("final_info/episode/t", "final_info/episode/_t"):
            out[f"{prefix}{key}"] = value  # (an episode's wall time differs, of course)
    return out


def _positive_seed(num_envs: int, start: int = 0) -> int:
    """The first seed ≥ `start` whose envs' ALE seeds (`AtariEnv.seed_game`) are all positive."""
    seed = start
    while True:
        states = [np.random.SeedSequence(seed + i).generate_state(n_words=2)[1]
                  for i in range(num_envs)]
        if all(int(np.int32(s)) > 0 for s in states):
            return seed
        seed += 1


def _assert_same_steps(env_id, routines, record, env_kwargs, steps, num_envs=4, seed=None):
    seed = _positive_seed(num_envs) if seed is None else seed
    kwargs = {"frameskip": 4, "obs_type": "grayscale", **env_kwargs}
    sticky = {**gym.spec(env_id).kwargs, **env_kwargs}["repeat_action_probability"] > 0
    batched = make_vector_env(env_id, num_envs, routines=routines, record_observations=record,
                              env_kwargs=env_kwargs)
    python = make_vector_env(env_id, num_envs, routines=routines, record_observations=record,
                             env_kwargs=env_kwargs, batched=False)
    assert unsupported_kwargs(env_id, kwargs) is None
    assert isinstance(batched, ALEVectorEnv)
    assert isinstance(python, gym.vector.SyncVectorEnv)
    assert batched.single_observation_space == python.single_observation_space
    assert batched.single_action_space == python.single_action_space
    obs_b, info_b = batched.reset(seed=seed)
    obs_p, info_p = python.reset(seed=seed)
    assert obs_b.dtype == obs_p.dtype and np.array_equal(obs_b, obs_p)
    flat_b, flat_p = _flat(info_b), _flat(info_p)
    assert flat_b.keys() == flat_p.keys()
    assert all(np.array_equal(flat_b[k], flat_p[k]) for k in flat_b)
    rng = np.random.default_rng(seed)
    counts = {"ends": 0, "truncations": 0, "games": 0, "lives": 0, "routines": 0}
    # The games that ended since the reset: in C++ they stopped mid frame skip, so ALE's frame
    # count is behind from then on, and with sticky actions so are the sticky draws (below).
    ended_a_game = np.zeros(num_envs, dtype=bool)
    for t in range(steps):
        actions = rng.integers(0, batched.single_action_space.n, num_envs)
        out_b, out_p = batched.step(actions), python.step(actions)
        rows = np.ones(num_envs, dtype=bool)
        for name, b, p in zip(("obs", "reward", "terminated", "truncated"), out_b, out_p,
                              strict=False):
            assert b.dtype == p.dtype and np.array_equal(b[rows], p[rows]), (t, name)
        flat_b, flat_p = _flat(out_b[4]), _flat(out_p[4])
        assert flat_b.keys() == flat_p.keys(), (t, sorted(flat_b.keys() ^ flat_p.keys()))
        game_over = np.zeros(num_envs, dtype=bool)
        if "final_info/lives" in flat_b:
            game_over = flat_b["final_info/_lives"] & (flat_b["final_info/lives"] == 0)
        for key in flat_b:
            if key == "final_obs":
                for i in range(num_envs):
                    b, p = flat_b[key][i], flat_p[key][i]
                    assert (b is None) == (p is None), (t, i)
                    if b is not None:  # at a game over the last frame may differ (see above)
                        n = 3 if game_over[i] else 4
                        assert b.dtype == p.dtype and np.array_equal(b[:n], p[:n]), (t, i)
            else:
                compared = rows & ~ended_a_game if key.endswith("frame_number") else rows
                if key == "frame_number":  # a game over's frames: checked before its end
                    compared = compared & ~game_over
                assert flat_b[key].dtype == flat_p[key].dtype, (t, key)
                assert np.array_equal(flat_b[key][compared], flat_p[key][compared]), (t, key)
        done = out_b[2] | out_b[3]
        counts["ends"] += int(done[rows].sum())
        counts["truncations"] += int(out_b[3][rows].sum())
        if "final_info/episode/r" in flat_b:
            counts["games"] += int(flat_b["final_info/_episode"][rows].sum())
        counts["lives"] += int((done & ~game_over)[rows].sum())
        counts["routines"] += int((actions >= batched.num_primitive_actions)[rows].sum())
        ended_a_game |= game_over
        if sticky and ended_a_game.any():
            break  # (the key sets of `info` then depend on the other path's games too)
    batched.close()
    python.close()
    return counts


@pytest.mark.parametrize("env_id,routines,record,env_kwargs,steps", [
    # Qbert (FIRE, 4 lives), v5's sticky actions: life losses, NOOP + FIRE resets.
    ("ALE/Qbert-v5", None, False, {}, 400),
    # Routines cut by life losses and by ALE's frame limit (600 frames: 150 steps a game).
    ("ALE/Qbert-v5", [[5, 5, 5], [2, 3, 2, 3, 2, 3]], True,
     {"max_num_frames_per_episode": 600}, 250),
    # Breakout: FIRE serves the ball; a game over within a few hundred random steps.
    ("ALE/Breakout-v5", [[1, 2, 2], [3, 3, 3, 3]], False, {}, 300),
    # A game without FIRE, and the NoFrameskip-v4 id (sticky actions off).
    ("MsPacmanNoFrameskip-v4", [[2, 2, 2, 2], [3, 4]], False,
     {"max_num_frames_per_episode": 400}, 200),
])
def test_the_cpp_games_return_what_the_python_path_returns(env_id, routines, record,
                                                            env_kwargs, steps):
    counts = _assert_same_steps(env_id, routines, record, env_kwargs, steps)
    assert counts["lives"] > 0  # life losses (EpisodicLife's reset) were compared
    if routines:
        assert counts["routines"] > 0
    if env_kwargs.get("max_num_frames_per_episode"):
        assert counts["truncations"] > 0 and counts["games"] > 0  # RecordEpisodeStatistics


def test_a_game_over_is_compared_too():
    # Breakout with random actions loses its 5 lives within 300 steps on these seeds.
    counts = _assert_same_steps("ALE/Breakout-v5", None, False, {}, 300, num_envs=3)
    assert counts["games"] > 0


def test_without_sticky_actions_any_seed_gives_the_same_steps():
    # Seed 1: envs 2 and 3 (seeds 2, 3) have negative ALE seeds (-1936809438, -1392079505).
    assert int(np.int32(np.random.SeedSequence(2).generate_state(n_words=2)[1])) < 0
    counts = _assert_same_steps("ALE/Qbert-v5", [[5, 5]], False,
                                {"repeat_action_probability": 0.0}, 200, seed=1)
    assert counts["lives"] > 0


def test_a_logged_return_is_the_unclipped_score_and_training_rewards_are_clipped():
    envs = ALEVectorEnv("ALE/Breakout-v5", 2, env_kwargs={"frameskip": 4,
                                                          "obs_type": "grayscale"})
    envs.reset(seed=_positive_seed(2))
    rng = np.random.default_rng(0)
    clipped, scores = 0.0, []
    while not scores:
        _, reward, _, _, info = envs.step(rng.integers(0, 4, 2))
        assert set(np.unique(reward)) <= {0.0, 1.0}  # Breakout's 1, 4 and 7 points, clipped
        clipped += reward.sum()
        if "episode" in info.get("final_info", {}):
            scores += info["final_info"]["episode"]["r"][info["final_info"]["_episode"]].tolist()
    envs.close()
    assert all(s == int(s) and s >= 0 for s in scores)


def test_the_factory_picks_the_cpp_games_only_for_the_training_view():
    kwargs = {"frameskip": 4, "obs_type": "grayscale"}
    assert isinstance(make_vector_env("ALE/Pong-v5", 2), ALEVectorEnv)
    assert isinstance(make_vector_env("ALE/Pong-v5", 2, training=False),
                      gym.vector.SyncVectorEnv)
    assert isinstance(make_vector_env("ALE/Pong-v5", 2, env_kwargs={"mode": 0}),
                      gym.vector.SyncVectorEnv)
    assert unsupported_kwargs("ALE/Pong-v5", {**kwargs, "mode": 0}) == "the C++ games take no mode"
    assert unsupported_kwargs("ALE/Pong-v5", {**kwargs, "obs_type": "rgb"}) == (
        "the C++ games give grey frames only")
    assert unsupported_kwargs("CartPole-v1", {}) == "CartPole-v1 is not one of ALE's envs"


def test_bad_input_gets_a_one_line_error():
    with pytest.raises(ValueError, match="ALEVectorEnv cannot build ALE/Pong-v5: the C\\+\\+ "
                                         "games give grey frames only"):
        ALEVectorEnv("ALE/Pong-v5", 2, env_kwargs={"obs_type": "rgb"})
    envs = ALEVectorEnv("ALE/Pong-v5", 2, env_kwargs={"frameskip": 4, "obs_type": "grayscale"})
    envs.reset(seed=0)
    with pytest.raises(ValueError, match="step needs 2 actions"):
        envs.step(np.array([0]))
    with pytest.raises(ValueError, match="action 6 is outside the action space Discrete\\(6\\)"):
        envs.step(np.array([0, 6]))
    envs.close()


def test_the_module_examples_run():
    import doctest

    import routine_gym.envs.atari_vector
    import routine_gym.macro_info

    for module in (routine_gym.envs.atari_vector, routine_gym.macro_info):
        result = doctest.testmod(module)
        assert result.attempted > 0 and result.failed == 0, module.__name__
