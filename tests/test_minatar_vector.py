"""`MinAtarVectorEnv` returns what the Python path (a `SyncVectorEnv` of `make_env`s) returns."""

from __future__ import annotations

import copy
from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers the MinAtar ids)
from routine_gym import _native
from routine_gym.envs.factory import make_vector_env
from routine_gym.envs.minatar_vector import MinAtarVectorEnv, _core_row

COMPILED_IDS = ("MinAtar/Breakout-v1", "MinAtar/SpaceInvaders-v1", "MinAtar/Freeway-v1",
                "MinAtar/Asterix-v1", "MinAtar/Seaquest-v1")  # all five

#: Whether the compiled core runs here (built, on, and MinAtar the version it ports); without it
#: the Python loop's tests run and the core's skip.
HAS_CORE = _native.core("minatar_core") is not None
needs_core = pytest.mark.skipif(not HAS_CORE,
                                reason=f"minatar_core: {_native.unavailable('minatar_core')}")


def _flat(info: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in info.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}/"))
        elif f"{prefix}{key}" not in ("final_info/episode/t", "final_info/episode/_t"):
            out[f"{prefix}{key}"] = value  # (an episode's wall time differs, of course)
    return out


def _assert_same_steps(env_id, routines, record, env_kwargs, steps, num_envs=6, seed=3,
                       compiled=None):
    if compiled and not HAS_CORE:
        pytest.skip("the compiled core 'minatar_core' is not there")
    if compiled is None:  # what the scripts get: the factory's choice
        batched = make_vector_env(env_id, num_envs, routines=routines,
                                  record_observations=record, env_kwargs=env_kwargs)
    else:
        batched = MinAtarVectorEnv(env_id, num_envs, routines=routines,
                                   record_observations=record, env_kwargs=env_kwargs,
                                   compiled=compiled)
    python = make_vector_env(env_id, num_envs, routines=routines, record_observations=record,
                             env_kwargs=env_kwargs, batched=False)
    assert isinstance(batched, MinAtarVectorEnv)
    # Every game runs in the compiled core, where there is one, unless told otherwise.
    assert batched.compiled == (compiled is not False and HAS_CORE and env_id in COMPILED_IDS)
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


@pytest.mark.parametrize("routines,record,env_kwargs,compiled", [
    (None, False, {}, False),  # Breakout's Python loop, kept for compiled=False
    ([[1, 1, 2], [0, 0, 0, 0]], True, {"max_episode_steps": 25}, False),
    ([[2, 2, 2, 2], [1, 0]], False, {"sticky_action_prob": 0.5, "max_episode_steps": 30}, True),
    ([[1]], True, {"sticky_action_prob": 1.0}, True),  # every action sticks: the first is NOOP
    (None, False, {"sticky_action_prob": 0.0}, True),
])
def test_breakout_compiled_or_not_returns_what_the_python_path_returns(routines, record,
                                                                      env_kwargs, compiled):
    ends, truncations = _assert_same_steps("MinAtar/Breakout-v1", routines, record, env_kwargs,
                                           300, compiled=compiled)
    assert ends > 0
    if env_kwargs.get("max_episode_steps"):
        assert truncations > 0


@pytest.mark.parametrize("env_id,routines,record,env_kwargs,steps", [
    ("MinAtar/SpaceInvaders-v1", [[3, 3, 1]], False,
     {"sticky_action_prob": 0.0, "difficulty_ramping": False, "max_episode_steps": 60}, 400),
    ("MinAtar/SpaceInvaders-v1", None, False, {"sticky_action_prob": 1.0}, 300),
    ("MinAtar/Freeway-v1", [[1, 1], [2]], True, {"max_episode_steps": 45}, 300),
    ("MinAtar/Freeway-v1", None, False, {}, 2600),  # the 2,500-step clock ends every game
    ("MinAtar/Asterix-v1", [[1, 1, 1], [3, 3]], True,
     {"sticky_action_prob": 0.5, "max_episode_steps": 30}, 300),
    ("MinAtar/Asterix-v1", None, False, {"difficulty_ramping": False}, 600),
    ("MinAtar/Seaquest-v1", [[5, 5, 1], [2, 2, 2]], True,
     {"sticky_action_prob": 0.5, "max_episode_steps": 30}, 300),
    ("MinAtar/Seaquest-v1", None, False, {"difficulty_ramping": False}, 1500),
])
@needs_core
def test_the_other_compiled_games_return_what_the_python_path_returns(env_id, routines, record,
                                                                     env_kwargs, steps):
    ends, truncations = _assert_same_steps(env_id, routines, record, env_kwargs, steps,
                                           compiled=True)
    assert ends > 0
    if env_kwargs.get("max_episode_steps"):
        assert truncations > 0


