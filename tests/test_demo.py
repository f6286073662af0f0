"""Demonstrations: the file format, DemoRecorder, loading errors, replay, agent and human demos."""

from __future__ import annotations

import io
import json
import os
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

import routine_gym  # noqa: F401  (registers the ALE envs)
from routine_gym.demo import (
    DEMO_FORMAT,
    Demo,
    DemoRecorder,
    DemoReplayError,
    record_agent_demo,
    record_human_demo,
    replay,
)

# -- a tiny env whose scores are worked out by hand ------------------------------------------


class CountdownEnv(gym.Env):
    """Episodes of exactly `length` steps; every step pays `seed % 3`, whatever the action."""

    metadata = {"render_modes": []}

    def __init__(self, length: int = 3, tag: tuple = ("a", 1)):
        self.action_space = gym.spaces.Discrete(3)
        self.observation_space = gym.spaces.Box(0, 1000, (1,), np.float32)
        self.length = length
        self.tag = tag

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self._pay = float((seed or 0) % 3)
        self._t = 0
        return np.array([0.0], np.float32), {}

    def step(self, action):
        self._t += 1
        obs = np.array([self._t], np.float32)
        return obs, self._pay, self._t >= self.length, False, {}

    def get_action_meanings(self):
        return ["NOOP", "LEFT", "RIGHT"]


COUNTDOWN = "RoutineGymTest/Countdown-v0"
if COUNTDOWN not in gym.envs.registration.registry:
    gym.register(id=COUNTDOWN, entry_point=CountdownEnv)


def play_episodes(recorder: gym.Env, seeds, policy_seed: int = 0) -> None:
    """Play one random-policy episode per seed through `recorder`."""
    rng = np.random.default_rng(policy_seed)
    for seed in seeds:
        recorder.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = recorder.step(int(rng.integers(2)))
            done = terminated or truncated


@pytest.fixture
def cartpole_demo() -> Demo:
    """Three CartPole episodes (seeds 0, 1, 2) with observations."""
    recorder = DemoRecorder(gym.make("CartPole-v1"), record_observations=True, source="random")
    play_episodes(recorder, [0, 1, 2])
    return recorder.demo()


def write_npz(path, arrays: dict) -> None:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    with open(path, "wb") as f:
        f.write(buffer.getvalue())


def demo_arrays(demo: Demo, **meta_changes) -> dict:
    """The arrays `Demo.save` writes, with `meta` entries changed."""
    meta = {**demo.meta, **meta_changes}
    return {
        "actions": demo.actions,
        "rewards": demo.rewards,
        "terminated": demo.terminated,
        "truncated": demo.truncated,
        "decisions": demo.decisions,
        "episode_lengths": demo.episode_lengths,
        "meta": np.array(json.dumps(meta)),
    }


# -- the Demo container ---------------------------------------------------------------------


def test_demo_slices_episodes_and_scores_them_by_hand():
    demo = Demo(
        actions=np.array([1, 1, 0, 2, 2, 0]),
        rewards=np.array([0.0, 1.0, 0.0, 0.0, 5.0, 2.0]),
        terminated=np.array([0, 0, 1, 0, 0, 1], dtype=bool),
        truncated=np.array([0, 0, 0, 0, 1, 0], dtype=bool),
        episode_lengths=np.array([3, 2, 1]),
        meta={"seeds": [10, 11, 12], "num_actions": 3},
    )
    assert len(demo) == 6 and demo.num_episodes == 3
    assert demo.scores.tolist() == [1.0, 5.0, 2.0]
    assert demo.meta["scores"] == [1.0, 5.0, 2.0]
    assert demo.score == 5.0 and demo.best_episode == 1
    assert [a.tolist() for a in demo.episode_actions()] == [[1, 1, 0], [2, 2], [0]]
    second = demo.episode(1)
    assert second.actions.tolist() == [2, 2] and second.seed == 11 and second.score == 5.0
    assert second.truncated.tolist() == [False, True]
    assert demo.episode(-1).actions.tolist() == [0]
    picked = demo.select([2, 0])
    assert picked.seeds == (12, 10)
    assert picked.actions.tolist() == [0, 1, 1, 0]
    assert picked.scores.tolist() == [2.0, 1.0]
    assert demo.best().seeds == (11,) and demo.best().score == 5.0
    assert demo.action_meanings == ("0", "1", "2")
    with pytest.raises(IndexError, match="episode 3 out of range"):
        demo.episode(3)


