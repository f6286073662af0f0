"""The env factory (routine_gym/envs/factory.py) and the Atari wrappers (envs/atari.py).

Atari tests play a few hundred agent steps of Qbert (a full random game is about 300 agent
steps, a fraction of a second); they are marked slow but stay in the default run.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import RecordEpisodeStatistics, TransformReward

import routine_gym  # noqa: F401  (registers MiniQbert, CoinRun and the ALE envs)
from routine_gym.envs import env_family, profile_for
from routine_gym.envs.atari import (
    EpisodicLife,
    FireOnLifeLoss,
    FireReset,
    NoopReset,
    sign_reward,
)
from routine_gym.envs.factory import (
    default_env_kwargs,
    make_env,
    make_primitive_env,
    preprocess,
)
from routine_gym.wrapper import RoutineActionWrapper

QBERT = "ALE/Qbert-v5"
RIGHT = 3  # Qbert: jump down-right; from the top it colours a cube (+25) every jump


def wrappers(env: gym.Env) -> list[type]:
    """The wrapper classes from the outside in."""
    chain = []
    while isinstance(env, gym.Wrapper):
        chain.append(type(env))
        env = env.env
    return chain


def episode_frames(env: gym.Env) -> int:
    return int(env.unwrapped.ale.getEpisodeFrameNumber())


# -- ids and default kwargs ----------------------------------------------------------------


def test_env_id_kinds():
    assert env_family("ALE/Qbert-v5") == env_family("QbertNoFrameskip-v4") == "atari"
    assert env_family("CartPole-v1") == "generic" and env_family("procgen/CoinRun-v0") == "procgen"
    assert profile_for("ALE/Qbert-v5").frame_stack == 4
    assert profile_for("procgen/CoinRun-v0").frame_stack == 1


def test_default_env_kwargs():
    # Atari: the agent step is 4 frames everywhere, grey frames.
    assert default_env_kwargs(QBERT) == {"frameskip": 4, "obs_type": "grayscale"}
    assert default_env_kwargs("QbertNoFrameskip-v4") == {"frameskip": 4, "obs_type": "grayscale"}
    assert default_env_kwargs("CartPole-v1") == {}
    assert default_env_kwargs("procgen/CoinRun-v0") == {}
    assert default_env_kwargs("MiniQbert-v0") == {}


@pytest.mark.slow
def test_primitive_atari_env_skips_four_frames_and_is_grey_with_overrides_allowed():
    env = make_primitive_env("QbertNoFrameskip-v4")
    assert env.spec.kwargs["frameskip"] == 4  # NoFrameskip ids get the same agent step
    assert env.observation_space.shape == (210, 160)
    env.close()
    rgb = make_primitive_env(QBERT, obs_type="rgb")  # a caller's kwargs win over the defaults
    assert rgb.observation_space.shape == (210, 160, 3)
    # preprocess turns an RGB primitive env grey too.
    agent_view = preprocess(rgb, QBERT, training=False)
    assert agent_view.observation_space.shape == (4, 84, 84)
    obs, _ = agent_view.reset(seed=0)
    assert obs.shape == (4, 84, 84) and obs.dtype == np.uint8
    agent_view.close()


# -- the agent's Atari view ----------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("training", [True, False])
def test_atari_observations_are_four_stacked_84x84_uint8_frames(training):
    env = make_env(QBERT, seed=0, training=training)()
    space = env.observation_space
    assert space.shape == (4, 84, 84) and space.dtype == np.uint8
    obs, _ = env.reset(seed=0)
    assert space.contains(obs)
    for _ in range(3):
        obs, *_ = env.step(RIGHT)
        assert space.contains(obs)
    chain = wrappers(env)
    # RecordEpisodeStatistics sits right on the primitive env: the real, unclipped, full game.
    assert chain.index(RecordEpisodeStatistics) > chain.index(NoopReset)
    assert (EpisodicLife in chain) == training
    assert (TransformReward in chain) == training
    assert FireReset in chain  # Qbert has FIRE
    env.close()


@pytest.mark.slow
def test_reward_is_sign_clipped_in_training_only():
    # Same seed, same actions: until the first life is lost the two envs see the same game.
    train = make_env(QBERT, seed=0, training=True)()
    evaluate = make_env(QBERT, seed=0, training=False)()
    obs_t, _ = train.reset(seed=5)
    obs_e, _ = evaluate.reset(seed=5)
    np.testing.assert_array_equal(obs_t, obs_e)
    raw_rewards = []
    for _ in range(300):
        obs_t, r_t, term, trunc, _ = train.step(RIGHT)
        obs_e, r_e, *_ = evaluate.step(RIGHT)
        if term or trunc:  # the training episode ends at the life loss
            break
        np.testing.assert_array_equal(obs_t, obs_e)
        assert r_t == np.sign(r_e)
        raw_rewards.append(r_e)
    else:
        pytest.fail("no life lost in 300 steps of jumping down-right")
    assert 25.0 in raw_rewards  # a cube coloured: +25 raw, +1 in training
    assert sign_reward(25.0) == 1.0 and sign_reward(-3.0) == -1.0 and sign_reward(0.0) == 0.0
    train.close()
    evaluate.close()


@pytest.mark.slow
def test_training_episode_ends_on_life_loss_but_statistics_cover_the_whole_game():
    env = make_env(QBERT, seed=0, training=True)()
    rng = np.random.default_rng(0)
    env.reset(seed=1)
    start_lives = env.unwrapped.ale.lives()
    assert start_lives > 1
    episodes, agent_steps, clipped = 0, 0, 0.0
    for _ in range(5000):
        _, reward, terminated, truncated, info = env.step(int(rng.integers(6)))
        agent_steps += 1
        clipped += reward
        if not (terminated or truncated):
            continue
        episodes += 1
        lives = env.unwrapped.ale.lives()
        if lives > 0:
            # A life lost: the training episode ends, the game (and its statistics) go on.
            assert "episode" not in info
            frames = episode_frames(env)
            env.reset()
            assert episode_frames(env) > frames, "a life-loss reset must not restart the game"
            assert env.unwrapped.ale.lives() == lives
            continue
        # Game over: one statistics record for the whole game, raw score, every primitive step.
        assert episodes == start_lives
        assert info["episode"]["l"] > agent_steps  # plus the no-op/FIRE steps of the resets
        assert info["episode"]["r"] >= clipped > 0  # raw 25s (and more) against clipped 1s
        break
    else:
        pytest.fail("no game over in 5000 random steps")
    # After game over, reset starts a new game.
    env.reset()
    assert env.unwrapped.ale.lives() == start_lives
    assert episode_frames(env) <= 4 * 32  # at most 30 no-ops and a FIRE
    env.close()


@pytest.mark.slow
def test_episodic_life_reset_with_a_seed_always_starts_a_new_game():
    env = EpisodicLife(make_primitive_env(QBERT))
    env.reset(seed=0)
    start_lives = env.unwrapped.ale.lives()
    for _ in range(1000):
        *_, terminated, truncated, _ = env.step(RIGHT)
        if terminated:
            break
    assert env.unwrapped.ale.lives() == start_lives - 1
    env.reset(seed=1)
    assert env.unwrapped.ale.lives() == start_lives
    assert episode_frames(env) == 0
    env.close()


# -- NoopReset, FireReset, EpisodicLife on their own ----------------------------------------


@pytest.mark.slow
def test_noop_reset_takes_between_one_and_noop_max_noops_seeded():
    frames = []
    env = NoopReset(make_primitive_env(QBERT), noop_max=30)
    for seed in range(6):
        env.reset(seed=seed)
        frames.append(episode_frames(env))
    for seed in range(6):
        env.reset(seed=seed)
        assert episode_frames(env) == frames[seed]  # the same seed, the same start
    env.close()
    # Every no-op is one 4-frame agent step: 1..30 of them.
    assert all(f % 4 == 0 and 4 <= f <= 120 for f in frames), frames
    assert len(set(frames)) > 1, f"no variety in the starts: {frames}"
    env = NoopReset(make_primitive_env(QBERT), noop_max=0)
    env.reset(seed=0)
    assert episode_frames(env) == 0
    env.close()


@pytest.mark.slow
def test_fire_reset_presses_fire_once():
    env = FireReset(make_primitive_env(QBERT))
    assert env.fire == 1  # Qbert's minimal set: NOOP, FIRE, UP, RIGHT, LEFT, DOWN
    env.reset(seed=0)
    assert episode_frames(env) == 4
    env.close()


@pytest.mark.slow
def test_fire_reset_refuses_a_game_without_fire_and_preprocess_skips_it():
    freeway = make_primitive_env("ALE/Freeway-v5")  # NOOP, UP, DOWN
    with pytest.raises(ValueError, match="FireReset needs a FIRE action"):
        FireReset(freeway)
    assert FireReset not in wrappers(preprocess(freeway, "ALE/Freeway-v5"))
    freeway.close()


class _ActionLog(gym.Wrapper):
    """Remembers every action that reaches the env it wraps."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.actions: list[int] = []

    def step(self, action):
        self.actions.append(int(action))
        return self.env.step(action)


