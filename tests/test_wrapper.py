"""RoutineActionWrapper: the routine semantics, the info contract, and third-party clients."""

from __future__ import annotations

import copy
import doctest
import json
import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv
from gymnasium.wrappers import TimeLimit

import routine_gym  # noqa: F401  (registers the envs)
import routine_gym.wrapper
from routine_gym.library import RoutineLibrary
from routine_gym.wrapper import RoutineActionWrapper


class CounterEnv(gym.Env):
    """Observation: the step count; action `a` gives reward `a + 1`; ends after `terminate_at`."""

    metadata = {"render_modes": []}
    observation_space = spaces.Box(0, 1000, shape=(1,), dtype=np.int64)
    action_space = spaces.Discrete(3)

    def __init__(self, terminate_at: int = 3):
        self.terminate_at = terminate_at
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.array([0]), {"t": 0}

    def step(self, action):
        assert self.action_space.contains(action), action
        self.t += 1
        info = {"t": self.t, "inner_action": int(action)}
        return np.array([self.t]), float(action + 1), self.t >= self.terminate_at, False, info


class NamedCounterEnv(CounterEnv):
    def get_action_meanings(self):
        return ["NOOP", "UP", "RIGHT"]


def counter(routines, terminate_at=3, **kwargs) -> RoutineActionWrapper:
    env = RoutineActionWrapper(CounterEnv(terminate_at), routines, **kwargs)
    env.reset(seed=0)
    return env


def check_wrapped_env(env: gym.Env, **kwargs) -> None:
    """`check_env` on a wrapped env, without the warnings that are about the inner env."""
    with warnings.catch_warnings():
        for message in (
            "different from the unwrapped version",  # check_env prefers bare envs
            "not having a spec",  # envs made without gym.make
            "Box observation space m",  # CartPole's infinite bounds
        ):
            warnings.filterwarnings("ignore", message=f".*{message}.*")
        check_env(env, **kwargs)


def assert_info(info, **expected):
    for key, value in expected.items():
        np.testing.assert_array_equal(info[key], value, err_msg=key)
        if isinstance(value, np.ndarray):
            assert info[key].dtype == value.dtype, key


# -- the routine semantics -----------------------------------------------------------------


def test_action_space_adds_one_action_per_routine():
    env = counter([[0, 1], np.array([2, 2, 2]), (1,)])
    assert env.action_space == spaces.Discrete(3 + 3)
    assert env.routines == ((0, 1), (2, 2, 2), (1,))
    assert all(type(a) is int for r in env.routines for a in r)
    assert env.num_primitive_actions == 3
    assert env.max_routine_length == 3


def test_routine_runs_one_primitive_per_inner_step():
    env = counter([[2, 0, 1]], terminate_at=10)
    obs, reward, terminated, truncated, info = env.step(3)
    assert reward == 3.0 + 1.0 + 2.0
    np.testing.assert_array_equal(obs, [3])
    assert (terminated, truncated) == (False, False)
    assert info["t"] == 3 and info["inner_action"] == 1  # the inner env's last info is kept
    assert_info(
        info,
        routine_index=0,
        routine_length=3,
        routine_actions=np.array([2, 0, 1]),
        routine_rewards=np.array([3.0, 1.0, 2.0]),
        routine_terminated=np.array([False, False, False]),
        routine_truncated=np.array([False, False, False]),
        routine_observations=np.array([[1], [2], [3]]),
    )