def test_best_episode_takes_the_first_of_equal_scores():
    demo = Demo(
        actions=np.zeros(4, dtype=np.int64),
        rewards=np.array([2.0, 1.0, 1.0, 2.0]),
        terminated=np.array([0, 1, 0, 1], dtype=bool),
        truncated=np.zeros(4, dtype=bool),
        episode_lengths=np.array([2, 2]),
    )
    assert demo.scores.tolist() == [3.0, 3.0]
    assert demo.best_episode == 0


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"episode_lengths": np.array([2, 2])}, "sum to 4 but there are 3 actions"),
        ({"episode_lengths": np.array([3, 0])}, "at least one step"),
        ({"episode_lengths": np.array([], dtype=np.int64)}, "at least one episode"),
        ({"rewards": np.zeros(2)}, r"rewards has shape \(2,\), expected \(3,\)"),
        ({"actions": np.array([0.0, 1.0, 1.0])}, "integer action ids"),
        ({"actions": np.array([0, -1, 1])}, "actions must be ≥ 0, got -1"),
        ({"actions": np.array([0, 2, 1])}, r"action 2 .* Discrete\(2\)"),
        ({"terminated": np.array([1, 0, 1], dtype=bool)}, "step 0 .* not the last step"),
        ({"observations": np.zeros((3, 4))}, "stored together"),
        (
            {"observations": np.zeros((2, 4)), "final_observations": np.zeros((1, 4))},
            "observations has shape",
        ),
        ({"meta": {"num_actions": 2, "seeds": [1, 2]}}, "2 seeds for 1 episodes"),
        ({"meta": {"num_actions": 2, "action_meanings": ["A"]}}, "1 action meanings for 2"),
        ({"meta": {"num_actions": 2, "note": object()}}, "JSON-serialisable"),
    ],
)
def test_demo_rejects_inconsistent_arrays(change, message):
    fields = {
        "actions": np.array([0, 1, 1]),
        "rewards": np.ones(3),
        "terminated": np.array([0, 0, 1], dtype=bool),
        "truncated": np.zeros(3, dtype=bool),
        "episode_lengths": np.array([3]),
        "meta": {"num_actions": 2},
    }
    fields.update(change)
    with pytest.raises(ValueError, match=message):
        Demo(**fields)


# -- saving and loading ---------------------------------------------------------------------


def test_round_trip_keeps_every_field(cartpole_demo, tmp_path):
    path = tmp_path / "cartpole.npz"
    cartpole_demo.save(path)
    loaded = Demo.load(path, env_id="CartPole-v1")
    for name in ("actions", "rewards", "terminated", "truncated", "episode_lengths"):
        original, back = getattr(cartpole_demo, name), getattr(loaded, name)
        assert back.dtype == original.dtype, name
        np.testing.assert_array_equal(back, original, err_msg=name)
    assert loaded.observations.dtype == np.float32
    np.testing.assert_array_equal(loaded.observations, cartpole_demo.observations)
    np.testing.assert_array_equal(loaded.final_observations, cartpole_demo.final_observations)
    assert loaded.meta == cartpole_demo.meta
    meta = loaded.meta
    assert meta["format"] == DEMO_FORMAT and meta["version"] == 2
    assert meta["env_id"] == "CartPole-v1" and meta["max_episode_steps"] == 500
    assert meta["seeds"] == [0, 1, 2] and meta["num_actions"] == 2
    assert meta["source"] == "random" and meta["routine_gym_version"]
    assert loaded.num_episodes == 3
    assert loaded.observations.shape == (len(loaded), 4)
    assert loaded.final_observations.shape == (3, 4)