def play_noops(env: gym.Env, log: _ActionLog, steps: int) -> tuple[bool, list[int]]:
    """NOOP for up to `steps` agent steps; whether the game ended, and lives after each step."""
    env.reset(seed=0)
    log.actions.clear()
    lives = []
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(0)
        lives.append(env.unwrapped.ale.lives())
        if terminated or truncated:
            return True, lives
    return False, lives


@pytest.mark.slow
def test_fire_on_life_loss_serves_each_new_life_as_training_does():
    # Breakout's paddle never moves under NOOP, so the served ball is soon lost; without a new
    # serve (FIRE) the game then waits forever with 4 lives left.
    log = _ActionLog(make_primitive_env("ALE/Breakout-v5"))
    ended, lives = play_noops(FireReset(log), log, 1500)
    assert not ended and lives[-1] == 4 and set(log.actions) == {0}

    env = FireOnLifeLoss(log)
    assert env.fire == 1  # Breakout's minimal set: NOOP, FIRE, RIGHT, LEFT
    ended, lives = play_noops(FireReset(env), log, 1500)
    assert ended and lives[-1] == 0
    # Each of the 4 life losses before the last was followed by a NOOP and a FIRE step.
    assert log.actions.count(1) == 4
    fires = [i for i, a in enumerate(log.actions) if a == 1]
    assert all(log.actions[i - 1] == 0 for i in fires)
    log.close()


