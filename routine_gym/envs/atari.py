"""Atari (ALE): its profile, and the standard training wrappers Gymnasium does not ship.

The profile (`AtariProfile`, SPEC §5): ALE's own frame skip of 4 (the last frame observed) and
grey frames in the primitive env; the agent's view adds no-op starts, (training only) a life
loss ending the episode and sign-clipped rewards, FIRE on reset, (evaluation only) FIRE after
a lost life, 84×84 frames in stacks of 4, and the Nature CNN.

Gymnasium has the observation side (`GrayscaleObservation`, `ResizeObservation`,
`FrameStackObservation`, `ClipReward`); the three reset-side habits of DQN/A2C training are
here: random no-op starts, a life loss ending the *training* episode, and pressing FIRE at the
start of games that wait for it. Each works one agent step (one ALE frame-skip) at a time.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import FrameStackObservation, ResizeObservation, TransformReward

from routine_gym.envs.profile import EnvProfile

__all__ = [
    "PROFILE",
    "AtariProfile",
    "EpisodicLife",
    "FireOnLifeLoss",
    "FireReset",
    "NoopReset",
    "sign_reward",
]


def _action_meanings(env: gym.Env) -> list[str]:
    unwrapped = env.unwrapped
    if not callable(getattr(unwrapped, "get_action_meanings", None)):
        raise ValueError(
            f"these wrappers need an env with get_action_meanings() (ALE), "
            f"got {type(unwrapped).__name__}"
        )
    return list(unwrapped.get_action_meanings())


def _lives(env: gym.Env) -> int:
    """Lives left: ALE's `ale.lives()`, else the game's own `lives` property (MiniQbert)."""
    unwrapped = env.unwrapped
    return unwrapped.ale.lives() if hasattr(unwrapped, "ale") else unwrapped.lives


class NoopReset(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """After a reset, take a random number (1..noop_max) of NOOP steps, for varied starts."""

    def __init__(self, env: gym.Env, noop_max: int = 30) -> None:
        if noop_max < 0:
            raise ValueError(f"noop_max needs to be ≥ 0, actual value: {noop_max}")
        if _action_meanings(env)[0] != "NOOP":
            raise ValueError("NoopReset needs action 0 to be NOOP")
        gym.utils.RecordConstructorArgs.__init__(self, noop_max=noop_max)
        gym.Wrapper.__init__(self, env)
        self.noop_max = noop_max

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if self.noop_max == 0:
            return obs, info
        for _ in range(int(self.np_random.integers(1, self.noop_max + 1))):
            obs, _, terminated, truncated, info = self.env.step(0)
            if terminated or truncated:
                obs, info = self.env.reset(options=options)
        return obs, info


class EpisodicLife(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A life loss terminates the training episode; the game itself goes on until game over.

    `reset` after a life loss only takes a NOOP step (action 0), so the agent sees a short
    episode per life (it learns that dying is final) while the game, and an inner
    `RecordEpisodeStatistics`, run to the real game over. Lives are read from ALE
    (`ale.lives()`) or from the game's own `lives` property (MiniQbert).
    """

    def __init__(self, env: gym.Env) -> None:
        unwrapped = env.unwrapped
        if not hasattr(unwrapped, "ale") and not isinstance(getattr(unwrapped, "lives", None), int):
            raise ValueError(
                f"EpisodicLife needs a game that counts lives (ALE's ale.lives() or a `lives` "
                f"property), got {type(unwrapped).__name__}"
            )
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.lives = 0
        self.game_over = True

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.game_over = terminated or truncated
        lives = _lives(self.env)
        if 0 < lives < self.lives:
            terminated = True
        self.lives = lives
        return obs, reward, terminated, truncated, info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if self.game_over or seed is not None:
            obs, info = self.env.reset(seed=seed, options=options)
        else:
            obs, _, terminated, truncated, info = self.env.step(0)
            if terminated or truncated:
                obs, info = self.env.reset(options=options)
        self.game_over = False
        self.lives = _lives(self.env)
        return obs, info