def test_observations_are_the_ones_before_each_action_and_after_the_last(cartpole_demo):
    env = gym.make("CartPole-v1")
    first = cartpole_demo.episode(0)
    obs, _ = env.reset(seed=0)
    np.testing.assert_array_equal(first.observations[0], obs)
    for action in first.actions:
        obs, *_ = env.step(int(action))
    np.testing.assert_array_equal(first.final_observation, obs)


def test_tuples_in_meta_come_back_as_tuples(tmp_path):
    recorder = DemoRecorder(gym.make(COUNTDOWN, tag=("b", 2)), record_observations=False)
    play_episodes(recorder, [4])
    recorder.save(tmp_path / "d.npz", meta={"note": ("x", 3)})
    loaded = Demo.load(tmp_path / "d.npz")
    assert loaded.env_kwargs == {"tag": ("b", 2)}
    assert loaded.meta["note"] == ("x", 3)
    assert replay(loaded).scores.tolist() == [3.0]  # seed 4: 3 steps paying 4 % 3 = 1


def test_saved_file_holds_no_pickles(cartpole_demo, tmp_path):
    path = tmp_path / "d.npz"
    cartpole_demo.save(path)
    with np.load(path, allow_pickle=False) as data:
        assert set(data.files) == {
            "actions", "rewards", "terminated", "truncated", "decisions", "episode_lengths",
            "observations", "final_observations", "meta",
        }
        arrays = {name: data[name] for name in data.files}
    assert all(not a.dtype.hasobject for a in arrays.values())
    assert arrays["meta"].shape == () and arrays["meta"].dtype.kind == "U"
    with zipfile.ZipFile(path) as archive:
        for member in archive.namelist():
            with archive.open(member) as f:
                major, _ = np.lib.format.read_magic(f)
                read_header = (
                    np.lib.format.read_array_header_1_0 if major == 1
                    else np.lib.format.read_array_header_2_0
                )
                _, _, dtype = read_header(f)
                assert not dtype.hasobject, member


def test_save_without_observations_drops_them_and_still_replays(cartpole_demo, tmp_path):
    path = tmp_path / "light.npz"
    cartpole_demo.save(path, include_observations=False)
    with np.load(path, allow_pickle=False) as data:
        assert "observations" not in data.files and "final_observations" not in data.files
    light = Demo.load(path)
    assert not light.has_observations
    result = replay(light, record_observations=True)
    assert result.matched
    np.testing.assert_array_equal(result.demo.observations, cartpole_demo.observations)
    np.testing.assert_array_equal(
        result.demo.final_observations, cartpole_demo.final_observations
    )


def test_failed_save_leaves_the_previous_file_intact(cartpole_demo, tmp_path, monkeypatch):
    path = tmp_path / "demo.npz"
    cartpole_demo.select([0]).save(path)
    before = path.read_bytes()

    def disk_full(src, dst):
        raise OSError("No space left on device")

    monkeypatch.setattr(os, "replace", disk_full)
    with pytest.raises(OSError, match="No space left"):
        cartpole_demo.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["demo.npz"]  # no temporary file left behind
    assert Demo.load(path).num_episodes == 1


# -- every bad input to load -----------------------------------------------------------------