def test_preprocess_serves_new_lives_only_outside_training():
    env = make_primitive_env(QBERT)
    assert FireOnLifeLoss in wrappers(preprocess(env, QBERT, training=False))
    assert FireOnLifeLoss not in wrappers(preprocess(env, QBERT, training=True))
    env.close()


class _NamedActions(gym.Env):
    """A tiny env whose action 0 is not NOOP."""

    action_space = gym.spaces.Discrete(2)
    observation_space = gym.spaces.Box(0, 1, (1,), np.float32)

    def get_action_meanings(self):
        return ["LEFT", "RIGHT"]


def test_atari_wrappers_give_clear_errors():
    with pytest.raises(ValueError, match="noop_max needs to be ≥ 0, actual value: -1"):
        NoopReset(make_primitive_env(QBERT), noop_max=-1)
    with pytest.raises(ValueError, match="action 0 to be NOOP"):
        NoopReset(_NamedActions())
    with pytest.raises(ValueError, match="FireReset needs a FIRE action"):
        FireReset(_NamedActions())
    # Not an ALE env at all: a ValueError naming the env, not an AttributeError deep inside.
    cartpole = gym.make("CartPole-v1")
    for wrapper in (NoopReset, FireReset, EpisodicLife, FireOnLifeLoss):
        with pytest.raises(ValueError, match="CartPoleEnv"):
            wrapper(cartpole)
    cartpole.close()


# -- other envs pass through ---------------------------------------------------------------


UP = 2  # MiniQbert: from the top cube, UP jumps off the pyramid and costs a life