def _breakout_pair(num_envs, sticky):
    kwargs = {"sticky_action_prob": sticky}
    pair = [MinAtarVectorEnv("MinAtar/Breakout-v1", num_envs, env_kwargs=kwargs, compiled=c)
            for c in (True, False)]
    for envs in pair:
        envs.reset(seed=11)
    return pair


def _set_state(envs, i, state):
    environment = envs._games[i]
    game = environment.env
    for key, value in state.items():
        if key == "last_action":
            environment.last_action = value
        else:
            setattr(game, key, value.copy() if isinstance(value, np.ndarray) else value)


def _draw_state(rng):
    """A Breakout state: the ball anywhere in rows 0-8 (half the time in row 8, over the
    paddle's row), any direction, the paddle anywhere, bricks anywhere in rows 0-8 (the wall
    cleared a third of the time)."""
    bricks = np.zeros((10, 10))
    if rng.random() > 1 / 3:
        bricks[:9] = rng.random((9, 10)) < 0.3
    ball_x, ball_y = int(rng.integers(10)), 8 if rng.random() < 0.5 else int(rng.integers(9))
    bricks[ball_y, ball_x] = 0  # the ball is never inside a brick
    return {"ball_x": ball_x, "ball_y": ball_y, "ball_dir": int(rng.integers(4)),
            "pos": int(rng.integers(10)), "strike": bool(rng.integers(2)),
            "last_x": int(rng.integers(10)), "last_y": int(rng.integers(10)),
            "brick_map": bricks, "last_action": int(rng.choice([0, 1, 3]))}


@needs_core
@pytest.mark.parametrize("sticky", [0.0, 0.3])
def test_the_compiled_core_steps_any_breakout_state_as_minatar_does(sticky):
    # From states drawn anywhere (walls, corners, bricks above, beside and below the ball, a
    # cleared wall refilled when the ball reaches the paddle's row, a strike in progress), one
    # step of each action in the compiled core against MinAtar's own `act` and `state`.
    compiled, python = _breakout_pair(8, sticky)
    rng = np.random.default_rng(0)
    refills = ends = 0
    for _ in range(300):
        for i in range(8):
            state = _draw_state(rng)
            _set_state(compiled, i, state)
            _set_state(python, i, state)
        compiled._load_core()
        actions = rng.integers(0, 3, 8)
        cleared = [not python._games[i].env.brick_map.any() for i in range(8)]
        out_c, out_p = compiled.step(actions), python.step(actions)
        for b, p in zip(out_c[:4], out_p[:4], strict=True):
            assert b.dtype == p.dtype and np.array_equal(b, p)
        done = out_p[2] | out_p[3]
        for i in np.flatnonzero(done):
            assert np.array_equal(out_c[4]["final_obs"][i], out_p[4]["final_obs"][i])
        for i in range(8):  # a cleared wall that was refilled has bricks again
            after = out_p[4]["final_obs"][i] if done[i] else out_p[0][i]
            refills += int(cleared[i] and after[3].any())
        ends += int(done.sum())
    assert refills > 10 and ends > 100  # both branches were compared, many times