class FireReset(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Press FIRE after a reset, for games that wait for it before starting."""

    def __init__(self, env: gym.Env) -> None:
        if "FIRE" not in _action_meanings(env):
            raise ValueError("FireReset needs a FIRE action")
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.fire = _action_meanings(env).index("FIRE")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        obs, _, terminated, truncated, info = self.env.step(self.fire)
        if terminated or truncated:
            obs, info = self.env.reset(options=options)
        return obs, info


class FireOnLifeLoss(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """After a life loss, take a NOOP and a FIRE step: the evaluation twin of `EpisodicLife`.

    In training, `EpisodicLife` ends the episode at a life loss and its reset takes a NOOP step,
    then `FireReset` presses FIRE, so every life the agent trains on starts that way, and an
    agent need not learn to press FIRE itself. Evaluated on full games, the same agent can
    wait forever for a ball that a serve would have launched (Breakout). This wrapper starts
    each new life the way training did; the two steps are real game steps (a demo records
    them as actions), their rewards are added to the step that lost the life.
    """

    def __init__(self, env: gym.Env) -> None:
        if not hasattr(env.unwrapped, "ale"):
            raise ValueError(
                f"FireOnLifeLoss needs an ALE env (it reads ale.lives()), "
                f"got {type(env.unwrapped).__name__}"
            )
        if "FIRE" not in _action_meanings(env):
            raise ValueError("FireOnLifeLoss needs a FIRE action")
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.fire = _action_meanings(env).index("FIRE")
        self.lives = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self.lives = _lives(self.env)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        lives = _lives(self.env)
        if 0 < lives < self.lives:
            for extra in (0, self.fire):
                if terminated or truncated:
                    break
                obs, r, terminated, truncated, info = self.env.step(extra)
                reward += r
        self.lives = _lives(self.env)
        return obs, reward, terminated, truncated, info


def sign_reward(reward: float) -> float:
    """Reward clipping for training: only the sign of a game's reward is kept."""
    return float(np.sign(reward))


class AtariProfile(EnvProfile):
    """ALE's games (`ALE/*-v5`, `*NoFrameskip-v4`): SPEC §5's preprocessing, the Nature CNN."""

    family = "atari"
    frame_stack = 4
    network = "nature_cnn"

    def default_kwargs(self, env_id: str) -> dict[str, Any]:
        # `*NoFrameskip-v4` gets frameskip=4 too, so an agent step is 4 frames everywhere.
        return {"frameskip": 4, "obs_type": "grayscale"}

    def preprocess(self, env: gym.Env, env_id: str, *, training: bool = True,
                   serve_lives: bool = True) -> gym.Env:
        env = NoopReset(env, noop_max=30)
        if training:
            env = EpisodicLife(env)
        if "FIRE" in env.unwrapped.get_action_meanings():
            if not training and serve_lives:  # each life starts as in training (EpisodicLife
                # + FireReset fire there)
                env = FireOnLifeLoss(env)
            env = FireReset(env)
        if training:
            env = TransformReward(env, sign_reward)
        return self.observation_view(env, env_id)

    def observation_view(self, env: gym.Env, env_id: str) -> gym.Env:
        if len(env.observation_space.shape) == 3:  # an RGB primitive env
            env = gym.wrappers.GrayscaleObservation(env)
        env = ResizeObservation(env, (84, 84))
        return FrameStackObservation(env, self.frame_stack)

    def vector_env(self, env_id: str, num_envs: int, *, routines: Any = None,
                   record_observations: bool = False, env_kwargs: dict[str, Any] | None = None,
                   training: bool = True) -> gym.vector.VectorEnv | None:
        # The training view through ale-py's C++ games (`routine_gym.envs.atari_vector`);
        # evaluation, and kwargs the C++ games cannot take, keep the Python path.
        from routine_gym.envs.atari_vector import ALEVectorEnv, unsupported_kwargs

        kwargs = {**self.default_kwargs(env_id), **(env_kwargs or {})}
        if not training or unsupported_kwargs(env_id, kwargs) is not None:
            return None
        return ALEVectorEnv(env_id, num_envs, routines=routines,
                            record_observations=record_observations, env_kwargs=kwargs)

    def recording_stacks(self, env_id: str):
        stacks = super().recording_stacks(env_id)
        # routine-gym 0.1's evaluation stack had no FireOnLifeLoss (the first Qbert demo).
        return {
            "agent": stacks["agent"],
            "agent-0.1": lambda env: self.preprocess(env, env_id, training=False,
                                                     serve_lives=False),
            "raw": stacks["raw"],
        }

    def score_key(self, env_id: str) -> str | None:
        from routine_gym.envs import canonical_env_id

        return canonical_env_id(env_id)

    def play_fps(self, env: gym.Env) -> int | None:
        # ALE's render_fps (30) plays frame-skipped Atari at twice its real speed; a human
        # wants the console's 60 frames per second, i.e. 60 / frameskip steps per second.
        frameskip = env.spec.kwargs.get("frameskip") if env.spec is not None else None
        if isinstance(frameskip, int) and frameskip >= 1:
            return max(1, round(60 / frameskip))
        return None


PROFILE = AtariProfile()
