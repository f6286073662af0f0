"""MiniQbert: rules, observations, Gymnasium conformance and the scripted expert."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import routine_gym  # noqa: F401  (registers MiniQbert-v0)
from routine_gym.envs.miniqbert import (
    ACTION_MEANINGS,
    DOWN,
    FIRE,
    LEFT,
    MOVES,
    NOOP,
    RIGHT,
    UP,
    MiniQbertEnv,
    ScriptedExpert,
    _geometry,
    cube_index,
    expert_route,
    num_cubes,
    scripted_expert,
)


def play(env: MiniQbertEnv, actions):
    """Step through `actions`; return the rewards and the last step's result."""
    rewards, last = [], None
    for a in actions:
        last = env.step(a)
        rewards.append(last[1])
    return rewards, last


def run_episode(
    env: gym.Env, policy, seed: int = 0, max_steps: int = 1000
) -> tuple[float, int, list[int]]:
    """Play one episode; a policy that stalls fails the test instead of hanging it."""
    obs, _ = env.reset(seed=seed)
    total, actions = 0.0, []
    for _ in range(max_steps):
        a = policy(obs)
        obs, r, terminated, truncated, _ = env.step(a)
        total += r
        actions.append(a)
        if terminated or truncated:
            return total, len(actions), actions
    raise AssertionError(f"episode still running after {max_steps} steps")


def shortest_level(size: int) -> int:
    """Fewest jumps that colour every cube from the start, by breadth-first search over
    (agent cube, coloured set) states."""
    _, jumps = _geometry(size)
    full = (1 << num_cubes(size)) - 1
    frontier, seen, depth = [(0, 0)], {(0, 0)}, 0
    while frontier:
        depth += 1
        nxt = []
        for pos, mask in frontier:
            for a in MOVES:
                j = int(jumps[pos, a])
                if j < 0:
                    continue
                state = (j, mask | (1 << j))
                if state[1] == full:
                    return depth
                if state not in seen:
                    seen.add(state)
                    nxt.append(state)
        frontier = nxt
    raise AssertionError("unreachable")


# -- geometry and rules ----------------------------------------------------------------------


def test_cube_count_and_index():
    assert num_cubes(4) == 10 and num_cubes(2) == 3
    assert [cube_index(r, c) for r in range(3) for c in range(r + 1)] == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize(
    ("start", "action", "landing"),
    [
        ((0, 0), DOWN, (1, 0)),
        ((0, 0), RIGHT, (1, 1)),
        ((0, 0), UP, None),
        ((0, 0), LEFT, None),
        ((2, 1), UP, (1, 1)),
        ((2, 1), LEFT, (1, 0)),
        ((2, 1), DOWN, (3, 1)),
        ((2, 1), RIGHT, (3, 2)),
        ((2, 0), LEFT, None),
        ((2, 2), UP, None),
        ((3, 0), DOWN, None),
        ((3, 3), RIGHT, None),
    ],
)
def test_jumps_follow_the_diagonal_geometry(start, action, landing):
    _, jumps = _geometry(4)
    target = int(jumps[cube_index(*start), action])
    assert target == (-1 if landing is None else cube_index(*landing))


def test_landing_on_an_uncoloured_cube_pays_25_once():
    env = MiniQbertEnv()
    env.reset(seed=0)
    rewards, _ = play(env, [DOWN, UP, DOWN])  # (1,0) new, (0,0) new, (1,0) again
    assert rewards == [25.0, 25.0, 0.0]
    assert env.position == (1, 0)
    assert env.colours.sum() == 2


def test_noop_and_fire_change_nothing():
    env = MiniQbertEnv()
    obs0, _ = env.reset(seed=0)
    rewards, (obs, _, terminated, truncated, info) = play(env, [NOOP, FIRE, NOOP])
    assert rewards == [0.0, 0.0, 0.0]
    np.testing.assert_array_equal(obs, obs0)
    assert not terminated and not truncated
    assert info == {"lives": 3, "level": 0, "cubes_left": 10}