def _drawn_steps(env_id, kwargs, draw, seed, rounds, values=list):
    """One step of 8 games from states drawn by `draw(rng)`, `rounds` times, in the compiled
    core and in MinAtar's own `act` and `state` (random actions of the agent's action space).
    Asserts both return the same step and final observations, that the games that go on hold
    the same variables (the core's row, through `values`, and maps against the Python game's)
    and that every game's generator is in the same state. Yields the Python games as they were
    before the step, the games themselves, and the step's rewards and ends, for the caller's
    counts of the branches it reached."""
    compiled, python = (MinAtarVectorEnv(env_id, 8, env_kwargs=kwargs, compiled=c)
                        for c in (True, False))
    for envs in (compiled, python):
        envs.reset(seed=11)
    rng = np.random.default_rng(seed)
    for _ in range(rounds):
        for i in range(8):
            state = draw(rng)
            for envs in (compiled, python):
                _set_state(envs, i, copy.deepcopy(state))
        compiled._load_core()
        actions = rng.integers(0, compiled.single_action_space.n, 8)
        before = [SimpleNamespace(**{key: copy.deepcopy(value) for key, value
                                     in vars(environment.env).items() if key != "random"})
                  for environment in python._games]  # the game's variables, not its generator
        out_c, out_p = compiled.step(actions), python.step(actions)
        for b, p in zip(out_c[:4], out_p[:4], strict=True):
            assert b.dtype == p.dtype and np.array_equal(b, p)
        done = out_p[2] | out_p[3]
        for i in range(8):
            environment = python._games[i]
            if done[i]:
                assert np.array_equal(out_c[4]["final_obs"][i], out_p[4]["final_obs"][i])
            else:
                row = _core_row(environment.env, compiled._core_fields)
                assert values(compiled._core[i].tolist()) == values(
                    row + [environment.last_action])
                for k, name in enumerate(compiled._core_maps):
                    assert np.array_equal(compiled._maps[i, k], getattr(environment.env, name))
            c_state, p_state = (e._games[i].random.get_state() for e in (compiled, python))
            assert c_state[2] == p_state[2] and np.array_equal(c_state[1], p_state[1])
        yield before, [environment.env for environment in python._games], out_p[1], done


def _draw_invaders_state(rng):
    """A Space Invaders state: aliens anywhere above the cannon's row (one to a handful a third
    of the time, so that a wave is often cleared), bullets anywhere, the cannon anywhere, the
    march at any point of its timers (often due this step), either direction."""
    aliens = np.zeros((10, 10))
    if rng.random() < 1 / 3:
        for _ in range(int(rng.integers(1, 4))):
            aliens[rng.integers(9), rng.integers(10)] = 1
    else:
        aliens[:9] = rng.random((9, 10)) < 0.3
        aliens[rng.integers(9), rng.integers(10)] = 1  # at least one alien
    return {"alien_map": aliens, "f_bullet_map": (rng.random((10, 10)) < 0.15) * 1.0,
            "e_bullet_map": (rng.random((10, 10)) < 0.15) * 1.0,
            "pos": int(rng.integers(10)), "alien_dir": int(rng.choice([-1, 1])),
            "enemy_move_interval": int(rng.integers(5, 13)),
            "alien_move_timer": int(rng.integers(0, 3)),
            "alien_shot_timer": int(rng.integers(0, 3)),
            "ramp_index": int(rng.integers(0, 4)), "shot_timer": int(rng.integers(0, 6)),
            "last_action": int(rng.choice([0, 1, 3, 5]))}


@needs_core
@pytest.mark.parametrize("sticky,ramping", [(0.0, True), (0.3, True), (0.1, False)])
def test_the_compiled_core_steps_any_space_invaders_state_as_minatar_does(sticky, ramping):
    # From states drawn anywhere (aliens at the walls and in the cannon's row, a march or a
    # shot due, a wave cleared by this step's kills), one step of each action in the compiled
    # core against MinAtar's own `act` and `state`, in both directions of the march.
    kwargs = {"sticky_action_prob": sticky, "difficulty_ramping": ramping}
    waves = ramps = ends = kills = 0
    for before, games, rewards, done in _drawn_steps("MinAtar/SpaceInvaders-v1", kwargs,
                                                      _draw_invaders_state, 1, 300):
        for i in np.flatnonzero(~done):
            aliens = games[i].alien_map
            waves += int(aliens[:4, 2:8].all() and aliens.sum() == 24)
            ramps += int(games[i].enemy_move_interval < before[i].enemy_move_interval)
        ends += int(done.sum())
        kills += int((rewards > 0).sum())
    assert waves > 10 and ends > 100 and kills > 100
    assert (ramps > 10) == ramping