def test_routine_stops_early_on_termination():
    env = counter([[1], [2, 2, 1, 0]], terminate_at=3)
    env.step(0)  # t = 1
    obs, reward, terminated, truncated, info = env.step(4)  # runs t = 2, 3 of 4 actions
    assert reward == 6.0
    np.testing.assert_array_equal(obs, [3])
    assert (terminated, truncated) == (True, False)
    assert info["t"] == 3 and info["inner_action"] == 2
    assert_info(
        info,
        routine_index=1,
        routine_length=2,
        routine_actions=np.array([2, 2, -1, -1]),
        routine_rewards=np.array([3.0, 3.0, 0.0, 0.0]),
        routine_terminated=np.array([False, True, False, False]),
        routine_truncated=np.array([False, False, False, False]),
        routine_observations=np.array([[2], [3], [0], [0]]),
    )
    # Zero padding makes the discounted routine reward a plain dot product: 3 + 0.9 * 3.
    gamma = 0.9
    discounts = gamma ** np.arange(env.max_routine_length)
    assert discounts @ info["routine_rewards"] == pytest.approx(5.7)


def test_routine_stops_early_on_truncation():
    env = RoutineActionWrapper(
        TimeLimit(CounterEnv(terminate_at=100), max_episode_steps=2), [[1, 1, 1]]
    )
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(3)
    assert reward == 4.0
    assert (terminated, truncated) == (False, True)
    assert_info(
        info,
        routine_length=2,
        routine_actions=np.array([1, 1, -1]),
        routine_rewards=np.array([2.0, 2.0, 0.0]),
        routine_terminated=np.array([False, False, False]),
        routine_truncated=np.array([False, True, False]),
        routine_observations=np.array([[1], [2], [0]]),
    )


def test_primitive_action_is_a_routine_of_length_one():
    env = counter([[0, 1, 2]], terminate_at=10)
    obs, reward, terminated, truncated, info = env.step(np.int64(2))
    assert reward == 3.0
    assert info["inner_action"] == 2
    assert_info(
        info,
        routine_index=-1,
        routine_length=1,
        routine_actions=np.array([2, -1, -1]),
        routine_rewards=np.array([3.0, 0.0, 0.0]),
        routine_terminated=np.array([False, False, False]),
        routine_truncated=np.array([False, False, False]),
        routine_observations=np.array([[1], [0], [0]]),
    )


def test_primitive_action_that_terminates_reports_the_flag():
    env = counter([[0, 0]], terminate_at=1)
    _, reward, terminated, _, info = env.step(1)
    assert (reward, terminated) == (2.0, True)
    assert_info(info, routine_length=1, routine_terminated=np.array([True, False]))


def test_no_routines_keeps_the_action_space_and_adds_the_info():
    env = counter([])
    assert env.action_space == spaces.Discrete(3)
    assert env.max_routine_length == 1
    _, reward, _, _, info = env.step(1)
    assert reward == 2.0
    assert_info(info, routine_index=-1, routine_length=1, routine_actions=np.array([1]))


def test_record_observations_false_omits_the_key():
    env = counter([[1, 1]], record_observations=False)
    for action in (1, 3):
        info = env.step(action)[4]
        assert "routine_observations" not in info
        assert "routine_rewards" in info


def test_info_arrays_are_new_on_every_step():
    env = counter([[1, 1]], terminate_at=10**6)
    first = env.step(3)[4]
    first["routine_rewards"][0] = 99.0  # a consumer may modify what it was given
    second = env.step(3)[4]
    assert_info(second, routine_rewards=np.array([2.0, 2.0]))
    assert not np.shares_memory(first["routine_rewards"], second["routine_rewards"])
    # More steps than one allocation block serves still give fresh, correct rows.
    for _ in range(routine_gym.wrapper._BLOCK_ROWS + 3):
        info = env.step(0)[4]
    assert_info(
        info, routine_actions=np.array([0, -1]), routine_terminated=np.array([False, False])
    )


@pytest.mark.parametrize(
    "clone",
    [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))],
    ids=["deepcopy", "pickle"],
)
def test_wrapper_can_be_copied_and_pickled(clone):
    """The info blocks are written through memoryviews, which neither can save: a copy makes
    its own, and both go on with correct, unshared info rows."""
    env = counter([[1, 1]], terminate_at=10**6)
    first = env.step(3)[4]
    twin = clone(env)
    for wrapper in (env, twin):
        info = wrapper.step(3)[4]
        assert_info(info, routine_actions=np.array([1, 1]), routine_rewards=np.array([2.0, 2.0]),
                    routine_length=2)
        assert not np.shares_memory(first["routine_rewards"], info["routine_rewards"])
    assert twin.env.t == env.env.t == 4