def test_jumping_off_costs_a_life_keeps_colours_and_respawns_on_top():
    env = MiniQbertEnv()
    env.reset(seed=0)
    play(env, [DOWN, DOWN])  # colour (1,0) and (2,0)
    _, (_, reward, terminated, _, info) = play(env, [LEFT])  # (2,0) has no up-left cube
    assert reward == 0.0 and not terminated
    assert info["lives"] == 2 and env.position == (0, 0)
    assert env.colours[[cube_index(1, 0), cube_index(2, 0)]].all()
    assert info["cubes_left"] == 8


def test_losing_the_last_life_terminates():
    env = MiniQbertEnv(lives=2)
    env.reset(seed=0)
    _, (_, _, terminated, _, _) = play(env, [UP])
    assert not terminated
    _, (obs, reward, terminated, truncated, info) = play(env, [LEFT])
    assert terminated and not truncated and reward == 0.0
    assert info["lives"] == 0 and obs[-1] == 0.0


def test_clearing_a_level_pays_the_bonus_and_resets_the_pyramid():
    env = MiniQbertEnv(size=2, num_levels=2)
    env.reset(seed=0)
    rewards, (obs, _, terminated, _, info) = play(env, [DOWN, UP, RIGHT])
    assert rewards == [25.0, 25.0, 125.0]  # the last cube also brings the +100 bonus
    assert not terminated
    assert info == {"lives": 3, "level": 1, "cubes_left": 3}
    assert env.position == (0, 0) and not env.colours.any()
    assert obs[-2] == pytest.approx(0.5)  # one of two levels done


def test_clearing_the_last_level_terminates_with_the_finished_pyramid():
    env = MiniQbertEnv(size=2, num_levels=1)
    env.reset(seed=0)
    _, (obs, reward, terminated, _, info) = play(env, [DOWN, UP, RIGHT])
    assert terminated and reward == 125.0
    assert info == {"lives": 3, "level": 1, "cubes_left": 0}
    np.testing.assert_array_equal(obs, [1, 1, 1, 0, 0, 1, 1.0, 1.0])


def test_vector_observation_layout():
    env = MiniQbertEnv()
    obs, _ = env.reset(seed=0)
    assert obs.shape == (22,) and obs.dtype == np.float32
    expected = np.zeros(22, dtype=np.float32)
    expected[10 + 0] = 1.0  # agent on the top cube
    expected[21] = 1.0  # all lives
    np.testing.assert_array_equal(obs, expected)
    obs, *_ = env.step(RIGHT)  # onto (1,1), cube index 2
    expected[:] = 0.0
    expected[2] = 1.0
    expected[10 + 2] = 1.0
    expected[21] = 1.0
    np.testing.assert_array_equal(obs, expected)