@needs_core
def test_the_compiled_core_refuses_a_space_invaders_shot_with_no_alien():
    # MinAtar's own `act` raises TypeError from such a state; the core says what happened.
    envs = MinAtarVectorEnv("MinAtar/SpaceInvaders-v1", 1,
                            env_kwargs={"sticky_action_prob": 0.0}, compiled=True)
    envs.reset(seed=0)
    _set_state(envs, 0, {"alien_map": np.zeros((10, 10)), "alien_shot_timer": 0})
    envs._load_core()
    with pytest.raises(ValueError, match="game 0: an alien was to shoot but there is none"):
        envs.step(np.array([0]))


def _draw_freeway_state(rng):
    """A Freeway state: the chicken anywhere (often one row from the top, so that a crossing
    redraws the cars), its move timer and the game's clock at any point (often about to end),
    cars anywhere in their lanes at any speed either way, their timers often due."""
    cars = [[int(rng.integers(10)), lane + 1, int(rng.integers(0, 3)),
             int(rng.integers(1, 6)) * int(rng.choice([-1, 1]))] for lane in range(8)]
    return {"pos": 1 if rng.random() < 0.4 else int(rng.integers(10)),
            "move_timer": int(rng.integers(0, 4)),
            "terminate_timer": int(rng.integers(0, 3)) if rng.random() < 0.2 else 2500,
            "cars": cars, "last_action": int(rng.choice([0, 2, 4]))}


@needs_core
@pytest.mark.parametrize("sticky", [0.0, 0.3])
def test_the_compiled_core_steps_any_freeway_state_as_minatar_does(sticky):
    # From states drawn anywhere (a crossing that redraws the cars from the game's generator,
    # cars hitting the chicken before and after they move, wrapping round, the clock running
    # out), one step of each action against MinAtar's own `act` and `state`; the games'
    # variables and their generators' states after it too.
    crossings = ends = hits = 0
    for before, games, rewards, done in _drawn_steps("MinAtar/Freeway-v1",
                                                      {"sticky_action_prob": sticky},
                                                      _draw_freeway_state, 2, 300):
        for i in np.flatnonzero(~done):
            hits += int(games[i].pos == 9 and before[i].pos not in (8, 9) and rewards[i] == 0)
        ends += int(done.sum())
        crossings += int((rewards > 0).sum())
    assert crossings > 100 and ends > 100 and hits > 100


def _draw_asterix_state(rng):
    """An Asterix state: the player anywhere in rows 1-8, entity slots empty or holding gold or
    an enemy moving either way anywhere in its lane (often beside the player), spawns, moves
    and the ramp often due this step (with every slot full, sometimes, so a spawn finds none)."""
    px, py = int(rng.integers(10)), int(rng.integers(1, 9))
    full = rng.random() < 0.1
    entities = []
    for slot in range(8):
        if full or rng.random() < 0.5:
            x = int(np.clip(px + rng.integers(-1, 2), 0, 9)) if rng.random() < 0.5 \
                else int(rng.integers(10))
            entities.append([x, slot + 1, bool(rng.integers(2)), bool(rng.random() < 1 / 3)])
        else:
            entities.append(None)
    return {"player_x": px, "player_y": py, "entities": entities,
            "spawn_speed": int(rng.integers(1, 11)), "spawn_timer": int(rng.integers(0, 3)),
            "move_speed": int(rng.integers(1, 6)), "move_timer": int(rng.integers(0, 3)),
            "ramp_timer": int(rng.integers(-1, 2)), "ramp_index": int(rng.integers(0, 4)),
            "last_action": int(rng.choice([0, 1, 2, 3, 4]))}