def test_structured_observations_are_stacked_and_padded():
    class DictObsEnv(CounterEnv):
        observation_space = spaces.Dict(
            {"t": spaces.Discrete(100), "pos": spaces.Box(-10, 10, (2,), dtype=np.float32)}
        )

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            return {"t": 0, "pos": np.zeros(2, np.float32)}, {}

        def step(self, action):
            obs, *rest = super().step(action)
            return {"t": int(obs[0]), "pos": np.full(2, obs[0], np.float32)}, *rest

    env = RoutineActionWrapper(DictObsEnv(terminate_at=2), [[0, 0, 0]])
    env.reset(seed=0)
    observations = env.step(3)[4]["routine_observations"]
    np.testing.assert_array_equal(observations["t"], [1, 2, 0])
    np.testing.assert_array_equal(observations["pos"], [[1, 1], [2, 2], [0, 0]])


# -- validation ----------------------------------------------------------------------------


def test_non_discrete_env_is_rejected():
    with pytest.raises(TypeError, match=r"Discrete action space, actual action space: Box"):
        RoutineActionWrapper(gym.make("MountainCarContinuous-v0"), [[0]])


def test_discrete_action_space_not_starting_at_zero_is_rejected():
    env = CounterEnv()
    env.action_space = spaces.Discrete(3, start=1)
    with pytest.raises(
        ValueError, match=r"starting at 0, actual action space: Discrete\(3, start=1\)"
    ):
        RoutineActionWrapper(env, [[1]])


@pytest.mark.parametrize(
    ("routines", "error", "match"),
    [
        ([[0, 1], []], ValueError, r"routine 1 is empty"),
        (
            [[0, 1, 3]],
            ValueError,
            r"routine 0 has action 3, outside the env's primitive actions \[0, 3\)",
        ),
        ([[0], [-1, 0]], ValueError, r"routine 1 has action -1, outside .* \[0, 3\)"),
        ([[0, 1.0]], ValueError, r"routine 0 has action 1\.0 of type float; .* \[0, 3\)"),
        ([[True]], ValueError, r"routine 0 has action True of type bool"),
        (
            [0, 1, 2],
            TypeError,
            r"routine 0 must be a sequence of primitive actions, actual value: 0",
        ),
        (["012"], TypeError, r"routine 0 must be a sequence"),
        (5, TypeError, r"routines must be a RoutineLibrary or a sequence"),
    ],
)
def test_invalid_routines_are_rejected(routines, error, match):
    with pytest.raises(error, match=match):
        RoutineActionWrapper(CounterEnv(), routines)


@pytest.mark.parametrize(
    ("action", "match"),
    [
        (5, r"action 5 is outside the action space Discrete\(5\)"),
        (-1, r"action -1 is outside"),
        (1.5, r"action 1\.5 is not an integer"),
    ],
)
def test_invalid_action_is_rejected(action, match):
    env = counter([[0, 1], [2]])
    with pytest.raises(ValueError, match=match):
        env.step(action)


# -- action meanings, libraries, specs -----------------------------------------------------


def test_action_meanings_name_routines_by_their_actions():
    env = RoutineActionWrapper(NamedCounterEnv(), [[1, 1, 2], [0]])
    assert env.get_action_meanings() == ["NOOP", "UP", "RIGHT", "R0:UP UP RIGHT", "R1:NOOP"]


def test_action_meanings_without_names_are_action_ids():
    env = RoutineActionWrapper(CounterEnv(), [[1, 1, 2]])
    assert env.get_action_meanings() == ["0", "1", "2", "R0:1 1 2"]