def test_rgb_observation_shows_cubes_agent_and_lives():
    env = MiniQbertEnv(obs_type="rgb", render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    obs, *_ = env.step(DOWN)  # agent on (1,0), now coloured
    # Cube (1,0) starts at y = 5 + 14, x = 5 + 2 * 7; its corner shows the cube colour,
    # its centre the agent.
    assert tuple(obs[19, 19]) == (230, 200, 40)
    assert tuple(obs[25, 25]) == (240, 100, 20)
    # The top cube (y 5, x 26) is still uncoloured and empty.
    assert tuple(obs[5, 26]) == (50, 70, 200) and tuple(obs[11, 32]) == (50, 70, 200)
    # Three 2-pixel life dots on a 3-pixel pitch in the top-left corner.
    assert (obs[1, [1, 2, 4, 5, 7, 8]] == 255).all()
    assert (obs[1, [0, 3, 6, 9, 10]] == 0).all()
    np.testing.assert_array_equal(env.render(), obs)


def test_ansi_render_draws_the_pyramid():
    env = MiniQbertEnv(size=3, render_mode="ansi")
    env.reset(seed=0)
    env.step(DOWN)
    picture = [
        "level 1/3  lives 3  cubes left 5",
        "    [.]",
        "  <#> [.]",
        "[.] [.] [.]",
    ]
    assert env.render() == "\n".join(picture) + "\n"


def test_render_without_mode_returns_none():
    env = MiniQbertEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_actions_mirror_ale_qbert():
    assert MiniQbertEnv().get_action_meanings() == list(ACTION_MEANINGS)
    ale = gym.make("ALE/Qbert-v5")
    try:
        assert ale.unwrapped.get_action_meanings() == list(ACTION_MEANINGS)
    finally:
        ale.close()


def test_keys_to_action_maps_letters_and_arrows_to_the_diagonals():
    import os

    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    pygame = pytest.importorskip("pygame")
    keys = MiniQbertEnv().get_keys_to_action()
    assert keys[("w",)] == keys[(pygame.K_UP,)] == UP
    assert keys[("d",)] == keys[(pygame.K_RIGHT,)] == RIGHT
    assert keys[("a",)] == keys[(pygame.K_LEFT,)] == LEFT
    assert keys[("s",)] == keys[(pygame.K_DOWN,)] == DOWN
    assert keys[(" ",)] == FIRE
    assert set(keys.values()) == set(range(6))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"size": 1}, "size"),
        ({"size": 2.5}, "size"),
        ({"size": True}, "size"),
        ({"lives": 0}, "lives"),
        ({"num_levels": 0}, "num_levels"),
        ({"obs_type": "ram"}, "obs_type"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_constructor_rejects_bad_arguments_by_name(kwargs, name):
    with pytest.raises(ValueError, match=name):
        MiniQbertEnv(**kwargs)


def test_step_errors():
    env = MiniQbertEnv(size=2, num_levels=1)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(NOOP)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(6)
    play(env, [DOWN, UP, RIGHT])  # game over
    with pytest.raises(RuntimeError, match="reset"):
        env.step(NOOP)


@pytest.mark.parametrize("obs_type", ["vector", "rgb"])
@pytest.mark.parametrize("render_mode", [None, "rgb_array", "ansi"])
def test_passes_gymnasium_env_checker(obs_type, render_mode):
    env = gym.make("MiniQbert-v0", obs_type=obs_type, render_mode=render_mode)
    check_env(env.unwrapped)


def test_registered_env_truncates_at_500_steps():
    env = gym.make("MiniQbert-v0")
    env.reset(seed=0)
    for t in range(500):
        _, _, terminated, truncated, _ = env.step(NOOP)
        assert not terminated
        assert truncated == (t == 499)


def test_game_is_deterministic_whatever_the_seed():
    actions = np.random.default_rng(1).integers(0, 6, size=200)
    traces = []
    for seed in (0, 123):
        env = MiniQbertEnv()
        obs, _ = env.reset(seed=seed)
        trace = [obs]
        for a in actions:
            obs, r, terminated, _, _ = env.step(a)
            trace.append(np.append(obs, r))
            if terminated:
                break
        traces.append(np.concatenate(trace))
    np.testing.assert_array_equal(traces[0], traces[1])


# -- scripted expert ------------------------------------------------------------------------


def test_expert_scores_1050_in_33_steps_with_default_settings():
    env = gym.make("MiniQbert-v0")
    total, length, actions = run_episode(env, scripted_expert(env))
    assert total == 3 * (10 * 25 + 100) == 1050
    assert length == 33
    # Every level repeats the same 11 actions: the routine structure RAPL mines.
    route = ["DOWN", "UP", "RIGHT", "RIGHT", "RIGHT", "LEFT", "DOWN", "LEFT", "DOWN", "LEFT"]
    level = tuple(ACTION_MEANINGS.index(m) for m in [*route, "DOWN"])
    assert tuple(actions) == level * 3


@pytest.mark.parametrize("size", [2, 3, 4])
def test_expert_route_is_the_shortest_possible(size):
    assert len(expert_route(size)) == shortest_level(size)


@pytest.mark.parametrize("size", [2, 4, 6, 8, 10])
def test_expert_route_meets_the_parity_bound_on_even_sizes(size):
    # Jumps alternate odd and even rows, starting with a landing on row 1, so covering the
    # size (size + 2) / 4 odd-row cubes needs at least size (size + 2) / 2 − 1 jumps.
    route = expert_route(size)
    assert len(route) == size * (size + 2) // 2 - 1
    assert {cube_index(r, c) for r, c in route} == set(range(num_cubes(size)))


@pytest.mark.parametrize("size", [2, 3, 5, 7])
def test_expert_clears_every_size_and_repeats_its_level_actions(size):
    env = MiniQbertEnv(size=size, num_levels=2)
    expert = scripted_expert(size)
    total, length, actions = run_episode(env, expert)
    assert total == 2 * (num_cubes(size) * 25 + 100)
    assert tuple(actions) == expert.level_actions * 2
    assert length == 2 * len(expert_route(size))


def test_expert_reads_rgb_observations_the_same_way():
    total, length, actions = run_episode(MiniQbertEnv(obs_type="rgb"), scripted_expert(4))
    assert (total, length) == (1050.0, 33)
    assert tuple(actions) == scripted_expert(4).level_actions * 3


def test_expert_finishes_the_level_from_any_state_without_falling():
    size = 4
    expert = ScriptedExpert(size)
    _, jumps = _geometry(size)
    rng = np.random.default_rng(0)
    for _ in range(200):
        colours = rng.random(num_cubes(size)) < 0.5
        colours[rng.integers(num_cubes(size))] = False  # at least one cube left
        pos = int(rng.integers(num_cubes(size)))
        for _ in range(3 * num_cubes(size)):  # a generous bound on the walk
            action = expert.act(colours, pos)
            pos = int(jumps[pos, action])
            assert action in MOVES and pos >= 0
            colours[pos] = True
            if colours.all():
                break
        assert colours.all()


def test_expert_jumps_back_onto_an_uncoloured_top_cube_after_a_fall():
    env = MiniQbertEnv()
    expert = scripted_expert(env)
    env.reset(seed=0)
    play(env, [DOWN, LEFT])  # colour (1,0), then fall off: back on the uncoloured top cube
    obs, *_ = env.step(NOOP)
    total, actions, done = 25.0, [], False
    while not done and len(actions) < 100:
        actions.append(expert(obs))
        obs, reward, done, _, info = env.step(actions[-1])
        total += reward
    # Standing on the top cube does not colour it: hop down onto the coloured (1,0) and back.
    assert actions[:2] == [DOWN, UP]
    assert total == 1050.0 and info["lives"] == 2


def test_noisy_expert_is_reproducible_for_a_seed_and_still_scores():
    env = MiniQbertEnv()
    first = run_episode(env, scripted_expert(env, noise=0.2, rng=7))
    second = run_episode(env, scripted_expert(env, noise=0.2, rng=7))
    assert first == second
    assert first[2] != list(scripted_expert(4).level_actions * 3)  # the noise did act
    assert first[0] >= 10 * 25 + 100  # it still clears at least one level


def test_scripted_expert_argument_errors():
    with pytest.raises(TypeError, match="MiniQbertEnv"):
        scripted_expert(gym.make("CartPole-v1"))
    with pytest.raises(TypeError):
        scripted_expert("4")
    with pytest.raises(ValueError, match="noise"):
        scripted_expert(4, noise=1.5)
    with pytest.raises(ValueError, match="size"):
        scripted_expert(1)
    with pytest.raises(ValueError, match="shape"):
        scripted_expert(4)(np.zeros(5, dtype=np.float32))