@needs_core
@pytest.mark.parametrize("sticky,ramping", [(0.0, True), (0.3, True), (0.1, False)])
def test_the_compiled_core_steps_any_asterix_state_as_minatar_does(sticky, ramping):
    # From states drawn anywhere (gold taken and enemies met before and after the entities
    # move, entities leaving the board, spawns into a random free slot from the game's
    # generator or into none, the ramp), one step of each action against MinAtar's own `act`
    # and `state`; the games' variables and their generators' states after it too.
    kwargs = {"sticky_action_prob": sticky, "difficulty_ramping": ramping}
    gold = ends = ramps = spawns = 0
    for before, games, rewards, done in _drawn_steps("MinAtar/Asterix-v1", kwargs,
                                                      _draw_asterix_state, 3, 300):
        for i in np.flatnonzero(~done):
            game, was = games[i], before[i]
            ramps += int((game.spawn_speed, game.move_speed) != (was.spawn_speed,
                                                                  was.move_speed))
            spawns += int(sum(e is not None for e in game.entities)
                          > sum(e is not None for e in was.entities))
        ends += int(done.sum())
        gold += int((rewards > 0).sum())
    assert gold > 100 and ends > 100 and spawns > 100
    assert (ramps > 10) == ramping


def _draw_seaquest_state(rng):
    """A Seaquest state: the submarine anywhere (often at the surface), oxygen and divers at any
    count (surfacing with none, some, or six; oxygen run out), objects of every kind around it
    and each other, often on the same cell, sometimes two equal in value (the game's loops
    remove the first equal element while they iterate), their timers often due."""
    sub_x, sub_y = int(rng.integers(10)), 0 if rng.random() < 0.3 else int(rng.integers(9))

    def near(spread=1):
        if rng.random() < 0.6:
            return (int(np.clip(sub_x + rng.integers(-spread, spread + 1), 0, 9)),
                    int(np.clip(sub_y + rng.integers(-1, 2), 0, 9)))
        return int(rng.integers(10)), int(rng.integers(1, 9))

    def objects(make, most):
        items = [make(*near()) for _ in range(int(rng.integers(0, most + 1)))]
        if items and rng.random() < 0.3:
            items.insert(int(rng.integers(len(items) + 1)), list(items[rng.integers(len(items))]))
        return items

    def flag():
        return bool(rng.integers(2))

    return {
        "sub_x": sub_x, "sub_y": sub_y, "sub_or": True if sub_x == 9 else flag(),
        "oxygen": int(rng.choice([-1, 0, 1, 37, 150, 200])),
        "diver_count": int(rng.integers(-1, 7)), "surface": flag(),
        "e_spawn_speed": int(rng.integers(1, 21)), "e_spawn_timer": int(rng.integers(0, 3)),
        "d_spawn_timer": int(rng.integers(0, 3)), "move_speed": int(rng.integers(2, 6)),
        "ramp_index": int(rng.integers(0, 5)), "shot_timer": int(rng.integers(0, 3)),
        "f_bullets": objects(lambda x, y: [x, y, flag()], 3),
        "e_bullets": objects(lambda x, y: [x, y, flag()], 3),
        "e_fish": objects(lambda x, y: [x, y, flag(), int(rng.integers(0, 3))], 4),
        "e_subs": objects(lambda x, y: [x, y, flag(), int(rng.integers(0, 3)),
                                        int(rng.integers(0, 3))], 4),
        "divers": objects(lambda x, y: [x, y, flag(), int(rng.integers(0, 2))], 3),
        "last_action": int(rng.integers(0, 6)),
    }


def _seaquest_values(row):
    """A Seaquest core row without the objects' ids and the next id (the Python game has none)."""
    row, offset = list(row), 15
    row[14] = 0
    for width in (3, 3, 4, 5, 4):
        for k in range(48):
            row[offset + 1 + k * (width + 1)] = 0
        offset += 1 + 48 * (width + 1)
    return row