def test_routine_library_is_accepted_and_its_names_used():
    library = RoutineLibrary(routines=((2, 2), (0, 1, 0)), action_meanings=("A", "B", "C"))
    env = RoutineActionWrapper(CounterEnv(), library)
    assert env.library is library
    assert env.routines == ((2, 2), (0, 1, 0))
    assert env.get_action_meanings() == ["A", "B", "C", "R0:C C", "R1:A B A"]


def test_spec_remakes_the_wrapper():
    library = RoutineLibrary(routines=((0, 1), (1, 1, 1)))
    env = RoutineActionWrapper(gym.make("CartPole-v1"), library, record_observations=False)
    spec_json = env.spec.to_json()  # plain lists of ints: serialisable
    wrapper_spec = json.loads(spec_json)["additional_wrappers"][-1]
    assert wrapper_spec["kwargs"] == {"routines": [[0, 1], [1, 1, 1]], "record_observations": False}

    remade = gym.make(env.spec)
    assert isinstance(remade, RoutineActionWrapper)
    assert remade.routines == env.routines and remade.record_observations is False
    assert remade.spec == env.spec
    first = env.reset(seed=5)[0], env.step(3)
    second = remade.reset(seed=5)[0], remade.step(3)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1][0], second[1][0])
    assert first[1][4]["routine_length"] == second[1][4]["routine_length"] == 3


