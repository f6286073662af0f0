"""RoutineActionWrapper's step on scripted envs: observations recorded as they arrive (an env
that updates one array in place), an error mid-routine, the errors of bad actions and of a
malformed inner step, integer-like actions, and a copy stepping its own env. (The compiled
step these were written against, `_wrapper_core.cpp`, went under issue 48's admission rule;
the Python step is the only one.)"""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from routine_gym.wrapper import RoutineActionWrapper

OBSERVATIONS = {
    # kind: (space, observation of step t after action a)
    "float32": (spaces.Box(-1e6, 1e6, (2,), np.float32),
                lambda t, a: np.array([t, 1.5 * a], dtype=np.float32)),
    "uint8 image": (spaces.Box(0, 255, (3, 4), np.uint8),
                    lambda t, a: np.full((3, 4), (7 * t + a) % 256, dtype=np.uint8)),
    "discrete": (spaces.Discrete(10**6), lambda t, a: 10 * t + a),
    "multibinary": (spaces.MultiBinary(3), lambda t, a: np.array([t % 2, a % 2, 1], np.int8)),
    # Not the space's dtype or not an array: numpy's item assignment converts them.
    "float64 given float32": (spaces.Box(-1e6, 1e6, (2,), np.float64),
                              lambda t, a: np.array([t / 3, a], dtype=np.float32)),
    "list": (spaces.Box(-1e6, 1e6, (3,), np.float64), lambda t, a: [t, a, 0.25]),
    "strided": (spaces.Box(-1e6, 1e6, (2,), np.float64),
                lambda t, a: np.array([[t, 9.0], [a, 9.0]])[:, 0]),
}



class ScriptEnv(gym.Env):
    """Step `t` (from 1) after action `a`: the observation of its kind, reward `0.3 a + 0.1 t`
    (a numpy float32 on odd steps), terminated at the steps in `terminate`, truncated at those
    in `truncate`; `in_place` returns one observation array updated in place every step."""

    action_space = spaces.Discrete(3)

    def __init__(self, kind: str, terminate=(), truncate=(), in_place: bool = False):
        self.observation_space, self._observe = OBSERVATIONS[kind]
        self.terminate, self.truncate, self.in_place = set(terminate), set(truncate), in_place
        self.t = 0
        self._buffer = None

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self._obs(0), {"t": 0}

    def _obs(self, action):
        obs = self._observe(self.t, action)
        if not self.in_place:
            return obs
        if self._buffer is None:
            self._buffer = np.array(obs)
        self._buffer[...] = obs
        return self._buffer

    def step(self, action):
        assert self.action_space.contains(int(action)), action
        self.t += 1
        reward = 0.3 * int(action) + 0.1 * self.t
        if self.t % 2:
            reward = np.float32(reward)
        return (self._obs(int(action)), reward, self.t in self.terminate, self.t in self.truncate,
                {"t": self.t})


def wrapped(kind: str, routines, record: bool = True, **env_kwargs) -> RoutineActionWrapper:
    env = RoutineActionWrapper(ScriptEnv(kind, **env_kwargs), routines,
                               record_observations=record)
    env.reset(seed=0)
    return env


@pytest.mark.parametrize("kind", sorted(OBSERVATIONS))
def test_each_observation_kind_is_recorded_padded_with_zeros(kind):
    space, observe = OBSERVATIONS[kind]
    env = wrapped(kind, [[1, 2], [0, 1, 2, 0]])
    obs, reward, terminated, truncated, info = env.step(3)  # routine 0: actions 1 then 2
    expected = np.zeros((4, *space.shape), dtype=space.dtype)
    expected[0], expected[1] = observe(1, 1), observe(2, 2)
    assert info["routine_observations"].dtype == space.dtype
    np.testing.assert_array_equal(info["routine_observations"], expected)
    np.testing.assert_array_equal(obs, observe(2, 2))
    # 0.3 a + 0.1 t per step, summed as floats: (0.3 + 0.1) + (0.6 + 0.2)
    assert type(reward) is float and reward == pytest.approx(1.2)
    assert (terminated, truncated, info["t"]) == (False, False, 2)


def test_observations_updated_in_place_are_recorded_per_step():
    """An env returning one array it updates in place: each row is the observation of its
    step (the step copies each observation when it arrives)."""
    env = wrapped("float32", [[1, 2, 0]], in_place=True)
    info = env.step(3)[4]
    np.testing.assert_array_equal(info["routine_observations"], [[1, 1.5], [2, 3.0], [3, 0.0]])


def test_an_error_mid_routine_leaves_the_next_steps_right():
    class FailingEnv(ScriptEnv):
        def step(self, action):
            if self.t == 1:
                self.t += 1
                raise RuntimeError("inner env failed")
            return super().step(action)

    env = RoutineActionWrapper(FailingEnv("float32"), [[2, 2, 2]])
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="inner env failed"):
        env.step(3)
    for _ in range(3):
        info = env.step(1)[4]
        np.testing.assert_array_equal(info["routine_actions"], [1, -1, -1])
        np.testing.assert_array_equal(info["routine_rewards"][1:], [0, 0])
        np.testing.assert_array_equal(info["routine_terminated"], [False] * 3)
        np.testing.assert_array_equal(info["routine_observations"][1:], 0)


@pytest.mark.parametrize(
    ("action", "error", "match"),
    [
        (5, ValueError, r"action 5 is outside the action space Discrete\(5\)"),
        (2**70, ValueError, r"action 1180591620717411303424 is outside"),
        (np.int64(-1), ValueError, r"action -1 is outside"),
        (1.5, ValueError, r"action 1\.5 is not an integer action of Discrete\(5\)"),
        ("1", ValueError, r"action '1' is not an integer"),
    ],
)
def test_invalid_actions_are_errors_naming_the_action(action, error, match):
    env = wrapped("float32", [[0, 1], [2]], record=False)
    with pytest.raises(error, match=match):
        env.step(action)
    assert env.env.t == 0  # nothing ran


@pytest.mark.parametrize(("action", "actions"),
                         [(np.int64(4), [2, -1]), (np.int32(1), [1, -1]), (np.uint8(3), [0, 1]),
                          (True, [1, -1])])
def test_integer_like_actions_are_accepted(action, actions):
    info = wrapped("float32", [[0, 1], [2]]).step(action)[4]
    np.testing.assert_array_equal(info["routine_actions"], actions)


@pytest.mark.parametrize(
    ("result", "error", "match"),
    [
        ((np.zeros(2, np.float32), 1.0, False, False), ValueError, "expected 5, got 4"),
        ((np.zeros(2, np.float32), "one", False, False, {}), ValueError,
         "could not convert string to float"),
    ],
)
def test_a_malformed_inner_step_is_an_error(result, error, match):
    class Malformed(ScriptEnv):
        def step(self, action):
            return result

    env = RoutineActionWrapper(Malformed("float32"), [[0, 1]])
    env.reset(seed=0)
    with pytest.raises(error, match=match):
        env.step(3)


def test_a_copy_steps_its_own_env():
    env = wrapped("float32", [[1, 1]])
    env.step(3)
    twin = copy.deepcopy(env)
    twin.step(3)
    assert (env.env.t, twin.env.t) == (2, 4)


def test_a_new_inner_env_is_the_one_stepped():
    env = wrapped("float32", [[1, 1]])
    first, other = env.env, ScriptEnv("float32")
    other.reset(seed=0)
    env.env = other
    env.step(3)
    assert (first.t, other.t) == (0, 2)
