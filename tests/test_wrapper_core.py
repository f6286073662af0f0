"""RoutineActionWrapper's compiled step (`routine_gym/_wrapper_core.cpp`) against its Python
`step`, which stays the reference: the same observations, rewards, flags and info on random
routines, actions, episode ends and observation spaces; the recycling of info arrays nobody
holds; and the cases that keep the Python step."""

from __future__ import annotations

import copy
import gc
import weakref

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from hypothesis import given, settings
from hypothesis import strategies as st

import routine_gym.wrapper
from routine_gym.wrapper import RoutineActionWrapper

RING = 4  # kRing in _wrapper_core.cpp: steps whose arrays the core holds

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


def twins(kind, routines, record, **env_kwargs):
    """The compiled wrapper and one stepped by the Python `step`, on identical envs."""
    envs = []
    for _ in range(2):
        env = RoutineActionWrapper(ScriptEnv(kind, **env_kwargs), routines,
                                   record_observations=record)
        env.reset(seed=0)
        envs.append(env)
    compiled, python = envs
    assert compiled.step.__self__ is compiled._stepper  # the core is built and in use
    return compiled, lambda action: RoutineActionWrapper.step(python, action), python


def assert_same_step(got, expected):
    (obs, reward, terminated, truncated, info), (obs2, reward2, terminated2, truncated2,
                                                 info2) = got, expected
    np.testing.assert_array_equal(obs, obs2)
    assert type(reward) is float and reward == reward2
    assert terminated is terminated2 and truncated is truncated2
    assert info.keys() == info2.keys()
    for key, value in info2.items():
        if isinstance(value, np.ndarray):
            assert info[key].dtype == value.dtype and info[key].shape == value.shape, key
            np.testing.assert_array_equal(info[key], value, err_msg=key)
        else:
            assert info[key] == value and type(info[key]) is type(value), key


def snapshot(info):
    return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in info.items()}


@settings(max_examples=60, deadline=None)
@given(
    kind=st.sampled_from(sorted(OBSERVATIONS)),
    routines=st.lists(st.lists(st.integers(0, 2), min_size=1, max_size=5), max_size=3),
    record=st.booleans(),
    in_place=st.booleans(),
    ends=st.lists(st.tuples(st.integers(1, 30), st.booleans()), max_size=6),
    steps=st.lists(st.tuples(st.integers(0, 5), st.booleans()), min_size=1, max_size=25),
)
def test_compiled_step_matches_the_python_step(kind, routines, record, in_place, ends, steps):
    terminate = [t for t, terminated in ends if terminated]
    truncate = [t for t, terminated in ends if not terminated]
    compiled, python_step, python = twins(kind, routines, record, terminate=terminate,
                                          truncate=truncate, in_place=in_place)
    kept = []
    for action, keep in steps:
        action %= compiled.action_space.n
        got = compiled.step(action)
        assert_same_step(got, python_step(action))
        if keep:  # a consumer that keeps the info: its arrays never change afterwards
            kept.append((got[4], snapshot(got[4])))
        if got[2] or got[3]:
            compiled.reset()
            python.reset()
        del got
    for info, saved in kept:
        assert_same_step((0, 0.0, False, False, info), (0, 0.0, False, False, saved))


def test_observations_updated_in_place_are_recorded_per_step():
    """An env returning one array it updates in place: each row is the observation of its
    step (both steps copy each observation when it arrives)."""
    compiled, python_step, _ = twins("float32", [[1, 2, 0]], True, in_place=True)
    expected = [[1, 1.5], [2, 3.0], [3, 0.0]]
    for info in (compiled.step(3)[4], python_step(3)[4]):
        np.testing.assert_array_equal(info["routine_observations"], expected)


def test_info_arrays_nobody_holds_are_reused_with_their_padding_back():
    env = RoutineActionWrapper(ScriptEnv("float32", terminate=[2]), [[1, 1, 1]])
    env.reset(seed=0)
    info = env.step(3)[4]  # terminates after 2 of the 3 primitives
    np.testing.assert_array_equal(info["routine_terminated"], [False, True, False])
    held = {key: weakref.ref(info[key]) for key in routine_gym.macro_info.ROUTINE_INFO_KEYS[2:]}
    del info
    env.reset()
    for _ in range(RING - 1):
        env.step(0)  # primitives, infos dropped
    gc.collect()
    info = env.step(0)[4]  # the first slot again: the same arrays, padding restored
    for key, ref in held.items():
        assert info[key] is ref(), key
    assert info["routine_length"] == 1
    np.testing.assert_array_equal(info["routine_actions"], [0, -1, -1])
    np.testing.assert_array_equal(info["routine_rewards"], [0.4, 0, 0])  # step 4 after reset
    np.testing.assert_array_equal(info["routine_terminated"], [False, False, False])
    np.testing.assert_array_equal(info["routine_observations"][1:], 0)