def test_load_missing_file_names_it(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        Demo.load(tmp_path / "nope.npz")


def test_load_rejects_a_directory(tmp_path):
    with pytest.raises(ValueError, match="not a file"):
        Demo.load(tmp_path)


def test_load_rejects_a_file_that_is_not_a_zip(tmp_path):
    path = tmp_path / "notes.npz"
    path.write_text("hello")
    with pytest.raises(ValueError, match=r"notes\.npz: not a routine-gym demo: not an \.npz"):
        Demo.load(path)


def test_load_rejects_a_truncated_file(cartpole_demo, tmp_path):
    path = tmp_path / "cut.npz"
    cartpole_demo.save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.npz: .*truncated or corrupt"):
        Demo.load(path)


def test_load_rejects_corrupted_compressed_data(cartpole_demo, tmp_path):
    path = tmp_path / "flipped.npz"
    cartpole_demo.save(path)
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("observations.npy")
    data = bytearray(path.read_bytes())
    # the middle of the observations member's compressed bytes; the central directory survives
    middle = info.header_offset + 100 + info.compress_size // 2
    data[middle : middle + 16] = bytes(255 - b for b in data[middle : middle + 16])
    path.write_bytes(bytes(data))
    assert zipfile.is_zipfile(path)
    with pytest.raises(ValueError, match=r"flipped\.npz: corrupt demo file"):
        Demo.load(path)


def test_load_rejects_missing_arrays(cartpole_demo, tmp_path):
    arrays = demo_arrays(cartpole_demo)
    del arrays["rewards"], arrays["truncated"]
    write_npz(tmp_path / "d.npz", arrays)
    with pytest.raises(ValueError, match=r"missing arrays \['rewards', 'truncated'\]"):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_an_npz_without_meta(tmp_path):
    write_npz(tmp_path / "d.npz", {"x": np.zeros(3)})
    with pytest.raises(ValueError, match=r"no 'meta' array \(arrays: \['x'\]\)"):
        Demo.load(tmp_path / "d.npz")


def test_load_never_unpickles_object_arrays(cartpole_demo, tmp_path):
    arrays = demo_arrays(cartpole_demo)
    arrays["actions"] = np.array([{"evil": 1}] * len(cartpole_demo), dtype=object)
    write_npz(tmp_path / "d.npz", arrays)
    with pytest.raises(ValueError, match="'actions' holds pickled Python objects"):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_another_format(cartpole_demo, tmp_path):
    write_npz(tmp_path / "d.npz", demo_arrays(cartpole_demo, format="someone-else/demo"))
    with pytest.raises(ValueError, match="format is 'someone-else/demo'"):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_an_unknown_version(cartpole_demo, tmp_path):
    write_npz(tmp_path / "d.npz", demo_arrays(cartpole_demo, version=7))
    with pytest.raises(
        ValueError, match="version 7 is not supported; this routine-gym reads versions 1, 2"
    ):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_meta_that_is_not_json(cartpole_demo, tmp_path):
    arrays = demo_arrays(cartpole_demo)
    arrays["meta"] = np.array("{not json")
    write_npz(tmp_path / "d.npz", arrays)
    with pytest.raises(ValueError, match="'meta' is not valid JSON"):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_inconsistent_lengths(cartpole_demo, tmp_path):
    arrays = demo_arrays(cartpole_demo)
    arrays["episode_lengths"] = cartpole_demo.episode_lengths + 1
    write_npz(tmp_path / "d.npz", arrays)
    total = int(cartpole_demo.episode_lengths.sum())
    with pytest.raises(
        ValueError, match=f"d.npz: episode_lengths sum to {total + 3} but there are {total}"
    ):
        Demo.load(tmp_path / "d.npz")


@pytest.mark.parametrize(("bad", "message"), [(2, r"action 2 .* Discrete\(2\)"), (-1, "≥ 0")])
def test_load_rejects_actions_outside_the_action_space(cartpole_demo, tmp_path, bad, message):
    arrays = demo_arrays(cartpole_demo)
    arrays["actions"] = cartpole_demo.actions.copy()
    arrays["actions"][4] = bad
    write_npz(tmp_path / "d.npz", arrays)
    with pytest.raises(ValueError, match=message):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_scores_that_disagree_with_rewards(cartpole_demo, tmp_path):
    arrays = demo_arrays(cartpole_demo)
    arrays["rewards"] = cartpole_demo.rewards * 2
    write_npz(tmp_path / "d.npz", arrays)
    with pytest.raises(ValueError, match="meta scores .* disagree with the rewards"):
        Demo.load(tmp_path / "d.npz")


def test_load_rejects_a_demo_of_another_env(cartpole_demo, tmp_path):
    write_npz(tmp_path / "pong.npz", demo_arrays(cartpole_demo, env_id="ALE/Pong-v5"))
    with pytest.raises(ValueError, match="demo was recorded on ALE/Pong-v5, not ALE/Qbert-v5"):
        Demo.load(tmp_path / "pong.npz", env_id="ALE/Qbert-v5")
    cartpole_demo.save(tmp_path / "cartpole.npz")
    with pytest.raises(ValueError, match=r"demo has 2 actions, the env has Discrete\(3\)"):
        Demo.load(tmp_path / "cartpole.npz", env=CountdownEnv())
    assert Demo.load(tmp_path / "cartpole.npz", env=gym.make("CartPole-v1")).num_episodes == 3


# -- DemoRecorder ---------------------------------------------------------------------------


def test_recorder_records_the_env_spec_and_action_meanings():
    recorder = DemoRecorder(gym.make(COUNTDOWN, length=2), record_observations=False)
    play_episodes(recorder, [5, 6])
    demo = recorder.demo()
    assert demo.env_id == COUNTDOWN
    assert demo.env_kwargs["length"] == 2
    assert demo.action_meanings == ("NOOP", "LEFT", "RIGHT")
    assert demo.seeds == (5, 6)
    assert demo.scores.tolist() == [4.0, 0.0]  # 2 steps paying 5 % 3 = 2, then 6 % 3 = 0
    assert demo.observations is None
    assert recorder.demo(episodes=1).seeds == (6,)


def test_unseeded_reset_gets_a_seed_that_replays():
    recorder = DemoRecorder(gym.make("CartPole-v1"), record_observations=True)
    recorder.reset()
    recorder.step(0)
    while not recorder._current.finished:
        recorder.step(0)
    demo = recorder.demo()
    assert isinstance(demo.seeds[0], int)
    assert replay(demo).matched


def test_unseeded_resets_count_up_from_the_recorder_seed():
    recorder = DemoRecorder(gym.make(COUNTDOWN), record_observations=False, seed=40)
    for _ in range(2):
        recorder.reset()
        recorder.reset()  # an abandoned empty episode takes no seed number
        for _ in range(3):
            recorder.step(0)
    assert recorder.demo().seeds == (40, 41)


def test_recorder_drops_an_abandoned_episode_and_can_keep_the_current_one():
    recorder = DemoRecorder(gym.make(COUNTDOWN, length=5), record_observations=True)
    recorder.reset(seed=1)
    recorder.step(2)
    recorder.reset(seed=2)  # abandons the first episode after one step
    recorder.step(1)
    recorder.step(1)
    with pytest.raises(ValueError, match="no completed episode"):
        recorder.demo()
    demo = recorder.demo(include_unfinished=True)
    assert demo.seeds == (2,) and demo.actions.tolist() == [1, 1]
    assert not demo.terminated.any() and not demo.truncated.any()
    assert demo.final_observations.tolist() == [[2.0]]
    assert replay(demo).lengths.tolist() == [2]


def test_recorder_rejects_misuse():
    with pytest.raises(TypeError, match="discrete actions"):
        DemoRecorder(gym.make("MountainCarContinuous-v0"))
    recorder = DemoRecorder(gym.make(COUNTDOWN, length=1))
    with pytest.raises(RuntimeError, match="before reset"):
        recorder.step(0)
    recorder.reset(seed=0)
    with pytest.raises(ValueError, match=r"action 3 is outside the action space Discrete\(3\)"):
        recorder.step(3)
    with pytest.raises(TypeError, match="single integer"):
        recorder.step(1.5)
    recorder.step(np.int64(1))
    with pytest.raises(RuntimeError, match="after the episode ended"):
        recorder.step(0)


def test_recorder_needs_array_observations_to_record_them():
    dict_space = gym.spaces.Dict({"o": CountdownEnv().observation_space})
    env = gym.wrappers.TransformObservation(gym.make(COUNTDOWN), lambda o: {"o": o}, dict_space)
    with pytest.warns(UserWarning, match="behind the wrappers"):
        recorder = DemoRecorder(env)
    with pytest.raises(TypeError, match="record_observations=False"):
        recorder.reset(seed=0)


def test_unserialisable_env_kwargs_are_dropped_with_a_warning():
    with pytest.warns(UserWarning, match="tag=.* not JSON-serialisable"):
        recorder = DemoRecorder(gym.make(COUNTDOWN, length=4, tag=object()))
    play_episodes(recorder, [0])
    assert recorder.demo().env_kwargs == {"length": 4}


def test_env_without_spec_records_but_replays_only_on_a_given_env(tmp_path):
    recorder = DemoRecorder(CartPoleEnv(), record_observations=True)
    play_episodes(recorder, [3])
    recorder.save(tmp_path / "d.npz")
    demo = Demo.load(tmp_path / "d.npz")
    assert demo.env_id is None and demo.meta["max_episode_steps"] is None
    with pytest.raises(ValueError, match=r"no env id .* replay\(demo, env=\.\.\.\)"):
        replay(demo)
    result = replay(demo, env=CartPoleEnv())
    assert result.matched and result.lengths.tolist() == [len(demo)]


# -- replay ---------------------------------------------------------------------------------


def test_replay_reproduces_cartpole_scores_and_lengths(cartpole_demo):
    result = replay(cartpole_demo)
    assert result.matched
    assert result.episodes == (0, 1, 2)
    np.testing.assert_array_equal(result.scores, cartpole_demo.scores)
    np.testing.assert_array_equal(result.lengths, cartpole_demo.episode_lengths)
    assert replay(cartpole_demo, episode=2).lengths.tolist() == [cartpole_demo.episode_lengths[2]]


def test_replay_names_the_episode_and_step_of_a_tampered_reward(cartpole_demo):
    rewards = cartpole_demo.rewards.copy()
    rewards[int(cartpole_demo.episode_offsets[1]) + 5] = 7.0
    tampered = Demo(
        actions=cartpole_demo.actions, rewards=rewards, terminated=cartpole_demo.terminated,
        truncated=cartpole_demo.truncated, episode_lengths=cartpole_demo.episode_lengths,
        meta=cartpole_demo.meta,
    )
    message = "episode 1 .* at step 5 .* reward 1 in replay, 7 in the demo"
    with pytest.raises(DemoReplayError, match=message) as err:
        replay(tampered)
    assert (err.value.episode, err.value.step) == (1, 5)
    report = replay(tampered, check=False)
    assert not report.matched
    assert report.divergences[0] is None and report.divergences[2] is None
    assert "step 5" in report.divergences[1]
    np.testing.assert_array_equal(report.lengths, cartpole_demo.episode_lengths)


def test_replay_detects_a_changed_action_through_the_observations(cartpole_demo):
    actions = cartpole_demo.actions.copy()
    actions[3] = 1 - actions[3]
    tampered = Demo(
        actions=actions, rewards=cartpole_demo.rewards, terminated=cartpole_demo.terminated,
        truncated=cartpole_demo.truncated, episode_lengths=cartpole_demo.episode_lengths,
        observations=cartpole_demo.observations,
        final_observations=cartpole_demo.final_observations, meta=cartpole_demo.meta,
    )
    with pytest.raises(DemoReplayError, match="step 3 .* observation differs") as err:
        replay(tampered)
    assert (err.value.episode, err.value.step) == (0, 3)


def test_replay_detects_a_changed_termination(cartpole_demo):
    terminated = cartpole_demo.terminated.copy()
    terminated[int(cartpole_demo.episode_lengths[0]) - 1] = False  # episode 0 "went on"
    tampered = Demo(
        actions=cartpole_demo.actions, rewards=cartpole_demo.rewards, terminated=terminated,
        truncated=cartpole_demo.truncated, episode_lengths=cartpole_demo.episode_lengths,
        meta=cartpole_demo.meta,
    )
    last = int(cartpole_demo.episode_lengths[0]) - 1
    with pytest.raises(DemoReplayError, match=f"step {last} .* terminated is True in replay"):
        replay(tampered)


def test_replay_refuses_a_demo_without_seeds():
    demo = Demo(
        actions=np.array([0, 1]), rewards=np.zeros(2), terminated=np.array([0, 1], dtype=bool),
        truncated=np.zeros(2, dtype=bool), episode_lengths=np.array([2]),
        meta={"env_id": "CartPole-v1"},
    )
    with pytest.raises(ValueError, match="episode 0 .* no reset seed"):
        replay(demo)


def test_replay_refuses_an_env_of_another_game(cartpole_demo):
    with pytest.raises(ValueError, match="demo was recorded on CartPole-v1, not " + COUNTDOWN):
        replay(cartpole_demo, env=gym.make(COUNTDOWN))


def test_qbert_replays_exactly_from_seed_and_actions_sticky_actions_included():
    rng = np.random.default_rng(1)
    demo = record_agent_demo(
        "ALE/Qbert-v5", lambda obs: rng.integers(6), num_episodes=1, seed=7, max_steps=300,
        record_observations=True, progress=False,
    )
    assert demo.env_kwargs["repeat_action_probability"] == 0.25
    assert demo.meta["max_episode_steps"] == 300
    assert demo.action_meanings == ("NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN")
    result = replay(demo)  # compares all 300 frames too
    assert result.matched
    assert result.scores.tolist() == demo.scores.tolist()
    assert result.lengths.tolist() == demo.episode_lengths.tolist()
    # The same actions from another seed draw other sticky actions: the replay must notice.
    reseeded = Demo(
        actions=demo.actions, rewards=demo.rewards, terminated=demo.terminated,
        truncated=demo.truncated, episode_lengths=demo.episode_lengths,
        observations=demo.observations, final_observations=demo.final_observations,
        meta={**demo.meta, "seeds": [8]},
    )
    with pytest.raises(DemoReplayError, match=r"episode 0 \(seed 8\) diverged"):
        replay(reseeded)


# -- agent demos ----------------------------------------------------------------------------


def test_record_agent_demo_keeps_the_best_of_n(capsys):
    # Seeds 10..13 pay 10 % 3 = 1, 2, 0, 1 per step for 3 steps: scores 3, 6, 0, 3.
    demo = record_agent_demo(COUNTDOWN, lambda obs: 0, num_episodes=4, seed=10)
    assert demo.num_episodes == 1
    assert demo.seeds == (11,) and demo.score == 6.0
    assert demo.meta["candidates"] == {
        "seeds": [10, 11, 12, 13], "scores": [3.0, 6.0, 0.0, 3.0], "lengths": [3, 3, 3, 3],
    }
    assert demo.meta["source"] == "agent"
    err = capsys.readouterr().err
    assert err.count("[record_agent_demo]") == 4
    assert "episode 2/4 seed 11: score 6, 3 steps" in err


def test_record_agent_demo_breaks_ties_by_the_first_episode():
    # Seeds 2..6 score 6, 0, 3, 6, 0: seed 2 and seed 5 tie; the first wins.
    demo = record_agent_demo(COUNTDOWN, lambda obs: 0, num_episodes=5, seed=2, progress=False)
    assert demo.seeds == (2,)


def test_record_agent_demo_keep_all_and_a_policy_that_reads_the_env():
    seen = []

    def policy(obs, env):
        seen.append(env.action_space.n)
        return np.array([2])

    demo = record_agent_demo(
        COUNTDOWN, policy, num_episodes=2, seed=0, keep="all", progress=False,
        env_kwargs={"length": 2},
    )
    assert demo.num_episodes == 2 and demo.seeds == (0, 1)
    assert demo.actions.tolist() == [2, 2, 2, 2]
    assert seen == [3, 3, 3, 3]
    with pytest.raises(ValueError, match='keep must be "best" or "all"'):
        record_agent_demo(COUNTDOWN, policy, keep="worst")
    with pytest.raises(ValueError, match="num_episodes needs to be ≥ 1, actual value: 0"):
        record_agent_demo(COUNTDOWN, policy, num_episodes=0)


class RepeatTwice(gym.Wrapper):
    """Each agent decision is two primitive steps (a stand-in for frame skipping)."""

    def step(self, action):
        total = 0.0
        for _ in range(2):
            obs, reward, terminated, truncated, info = self.env.step(action)
            total += reward
            if terminated or truncated:
                break
        return obs, total, terminated, truncated, info


def test_record_agent_demo_records_primitive_steps_under_the_agents_wrappers():
    decisions = []

    def policy(obs):
        decisions.append(1)
        return 1

    demo = record_agent_demo(
        COUNTDOWN, policy, num_episodes=1, seed=1, env_kwargs={"length": 4},
        wrap_env=RepeatTwice, progress=False,
    )
    assert len(decisions) == 2
    assert demo.actions.tolist() == [1, 1, 1, 1]
    assert replay(demo).matched


def test_record_agent_demo_caps_episodes_with_max_steps_that_replay():
    demo = record_agent_demo(
        "CartPole-v1", lambda obs: int(obs[2] > 0), num_episodes=1, max_steps=25, progress=False
    )
    assert len(demo) == 25 and demo.truncated[-1] and not demo.terminated.any()
    assert replay(demo).matched


# -- human demos (gymnasium.utils.play with scripted key events) ------------------------------


@pytest.fixture
def scripted_keyboard(monkeypatch):
    """Replace pygame's event queue: `script[k]` is the events of play's k-th loop (from 0)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    pygame = pytest.importorskip("pygame")
    script: dict[int, list] = {}
    calls = [0]

    def get_events(*args, **kwargs):
        events = script.get(calls[0], [])
        calls[0] += 1
        return events

    monkeypatch.setattr(pygame.event, "get", get_events)
    return pygame, script


def test_human_demo_records_the_held_key_until_the_episode_ends(scripted_keyboard):
    pygame, script = scripted_keyboard
    script[0] = [pygame.event.Event(pygame.KEYDOWN, key=ord("d"))]  # held from the first step
    demo = record_human_demo(
        "CartPole-v1", keys_to_action={"a": 0, "d": 1}, seed=5, fps=1000
    )
    assert demo.meta["source"] == "human" and demo.seeds == (5,)
    assert demo.num_episodes == 1 and demo.terminated[-1]
    assert set(demo.actions.tolist()) == {1}
    result = replay(demo)
    assert result.matched and result.lengths.tolist() == [len(demo)]


def test_human_demo_keeps_an_episode_cut_short_by_escape(scripted_keyboard):
    pygame, script = scripted_keyboard
    script[0] = [pygame.event.Event(pygame.KEYDOWN, key=ord("w"))]  # UP in ALE's key map
    script[5] = [pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE)]  # after 5 steps
    demo = record_human_demo("ALE/Qbert-v5", seed=2, fps=1000)
    assert demo.actions.tolist() == [2, 2, 2, 2, 2]
    assert not demo.terminated.any() and not demo.truncated.any()
    assert demo.seeds == (2,)
    assert replay(demo).matched


def test_human_demo_needs_a_key_map_for_envs_without_one():
    with pytest.raises(ValueError, match="CartPole-v1 has no default keyboard mapping"):
        record_human_demo("CartPole-v1")


def test_qbert_demo_saves_loads_replays_and_mines(tmp_path):
    """The issue's end-to-end check: an ALE/Qbert-v5 demo through the whole pipeline."""
    from routine_gym.envs.factory import default_env_kwargs
    from routine_gym.mining import SequiturMiner

    rng = np.random.default_rng(3)
    # A jumpy random player: Qbert's four moves, mostly repeated, so routines recur.
    moves = [2, 3, 4, 5]
    demo = record_agent_demo(
        "ALE/Qbert-v5", lambda obs: moves[int(rng.integers(4))] if rng.random() < 0.3 else 3,
        num_episodes=2, seed=11, max_steps=400, env_kwargs=default_env_kwargs("ALE/Qbert-v5"),
        progress=False,
    )
    path = tmp_path / "qbert.npz"
    demo.save(path, include_observations=False)
    loaded = Demo.load(path, env_id="ALE/Qbert-v5")
    assert loaded.actions.tolist() == demo.actions.tolist()
    assert replay(loaded).scores.tolist() == demo.scores.tolist()
    library = SequiturMiner().mine(loaded)
    assert len(library) == 3
    assert library.source["env_id"] == "ALE/Qbert-v5"
    assert "RIGHT" in library.describe()