def test_docstring_example_runs():
    result = doctest.testmod(routine_gym.wrapper, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


# -- Gymnasium's checker and vector envs ----------------------------------------------------


def test_check_env_passes_on_cartpole():
    check_wrapped_env(RoutineActionWrapper(gym.make("CartPole-v1"), [[0, 1], [1, 1, 1]]))


def test_check_env_passes_on_the_counter_env():
    check_wrapped_env(RoutineActionWrapper(CounterEnv(terminate_at=100), [[0, 1], [2, 2, 2]]))


def make_counter_env():
    return RoutineActionWrapper(CounterEnv(terminate_at=3), [[2, 2, 2, 2]])


@pytest.mark.parametrize("vector_cls", [SyncVectorEnv, AsyncVectorEnv])
def test_vector_env_next_step_autoreset(vector_cls):
    envs = vector_cls([make_counter_env] * 2, autoreset_mode=AutoresetMode.NEXT_STEP)
    try:
        envs.reset(seed=0)
        # env 0 runs the routine into the end of its episode (3 of 4 steps); env 1 a primitive.
        obs, rewards, terminations, truncations, infos = envs.step(np.array([3, 0]))
        np.testing.assert_array_equal(rewards, [9.0, 1.0])
        np.testing.assert_array_equal(terminations, [True, False])
        np.testing.assert_array_equal(obs, [[3], [1]])
        assert_info(
            infos,
            routine_index=np.array([0, -1]),
            routine_length=np.array([3, 1]),
            routine_actions=np.array([[2, 2, 2, -1], [0, -1, -1, -1]]),
            routine_rewards=np.array([[3.0, 3.0, 3.0, 0.0], [1.0, 0.0, 0.0, 0.0]]),
            routine_terminated=np.array([[False, False, True, False], [False] * 4]),
            routine_truncated=np.zeros((2, 4), dtype=bool),
            routine_observations=np.array([[[1], [2], [3], [0]], [[1], [0], [0], [0]]]),
        )
        # Next step: env 0 resets (no routine info), env 1 runs the routine from t = 1.
        obs, rewards, terminations, _, infos = envs.step(np.array([3, 3]))
        np.testing.assert_array_equal(rewards, [0.0, 6.0])
        np.testing.assert_array_equal(terminations, [False, True])
        np.testing.assert_array_equal(infos["_routine_length"], [False, True])
        assert infos["routine_length"][1] == 2
        np.testing.assert_array_equal(infos["routine_rewards"][1], [3.0, 3.0, 0.0, 0.0])
    finally:
        envs.close()


@pytest.mark.parametrize("vector_cls", [SyncVectorEnv, AsyncVectorEnv])
def test_vector_env_same_step_autoreset(vector_cls):
    envs = vector_cls([make_counter_env] * 2, autoreset_mode=AutoresetMode.SAME_STEP)
    try:
        envs.reset(seed=0)
        obs, rewards, terminations, _, infos = envs.step(np.array([3, 0]))
        np.testing.assert_array_equal(rewards, [9.0, 1.0])
        np.testing.assert_array_equal(terminations, [True, False])
        np.testing.assert_array_equal(obs, [[0], [1]])  # env 0 was reset in the same step
        # The routine's info of the finished episode is in final_info, the reset's in info.
        final = infos["final_info"]
        np.testing.assert_array_equal(final["_routine_length"], [True, False])
        assert final["routine_length"][0] == 3
        np.testing.assert_array_equal(final["routine_rewards"][0], [3.0, 3.0, 3.0, 0.0])
        np.testing.assert_array_equal(final["routine_terminated"][0], [False, False, True, False])
        np.testing.assert_array_equal(final["routine_observations"][0], [[1], [2], [3], [0]])
        np.testing.assert_array_equal(infos["final_obs"][0], [3])
        np.testing.assert_array_equal(infos["_routine_length"], [False, True])
        assert infos["routine_length"][1] == 1
        np.testing.assert_array_equal(infos["routine_actions"][1], [0, -1, -1, -1])
    finally:
        envs.close()


# -- third-party clients and real games ----------------------------------------------------


@pytest.mark.slow
def test_stable_baselines3_a2c_trains_through_the_wrapper(tmp_path, monkeypatch):
    torch = pytest.importorskip("torch")
    monkeypatch.setenv("SB3_LOGDIR", str(tmp_path))  # SB3's logger makes a folder, /tmp/SB3-… else
    from stable_baselines3 import A2C

    env = RoutineActionWrapper(
        gym.make("CartPole-v1"), [[0, 1], [1, 0, 1]], record_observations=False
    )
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a tiny MLP: more threads only contend on a 2-core machine
    try:
        model = A2C("MlpPolicy", env, n_steps=5, seed=0, device="cpu")
        model.learn(256)
    finally:
        torch.set_num_threads(threads)
    assert model.num_timesteps == 260  # decisions, in whole rollouts of 5: 52 * 5 ≥ 256
    episodes = list(model.ep_info_buffer)
    assert episodes
    # CartPole's return is its number of primitive steps; routines make it exceed the decisions.
    assert sum(ep["r"] for ep in episodes) > sum(ep["l"] for ep in episodes)


def test_wrapper_on_ale_qbert_runs_a_routine():
    env = RoutineActionWrapper(gym.make("ALE/Qbert-v5"), [[2, 2, 3]])
    assert env.get_action_meanings()[:6] == ["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"]
    assert env.get_action_meanings()[-1] == "R0:UP UP RIGHT"
    _, info = env.reset(seed=0)
    start_frame = info["frame_number"]
    obs, _, terminated, truncated, info = env.step(6)
    assert not (terminated or truncated)
    assert info["routine_length"] == 3
    np.testing.assert_array_equal(info["routine_actions"], [2, 2, 3])
    assert info["frame_number"] - start_frame == 3 * 4  # three steps of frame-skip 4
    assert info["routine_observations"].shape == (3, 210, 160, 3)
    np.testing.assert_array_equal(info["routine_observations"][-1], obs)
    env.close()


def test_check_env_passes_on_ale_qbert():
    env = RoutineActionWrapper(gym.make("ALE/Qbert-v5"), [[2, 2, 3], [5, 4]])
    check_wrapped_env(env, skip_render_check=True)
    env.close()


def test_check_env_passes_on_coinrun():
    # LEFT, DOWN, UP, RIGHT, NOOP: "jump right twice" and "run left".
    env = RoutineActionWrapper(gym.make("procgen/CoinRun-v0"), [[2, 3, 3], [0, 0, 0]])
    check_wrapped_env(env, skip_render_check=True)
    assert env.action_space == gym.spaces.Discrete(7)
    env.close()