def test_info_arrays_held_or_reshaped_are_not_reused():
    env = RoutineActionWrapper(ScriptEnv("float32"), [[1, 1]])
    env.reset(seed=0)
    first = env.step(3)[4]
    kept = first["routine_rewards"]
    reshaped = first["routine_actions"]
    reshaped.shape = (1, 2)  # a consumer changed the array itself, then dropped it
    del first, reshaped
    for _ in range(RING - 1):
        env.step(0)
    info = env.step(3)[4]
    assert info["routine_rewards"] is not kept
    np.testing.assert_array_equal(kept, [np.float32(0.4), 0.5])  # the first step's, unchanged
    assert info["routine_actions"].shape == (2,)
    np.testing.assert_array_equal(info["routine_actions"], [1, 1])


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
    for _ in range(RING - 1):
        env.step(1)
    info = env.step(1)[4]  # the slot the failed step had written to
    np.testing.assert_array_equal(info["routine_actions"], [1, -1, -1])
    np.testing.assert_array_equal(info["routine_rewards"][1:], [0, 0])
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
def test_invalid_actions_get_the_python_steps_errors(action, error, match):
    compiled, python_step, _ = twins("float32", [[0, 1], [2]], False)
    for step in (compiled.step, python_step):
        with pytest.raises(error, match=match):
            step(action)


@pytest.mark.parametrize("action", [np.int64(4), np.int32(1), np.uint8(3), True])
def test_integer_like_actions_are_accepted(action):
    compiled, python_step, _ = twins("float32", [[0, 1], [2]], True)
    assert_same_step(compiled.step(action), python_step(action))


@pytest.mark.parametrize(
    ("result", "error", "match"),
    [
        ((np.zeros(2, np.float32), 1.0, False, False), ValueError, "returned 4 values"),
        ((np.zeros(2, np.float32), "one", False, False, {}), TypeError, "must be real number"),
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


def test_a_subclass_overriding_step_and_structured_observations_keep_the_python_step():
    class Logged(RoutineActionWrapper):
        def step(self, action):
            self.calls = getattr(self, "calls", 0) + 1
            return super().step(action)

    env = Logged(ScriptEnv("float32"), [[0, 1]])
    env.reset(seed=0)
    env.step(2)
    assert env.calls == 1 and "step" not in vars(env)

    class DictEnv(ScriptEnv):
        def __init__(self):
            super().__init__("float32")
            self.observation_space = spaces.Dict({"x": OBSERVATIONS["float32"][0]})

    assert "step" not in vars(RoutineActionWrapper(DictEnv(), [[0]]))
    assert "step" in vars(RoutineActionWrapper(DictEnv(), [[0]], record_observations=False))


def test_without_the_compiled_core_the_python_step_runs(monkeypatch):
    monkeypatch.setattr(routine_gym.wrapper, "_Stepper", None)
    env = RoutineActionWrapper(ScriptEnv("float32"), [[0, 1]])
    env.reset(seed=0)
    assert "step" not in vars(env)
    info = env.step(3)[4]
    np.testing.assert_array_equal(info["routine_actions"], [0, 1])


def test_a_copy_steps_its_own_env():
    env = RoutineActionWrapper(ScriptEnv("float32"), [[1, 1]])
    env.reset(seed=0)
    env.step(3)
    twin = copy.deepcopy(env)
    assert twin.step.__self__ is twin._stepper is not env._stepper
    twin.step(3)
    assert (env.env.t, twin.env.t) == (2, 4)


def test_a_new_inner_env_gets_its_own_compiled_step():
    env = RoutineActionWrapper(ScriptEnv("float32"), [[1, 1]])
    env.reset(seed=0)
    other = ScriptEnv("float32")
    other.reset(seed=0)
    env.env = other
    env.step(3)
    assert other.t == 2 and env.step.__self__ is env._stepper


def test_the_compiled_step_has_a_signature():
    import inspect

    env = RoutineActionWrapper(ScriptEnv("float32"), [[1, 1]])
    assert list(inspect.signature(env.step).parameters) == ["action"]