@needs_core
@pytest.mark.parametrize("sticky,ramping", [(0.0, True), (0.3, True), (0.1, False)])
def test_the_compiled_core_steps_any_seaquest_state_as_minatar_does(sticky, ramping):
    # From states drawn anywhere, one step of each action against MinAtar's own `act` and
    # `state`: bullets meeting fish and subs, enemies moving onto bullets, divers picked up,
    # surfacing with no diver, some, or six (the oxygen bonus), oxygen running out, spawns
    # refused for a lane in use, a removed sub still shooting, equal objects removed in the
    # lists' order; the games' variables and their generators' states after it too.
    kwargs = {"sticky_action_prob": sticky, "difficulty_ramping": ramping}
    rewarded = ends = bonus = ramps = 0
    for before, games, rewards, done in _drawn_steps("MinAtar/Seaquest-v1", kwargs,
                                                      _draw_seaquest_state, 4, 400,
                                                      values=_seaquest_values):
        for i in np.flatnonzero(~done):
            ramps += int((games[i].e_spawn_speed, games[i].move_speed)
                         != (before[i].e_spawn_speed, before[i].move_speed))
        ends += int(done.sum())
        rewarded += int((rewards > 0).sum())
        bonus += int((rewards > 1).sum())
    assert rewarded > 100 and ends > 100 and bonus > 5
    assert (ramps > 10) == ramping


@needs_core
def test_the_compiled_core_shares_each_games_random_stream_with_python():
    # The sticky draws and the reset's coin come from the game's own RandomState: after the
    # same steps, the compiled games' generators are where the Python games' are.
    compiled, python = _breakout_pair(4, 0.25)
    rng = np.random.default_rng(5)
    for _ in range(200):
        actions = rng.integers(0, 3, 4)
        compiled.step(actions)
        python.step(actions)
    for c, p in zip(compiled._games, python._games, strict=True):
        assert c.random.rand() == p.random.rand()


def test_compiled_true_is_refused_where_there_is_no_core(monkeypatch):
    import routine_gym.envs.minatar_vector as minatar_vector

    # Every MinAtar game has a core now; a game without one (as Seaquest was) is refused.
    monkeypatch.setattr(minatar_vector, "COMPILED_GAMES", ("breakout",))
    with pytest.raises(ValueError, match="MinAtar/Seaquest-v1 has no compiled core"):
        MinAtarVectorEnv("MinAtar/Seaquest-v1", 2, compiled=True)
    assert not MinAtarVectorEnv("MinAtar/Seaquest-v1", 2).compiled


def test_without_the_core_compiled_true_is_refused_and_none_steps_in_python(monkeypatch):
    monkeypatch.setenv("ROUTINE_GYM_NATIVE", "sequitur,masked_gru")  # every core but this one
    with pytest.raises(ImportError, match="needs the compiled core 'minatar_core': "
                                          "ROUTINE_GYM_NATIVE=sequitur,masked_gru turns it off"):
        MinAtarVectorEnv("MinAtar/Asterix-v1", 2, compiled=True)
    envs = MinAtarVectorEnv("MinAtar/Asterix-v1", 2)
    envs.reset(seed=0)
    assert not envs.compiled and envs.step(np.array([0, 1]))[0].shape == (2, 4, 10, 10)


def test_another_minatar_version_takes_the_python_games_with_one_warning(monkeypatch):
    """The core ports MinAtar 1.0.15's games: on any other installed version (faked here) it
    steps aside, with one warning naming both versions, and the games run in MinAtar's
    Python, stepping as the Python path does."""
    import importlib.util

    assert _native.MINATAR_VERSION == "1.0.15"
    if importlib.util.find_spec("routine_gym._native._minatar_core") is None:
        pytest.skip("the compiled core 'minatar_core' is not built")
    monkeypatch.setenv("ROUTINE_GYM_NATIVE", "minatar_core")  # on, whatever the run's setting
    monkeypatch.setattr(_native, "_loaded", {})  # loaded afresh, so the version is checked
    monkeypatch.setattr(_native, "_warned", set())
    monkeypatch.setattr(_native, "installed_version",
                        lambda name: "1.0.16" if name == "minatar" else None)
    with pytest.warns(RuntimeWarning, match=r"ports minatar 1\.0\.15, but minatar 1\.0\.16 is "
                                            r"installed; its Python twin runs") as caught:
        envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 3, env_kwargs={"sticky_action_prob": 0})
        again = MinAtarVectorEnv("MinAtar/Breakout-v1", 3, env_kwargs={"sticky_action_prob": 0})
    assert len([w for w in caught if "ports minatar" in str(w.message)]) == 1  # one warning
    assert not envs.compiled and not again.compiled
    with pytest.raises(ImportError, match="minatar 1.0.16 is installed"):
        MinAtarVectorEnv("MinAtar/Breakout-v1", 2, compiled=True)
    python = make_vector_env("MinAtar/Breakout-v1", 3, env_kwargs={"sticky_action_prob": 0},
                             batched=False)
    for vector in (envs, python):
        vector.reset(seed=5)
    for _ in range(40):
        actions = np.array([1, 2, 0])
        got, expected = envs.step(actions), python.step(actions)
        np.testing.assert_array_equal(got[0], expected[0])
        np.testing.assert_array_equal(got[1], expected[1])
    # The version it ports: the core is taken.
    monkeypatch.setattr(_native, "_loaded", {})
    monkeypatch.setattr(_native, "installed_version", lambda name: "1.0.15")
    assert MinAtarVectorEnv("MinAtar/Breakout-v1", 2).compiled


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
    with pytest.raises(ValueError, match="actions must be integers, got an array of float64"):
        envs.step(np.array([1.9, 0.0]))
    with pytest.raises(ValueError, match="outside the env's primitive actions"):
        MinAtarVectorEnv("MinAtar/Breakout-v1", 2, routines=[[7]])
    with pytest.raises(ValueError, match="runs MinAtar's games, not 'CartPole-v1'"):
        MinAtarVectorEnv("CartPole-v1", 2)


