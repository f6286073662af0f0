"""The agent's replay memory (routine_gym.replay_memory): frame stacks rebuilt from a ring of
frames, so that after a routine they are the stacks the env returned."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from routine_gym.envs.factory import make_env
from routine_gym.replay_memory import FrameReplayMemory
from routine_gym.wrapper import RoutineActionWrapper


def _stack(*values: int) -> np.ndarray:
    return np.array(values, dtype=np.uint8).reshape(len(values), 1, 1)


def _all_transitions(memory: FrameReplayMemory) -> dict[str, np.ndarray]:
    index = np.flatnonzero(memory._valid(np.arange(memory.capacity)))
    return {
        "index": index,
        "obs": memory.stacks(index)[:, :, 0, 0],
        "next_obs": memory.stacks((index + 1) % memory.capacity)[:, :, 0, 0],
        "actions": memory.actions[index],
        "lengths": memory.lengths[index],
        "terminated": memory.terminated[index],
    }


# -- hand-worked streams -----------------------------------------------------------------------


def test_frame_memory_rebuilds_stacks_and_pads_them_with_the_first_frame_of_the_episode():
    memory = FrameReplayMemory(16, (4, 1, 1), np.uint8, frame_stack=4)
    assert memory.frames.shape == (16, 1, 1)  # one frame per slot, not a stack
    memory.start_episode(_stack(1, 1, 1, 1))
    memory.add(0, 1, False, _stack(1, 1, 1, 2))
    memory.add(1, 3, False, _stack(2, 3, 4, 5))  # a routine of 3 steps: frames 3, 4, 5
    memory.add(2, 1, True, _stack(3, 4, 5, 6))  # the final observation of episode 1
    memory.start_episode(_stack(9, 9, 9, 9))
    memory.add(3, 2, False, _stack(9, 9, 10, 11))  # padded with the reset frame 9
    assert len(memory) == 4
    t = _all_transitions(memory)
    assert t["index"].tolist() == [0, 1, 2, 4]  # the final observation starts nothing
    assert t["obs"].tolist() == [[1, 1, 1, 1], [1, 1, 1, 2], [2, 3, 4, 5], [9, 9, 9, 9]]
    assert t["next_obs"].tolist() == [[1, 1, 1, 2], [2, 3, 4, 5], [3, 4, 5, 6], [9, 9, 10, 11]]
    assert t["actions"].tolist() == [0, 1, 2, 3]
    assert t["lengths"].tolist() == [1, 3, 1, 2]
    assert t["terminated"].tolist() == [False, False, True, False]


def test_stacks_after_a_routine_of_two_steps_hold_the_frame_from_inside_it():
    memory = FrameReplayMemory(16, (4, 1, 1), np.uint8, frame_stack=4)
    memory.start_episode(_stack(1, 1, 1, 1))
    memory.add(0, 1, False, _stack(1, 1, 1, 2))
    memory.add(6, 2, False, _stack(1, 2, 3, 4))  # frame 3 was seen inside the routine only
    for t in (5, 6, 7):
        memory.add(0, 1, False, _stack(t - 3, t - 2, t - 1, t))
    assert memory.frames[: memory.num_frames, 0, 0].tolist() == [1, 2, 3, 4, 5, 6, 7]
    # One frame per decision would rebuild entries 2, 3, 4 as [1,1,2,4], [1,2,4,5], [2,4,5,6].
    assert memory.stacks(np.arange(6))[:, :, 0, 0].tolist() == [
        [1, 1, 1, 1], [1, 1, 1, 2], [1, 2, 3, 4], [2, 3, 4, 5], [3, 4, 5, 6], [4, 5, 6, 7],
    ]
    assert len(memory) == 5


def test_routines_of_four_steps_or_more_keep_only_the_last_four_frames():
    memory = FrameReplayMemory(16, (4, 1, 1), np.uint8, frame_stack=4)
    memory.start_episode(_stack(0, 0, 0, 0))
    memory.add(6, 4, False, _stack(1, 2, 3, 4))  # 4 steps from the reset: no padding left
    memory.add(7, 5, False, _stack(6, 7, 8, 9))  # frame 5 is in no stack: it is not kept
    memory.add(0, 1, False, _stack(7, 8, 9, 10))
    memory.add(7, 2, True, _stack(9, 10, 11, 12))  # a routine of 5 cut short after 2 steps
    assert memory.num_frames == 1 + 4 + 4 + 1 + 2
    assert memory.frames[: memory.num_frames, 0, 0].tolist() == [0, 1, 2, 3, 4, 6, 7, 8, 9, 10,
                                                                 11, 12]
    t = _all_transitions(memory)
    assert t["obs"].tolist() == [[0, 0, 0, 0], [1, 2, 3, 4], [6, 7, 8, 9], [7, 8, 9, 10]]
    assert t["next_obs"].tolist() == [[1, 2, 3, 4], [6, 7, 8, 9], [7, 8, 9, 10], [9, 10, 11, 12]]
    assert t["lengths"].tolist() == [4, 5, 1, 2]


def test_both_rings_wrap_and_entries_whose_frames_were_overwritten_are_not_sampled():
    # 6 slots of frames and 6 of decisions, stacks of 2; frame values name the env's frames.
    memory = FrameReplayMemory(6, (2, 1, 1), np.uint8, frame_stack=2)
    memory.start_episode(_stack(0, 0))  # entry 0, frame number 0
    memory.add(0, 1, False, _stack(0, 1))  # entry 1, frame 1
    memory.add(1, 3, False, _stack(3, 4))  # entry 2, frames 2-3 (values 3, 4)
    memory.add(2, 1, False, _stack(4, 5))  # entry 3, frame 4
    memory.add(3, 2, True, _stack(6, 7))  # entry 4 (final), frames 5-6: frame 6 overwrites 0
    # Entries 0 and 1 need frame value 0, now gone; entry 2 needs values 3, 4, still there.
    assert _all_transitions(memory)["index"].tolist() == [2, 3]
    assert len(memory) == 2
    memory.start_episode(_stack(9, 9))  # entry 5, frame 7 (overwrites value 3)
    memory.add(4, 1, False, _stack(9, 10))  # entry 6 in slot 0, frame 8 (overwrites value 4)
    assert memory.full and memory.pos == 1 and memory.num_frames == 9
    assert memory.frames[:, 0, 0].tolist() == [7, 9, 10, 4, 5, 6]
    t = _all_transitions(memory)
    assert t["index"].tolist() == [3, 5] and len(memory) == 2  # entries 3 and 5
    assert t["obs"].tolist() == [[4, 5], [9, 9]]
    assert t["next_obs"].tolist() == [[6, 7], [9, 10]]
    assert t["actions"].tolist() == [3, 4] and t["lengths"].tolist() == [2, 1]
    assert memory.stacks(np.array([0]))[0, :, 0, 0].tolist() == [9, 10]  # the newest entry
    batch = memory.sample(100, np.random.default_rng(0))
    pairs = {(tuple(o), tuple(n)) for o, n in zip(batch["obs"][:, :, 0, 0].tolist(),
                                                  batch["next_obs"][:, :, 0, 0].tolist(),
                                                  strict=True)}
    assert pairs == {((4, 5), (6, 7)), ((9, 9), (9, 10))}


def test_capacity_counts_frames_so_long_routines_keep_fewer_decisions():
    def fill(length: int, decisions: int) -> FrameReplayMemory:
        memory = FrameReplayMemory(12, (4, 1, 1), np.uint8, frame_stack=4)
        memory.start_episode(_stack(0, 0, 0, 0))
        for t in range(length, length * decisions + 1, length):
            memory.add(0, length, False, _stack(*(max(v, 0) for v in range(t - 3, t + 1))))
        return memory

    # 1 + 40 frames either way. Primitive steps: the last 12 frames are the last 12 entries; the
    # newest has no next and the 3 oldest lack history: 8 transitions.
    primitive = fill(1, 40)
    assert primitive.num_frames == 41 and len(primitive) == 8
    # Routines of 5 steps keep 4 frames each: the last 12 frames are entries 8, 9, 10, and 8 and
    # 9 lead on: 2 transitions.
    routines = fill(5, 10)
    assert routines.num_frames == 41 and len(routines) == 2
    assert _all_transitions(routines)["obs"].tolist() == [[37, 38, 39, 40], [42, 43, 44, 45]]


def test_frame_memory_never_samples_stacks_reaching_into_overwritten_slots():
    memory = FrameReplayMemory(7, (4, 1, 1), np.uint8, frame_stack=4)
    memory.start_episode(_stack(0, 0, 0, 0))
    for t in range(1, 20):  # one long episode whose frame t is t
        window = [max(t - j, 0) for j in (3, 2, 1, 0)]
        memory.add(t % 5, 1, False, _stack(*window))
    assert memory.full and len(memory) == 3  # 7 slots: newest has no next, 3 oldest lack history
    batch = memory.sample(200, np.random.default_rng(0))
    newest = batch["obs"][:, -1, 0, 0].astype(int)
    assert set(newest.tolist()) == {16, 17, 18}  # frames 13..19 are kept
    for obs, next_obs, last in zip(batch["obs"][:, :, 0, 0], batch["next_obs"][:, :, 0, 0],
                                   newest, strict=True):
        assert obs.tolist() == [last - 3, last - 2, last - 1, last]
        assert next_obs.tolist() == [last - 2, last - 1, last, last + 1]
    assert (batch["actions"] == (newest + 1) % 5).all()


def test_frame_memory_without_stacking_stores_whole_observations():
    memory = FrameReplayMemory(8, (3,), np.float32)
    memory.start_episode(np.zeros(3))
    memory.add(1, 1, False, np.ones(3))
    memory.add(2, 4, False, np.full(3, 2.0))  # a routine is one observation too
    batch = memory.sample(4, np.random.default_rng(0))
    assert memory.num_frames == 3 and len(memory) == 2
    assert {(o[0], n[0]) for o, n in zip(batch["obs"], batch["next_obs"], strict=True)} <= {
        (0.0, 1.0), (1.0, 2.0)}


def test_frame_memory_rejects_misuse():
    memory = FrameReplayMemory(8, (4, 1, 1), np.uint8, frame_stack=4)
    with pytest.raises(RuntimeError, match="start_episode"):
        memory.add(0, 1, False, _stack(1, 1, 1, 1))
    with pytest.raises(ValueError, match="no transition"):
        memory.sample(1, np.random.default_rng(0))
    with pytest.raises(ValueError, match="one repeated frame"):
        memory.start_episode(_stack(1, 2, 3, 4))
    with pytest.raises(ValueError, match="shape"):
        memory.start_episode(_stack(1, 1))
    memory.start_episode(_stack(1, 1, 1, 1))
    with pytest.raises(ValueError, match="length needs to be ≥ 1, actual value: 0"):
        memory.add(0, 0, False, _stack(1, 1, 1, 2))
    with pytest.raises(ValueError, match="shape"):
        memory.add(0, 1, False, _stack(1, 2))
    with pytest.raises(ValueError, match="frame_stack=4"):
        FrameReplayMemory(8, (84, 84), np.uint8, frame_stack=4)
    with pytest.raises(ValueError, match="capacity"):
        FrameReplayMemory(3, (4, 1, 1), np.uint8, frame_stack=4)


def test_the_docstring_examples_run():
    import doctest

    import routine_gym.replay_memory

    result = doctest.testmod(routine_gym.replay_memory)
    assert result.attempted > 0 and result.failed == 0


# -- streams from real envs --------------------------------------------------------------------


class _Counter(gym.Env):
    """Frames count the steps; episodes of 2–5 steps end by termination or truncation."""

    observation_space = gym.spaces.Box(0, 255, (2, 3), np.uint8)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t, self.horizon = 0, int(self.np_random.integers(2, 6))
        self.base = int(self.np_random.integers(0, 200))
        return self._obs(), {}

    def _obs(self):
        return np.full((2, 3), self.base + self.t, dtype=np.uint8)

    def step(self, action):
        self.t += 1
        done = self.t == self.horizon
        return self._obs(), 0.0, done and action == 0, done and action == 1, {}


def _play(env: gym.Env, memories: list[FrameReplayMemory], decisions: int, seed: int,
          routine_share: float) -> tuple[list[np.ndarray], list[tuple[int, int, bool]]]:
    """Random decisions (primitives, and routines with probability `routine_share`), each
    observation added to every memory; returns the env's observation of every entry and the
    (action, executed length, terminated) of the decision taken there (None at final ones)."""
    num_primitives = getattr(env, "num_primitive_actions", int(env.action_space.n))
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    for memory in memories:
        memory.start_episode(obs)
    seen, decided = [obs], []
    for _ in range(decisions):
        if rng.random() < routine_share:
            action = int(rng.integers(num_primitives, env.action_space.n))
        else:
            action = int(rng.integers(num_primitives))
        next_obs, _, terminated, truncated, info = env.step(action)
        length = int(info.get("routine_length", 1))
        for memory in memories:
            memory.add(action, length, terminated, next_obs)
        decided.append((action, length, terminated))
        seen.append(next_obs)
        if terminated or truncated:
            obs, _ = env.reset()
            for memory in memories:
                memory.start_episode(obs)
            decided.append(None)
            seen.append(obs)
    decided.append(None)  # the newest entry
    return seen, decided


def _assert_memory_holds_what_the_env_returned(memory: FrameReplayMemory, seen, decided):
    """Every entry still in `memory` that `_valid` lets start a transition is the env's, and so
    is everything `sample` returns."""
    first = max(0, len(seen) - memory.capacity)
    env_transitions = set()
    checked = 0
    for d in range(first, len(seen)):
        slot = d % memory.capacity
        if decided[d] is None:
            assert not memory._valid(np.array([slot]))[0]
            continue
        env_transitions.add((seen[d].tobytes(), *decided[d], seen[d + 1].tobytes()))
        if memory._valid(np.array([slot]))[0]:
            obs, next_obs = memory.stacks(np.array([slot, (slot + 1) % memory.capacity]))
            np.testing.assert_array_equal(obs, seen[d])
            np.testing.assert_array_equal(next_obs, seen[d + 1])
            checked += 1
    assert checked == len(memory) > 0
    batch = memory.sample(256, np.random.default_rng(1))
    for i in range(256):
        key = (batch["obs"][i].tobytes(), int(batch["actions"][i]), int(batch["lengths"][i]),
               bool(batch["terminated"][i]), batch["next_obs"][i].tobytes())
        assert key in env_transitions
    return batch


def test_frame_memory_reproduces_frame_stack_observation_exactly():
    env = gym.wrappers.FrameStackObservation(_Counter(), 4)
    memory = FrameReplayMemory(10_000, (4, 2, 3), np.uint8, frame_stack=4)
    seen, decided = _play(env, [memory], 300, seed=0, routine_share=0.0)
    for d, obs in enumerate(seen):
        np.testing.assert_array_equal(memory.stacks(np.array([d]))[0], obs)
    _assert_memory_holds_what_the_env_returned(memory, seen, decided)


def test_frame_memory_reproduces_frame_stacks_under_routines_cut_short_by_episode_ends():
    routines = [[0, 1], [1, 1, 0], [1, 0, 1, 1, 0, 1]]  # lengths 2, 3 and 6 > 4
    env = RoutineActionWrapper(gym.wrappers.FrameStackObservation(_Counter(), 4), routines)
    large = FrameReplayMemory(10_000, (4, 2, 3), np.uint8, frame_stack=4)
    small = FrameReplayMemory(23, (4, 2, 3), np.uint8, frame_stack=4)  # wraps many times
    seen, decided = _play(env, [large, small], 400, seed=1, routine_share=0.6)
    lengths = {d[1] for d in decided if d is not None}
    assert {1, 2, 3, 4, 5} <= lengths  # the routine of 6 is always cut short (episodes ≤ 5)
    for d, obs in enumerate(seen):
        np.testing.assert_array_equal(large.stacks(np.array([d]))[0], obs)
    _assert_memory_holds_what_the_env_returned(large, seen, decided)
    _assert_memory_holds_what_the_env_returned(small, seen, decided)


def test_frame_memory_reproduces_a_qbert_training_env_with_routines():
    """The acceptance test of issue 9 item 4: the agent's env of RAPL-SQIL on Qbert (frame
    stack under the routine wrapper, a life loss ending the episode)."""
    env = make_env("ALE/Qbert-v5", 5, 0, routines=[[3, 3, 2], [5, 4, 5, 4, 0]], training=True)()
    shape = env.observation_space.shape
    assert shape == (4, 84, 84)
    large = FrameReplayMemory(10_000, shape, np.uint8, frame_stack=4)
    small = FrameReplayMemory(97, shape, np.uint8, frame_stack=4)  # both rings wrap
    seen, decided = _play(env, [large, small], 200, seed=5, routine_share=0.5)
    assert decided.count(None) >= 3  # episodes end (lives lost) along the way
    assert {1, 3, 5} <= {d[1] for d in decided if d is not None}
    for d, obs in enumerate(seen):
        assert np.array_equal(large.stacks(np.array([d]))[0], obs), f"entry {d}"
    batch = _assert_memory_holds_what_the_env_returned(large, seen, decided)
    assert {1, 3, 5} <= set(batch["lengths"].tolist())
    _assert_memory_holds_what_the_env_returned(small, seen, decided)
    env.close()