def test_miniqbert_trains_like_qbert_a_life_loss_ends_the_training_episode():
    env = make_env("MiniQbert-v0", seed=0, training=True)()
    assert wrappers(env)[:2] == [EpisodicLife, RecordEpisodeStatistics]
    env.reset(seed=0)
    # 3 lives: the first two falls end training episodes, each reset takes one NOOP step ...
    for _ in range(2):
        _, reward, terminated, _, info = env.step(UP)
        assert terminated and reward == 0 and "episode" not in info
        env.reset()
    # ... and the third ends the game, whose statistics count all 3 jumps and 2 NOOPs.
    _, _, terminated, _, info = env.step(UP)
    assert terminated and info["episode"]["l"] == 5 and info["episode"]["r"] == 0
    env.close()

    env = make_env("MiniQbert-v0", seed=0, training=False)()  # evaluation plays the full game
    env.reset(seed=0)
    assert [env.step(UP)[2] for _ in range(3)] == [False, False, True]
    env.close()


@pytest.mark.parametrize("env_id", ["CartPole-v1", "MiniQbert-v0"])
def test_non_atari_envs_pass_through_with_episode_statistics(env_id):
    raw = gym.make(env_id)
    if env_id == "CartPole-v1":
        assert preprocess(raw, env_id) is raw
    assert preprocess(raw, env_id, training=False) is raw
    env = make_env(env_id, seed=0, training=False)()
    assert type(env) is RecordEpisodeStatistics
    assert env.observation_space == raw.observation_space
    env.reset(seed=0)
    for _ in range(600):
        *_, terminated, truncated, info = env.step(0)
        if terminated or truncated:
            break
    assert info["episode"]["l"] >= 1
    env.close()
    raw.close()


@pytest.mark.slow
def test_coinrun_passes_through_with_its_kwargs():
    env = make_env("procgen/CoinRun-v0", seed=0, env_kwargs={"num_levels": 1, "start_level": 7})()
    assert type(env) is RecordEpisodeStatistics
    assert env.observation_space.shape == (64, 64, 3)
    assert env.action_space == gym.spaces.Discrete(5)
    assert env.spec.kwargs["num_levels"] == 1 and env.spec.kwargs["start_level"] == 7
    obs, _ = env.reset(seed=0)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8
    env.close()


# -- routines ------------------------------------------------------------------------------


def test_routines_extend_the_action_space():
    routines = [[2, 3], [5, 5, 5]]
    env = make_env("MiniQbert-v0", seed=0, routines=routines, record_observations=True)()
    assert isinstance(env, RoutineActionWrapper)
    assert env.action_space == gym.spaces.Discrete(6 + 2)
    env.reset(seed=0)
    *_, info = env.step(6 + 1)  # routine 1: DOWN DOWN DOWN
    assert info["routine_index"] == 1
    assert info["routine_length"] == 3
    assert info["routine_observations"].shape == (3, *env.observation_space.shape)
    env.close()
    # No routines: no wrapper.
    assert not isinstance(make_env("MiniQbert-v0", routines=[])(), RoutineActionWrapper)


@pytest.mark.slow
def test_routines_on_atari_sit_over_the_preprocessing():
    env = make_env(QBERT, seed=0, routines=[[RIGHT, RIGHT, RIGHT]])()
    assert env.action_space == gym.spaces.Discrete(6 + 1)
    assert env.observation_space.shape == (4, 84, 84)
    env.reset(seed=0)
    obs, _, _, _, info = env.step(6)
    assert obs.shape == (4, 84, 84)
    assert info["routine_length"] == 3
    assert "routine_observations" not in info  # off unless asked for (speed)
    env.close()


def test_each_env_of_a_vector_env_seeds_its_action_space_with_seed_plus_index():
    def samples(seed, idx):
        env = make_env("MiniQbert-v0", seed=seed, idx=idx)()
        return [int(env.action_space.sample()) for _ in range(30)]

    assert samples(4, 1) == samples(4, 1)
    assert samples(4, 1) == samples(5, 0)  # both seeded with 5
    assert samples(4, 1) != samples(4, 2)