@needs_core
def test_a_copy_of_the_compiled_env_draws_from_its_own_games_generators():
    # The core reaches each game's RandomState by address: a copy (deepcopy, pickle) must use
    # its own games' generators, so the copy and the original go on identically and apart.
    import copy
    import pickle

    envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 3, env_kwargs={"sticky_action_prob": 0.5})
    envs.reset(seed=2)
    twins = [copy.deepcopy(envs), pickle.loads(pickle.dumps(envs))]
    for twin in twins:
        assert twin.compiled
        assert not set(twin._rngs.tolist()) & set(envs._rngs.tolist())
    rng = np.random.default_rng(0)
    for _ in range(100):
        actions = rng.integers(0, 3, 3)
        outs = [e.step(actions)[:4] for e in (envs, *twins)]
        for out in outs[1:]:
            for a, b in zip(outs[0], out, strict=True):
                assert np.array_equal(a, b)


@needs_core
def test_the_compiled_env_steps_before_any_reset_as_the_python_loop_does():
    compiled, python = (MinAtarVectorEnv("MinAtar/Breakout-v1", 2, compiled=c)
                        for c in (True, False))
    for i, (game_c, game_p) in enumerate(zip(compiled._games, python._games, strict=True)):
        # MinAtar started each game from its own unseeded generator: make the two the same.
        game_p.random.set_state(game_c.random.get_state())
        _set_state(python, i, {key: getattr(game_c.env, key) for key in (
            "ball_x", "ball_y", "ball_dir", "pos", "strike", "last_x", "last_y", "brick_map")})
    out_c, out_p = compiled.step(np.array([1, 2])), python.step(np.array([1, 2]))
    for a, b in zip(out_c[:4], out_p[:4], strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("field,value", [("ball_y", 10), ("ball_x", -1), ("pos", 12),
                                         ("ball_dir", 4), ("last_action", 9)])
@needs_core
def test_the_compiled_core_refuses_a_state_off_the_board(field, value):
    envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 2, compiled=True)
    envs.reset(seed=0)
    _set_state(envs, 1, {field: value})
    envs._load_core()
    with pytest.raises(ValueError, match="game 1 is not a Breakout state"):
        envs.step(np.array([0, 0]))


@needs_core
def test_the_compiled_core_refuses_a_ball_falling_out_of_the_board():
    # MinAtar's own `act` raises IndexError from such a state; the core says what happened.
    envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 1, env_kwargs={"sticky_action_prob": 0.0},
                            compiled=True)
    envs.reset(seed=0)
    _set_state(envs, 0, {"ball_y": 9, "ball_dir": 2, "pos": 0, "ball_x": 5})
    envs._load_core()
    with pytest.raises(ValueError, match="the ball left the board at the bottom"):
        envs.step(np.array([0]))
