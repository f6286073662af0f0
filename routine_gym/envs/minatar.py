"""MinAtar (Young & Tian 2019): the CPU-scale Atari suite, as Gymnasium envs and a profile.

Five Atari-like games on 10×10 boolean frames with one channel per kind of object, built for
experiments that fit a CPU: `MinAtar/{Asterix,Breakout,Freeway,Seaquest,SpaceInvaders}-v1`,
registered when `routine_gym` is imported. They use MinAtar's defaults: the minimal action set
of each game (the `-v1` ids of MinAtar's own Gymnasium module), sticky actions with
probability 0.1 and difficulty ramping; episodes are cut at 10,000 steps (truncation), since a
good agent can play Breakout or Seaquest for ever.

`MinAtarEnv` wraps MinAtar's `Environment` itself rather than MinAtar's Gymnasium module, for
three things the demos need: `reset(seed=s)` reseeds the game *and* forgets the sticky action
of the previous episode (MinAtar keeps it), so an episode replays from its seed and actions
alone; `get_action_meanings()` names the actions; and `render()` draws RGB frames without
matplotlib, so `routine-gym play` works with W/A/S/D and space.

The profile (`MinAtarProfile`): the observation as a channels-first float array (C, 10, 10), no
frame stack, the MinAtar paper's network (one 3×3 convolution of 16 channels, a 128-unit layer),
no reward clipping (rewards are small integers), evaluation as training (no life tricks).
"""

from __future__ import annotations

import contextlib
import importlib
import io
import logging
import sys
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from routine_gym.envs.profile import EnvProfile

__all__ = ["GAMES", "MAX_EPISODE_STEPS", "PROFILE", "MinAtarEnv", "MinAtarProfile"]

#: The registered name of each game and MinAtar's own.
GAMES: dict[str, str] = {
    "Asterix": "asterix",
    "Breakout": "breakout",
    "Freeway": "freeway",
    "Seaquest": "seaquest",
    "SpaceInvaders": "space_invaders",
}
#: The time limit of every MinAtar episode, in agent steps.
MAX_EPISODE_STEPS = 10_000
#: MinAtar's full action set ('n', 'l', 'u', 'r', 'd', 'f') in ALE's names.
_ACTION_NAMES = ("NOOP", "LEFT", "UP", "RIGHT", "DOWN", "FIRE")
_KEYS = {"NOOP": None, "LEFT": "a", "UP": "w", "RIGHT": "d", "DOWN": "s", "FIRE": " "}
_PIXELS = 16  # rendered pixels per cell


#: What `minatar.environment` imports only to draw its own window (pyplot, seaborn: about 2 s
#: of a process's start, with scipy); routine-gym draws its own frames and never opens it.
_DRAWING_MODULES = ("matplotlib", "matplotlib.pyplot", "matplotlib.colors", "seaborn")


def _environment_class():
    # MinAtar imports its drawing libraries in a try block and logs a warning when they are
    # missing. While it is imported, the ones not loaded yet are marked missing (None in
    # sys.modules), so that a process stepping MinAtar never pays for them; the warning is
    # noise and is silenced. Stepping never uses them, so the games are unchanged.
    if "minatar.environment" not in sys.modules:
        blocked = [name for name in _DRAWING_MODULES if name not in sys.modules]
        for name in blocked:
            sys.modules[name] = None  # type: ignore[assignment]
        try:
            with contextlib.redirect_stderr(io.StringIO()):
                logging.disable(logging.WARNING)
                try:
                    importlib.import_module("minatar.environment")
                finally:
                    logging.disable(logging.NOTSET)
        finally:
            for name in blocked:
                if sys.modules.get(name, 0) is None:
                    del sys.modules[name]
    from minatar import Environment

    return Environment


class MinAtarEnv(gym.Env[np.ndarray, int]):
    """One MinAtar game with its minimal action set, seeded, replayable resets and RGB frames.

    Example:
        >>> import gymnasium as gym, routine_gym
        >>> env = gym.make("MinAtar/Breakout-v1")
        >>> obs, _ = env.reset(seed=0)
        >>> obs.shape, obs.dtype, env.unwrapped.get_action_meanings()
        ((10, 10, 4), dtype('bool'), ['NOOP', 'LEFT', 'RIGHT'])

    Args:
        game: MinAtar's name of the game (`"breakout"`, ...).
        sticky_action_prob: probability that the previous action is repeated instead.
        difficulty_ramping: the game speeds up as it goes on, as MinAtar defines.
        render_mode: None or `"rgb_array"`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, game: str, sticky_action_prob: float = 0.1,
                 difficulty_ramping: bool = True, render_mode: str | None = None) -> None:
        if game not in GAMES.values():
            raise ValueError(f"unknown MinAtar game {game!r}; the games are "
                             f"{', '.join(GAMES.values())}")
        if not 0 <= sticky_action_prob <= 1:
            raise ValueError(f"sticky_action_prob needs to be in [0, 1], actual value: "
                             f"{sticky_action_prob}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.game = _environment_class()(game, sticky_action_prob=sticky_action_prob,
                                         difficulty_ramping=difficulty_ramping)
        self.render_mode = render_mode
        self.sticky_action_prob = sticky_action_prob
        self.difficulty_ramping = difficulty_ramping  # Breakout and Freeway have no ramping
        self.action_set = list(self.game.minimal_action_set())
        self.action_space = spaces.Discrete(len(self.action_set))
        self.observation_space = spaces.Box(0, 1, shape=self.game.state_shape(), dtype=bool)
        self._seeded = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None or not self._seeded:
            # An unseeded first reset draws the game's seed from Gymnasium's np_random.
            game_seed = seed if seed is not None else int(self.np_random.integers(2**31 - 1))
            self.game.seed(game_seed)
            self._seeded = True
        self.game.last_action = 0  # MinAtar would carry the sticky action across episodes
        self.game.reset()
        return self.game.state().copy(), {}

    def step(self, action: int):
        reward, terminated = self.game.act(self.action_set[int(action)])
        return self.game.state().copy(), float(reward), bool(terminated), False, {}

    def get_action_meanings(self) -> list[str]:
        return [_ACTION_NAMES[a] for a in self.action_set]

    def get_keys_to_action(self) -> dict[tuple[str, ...], int]:
        """`gymnasium.utils.play`'s keys: W/A/S/D to move, space to fire (where the game can)."""
        keys = {}
        for i, name in enumerate(self.get_action_meanings()):
            if _KEYS[name] is not None:
                keys[(_KEYS[name],)] = i
        return keys

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        state = self.game.state()
        channels = state.shape[-1]
        # One colour per channel (the last channel drawn wins), black background.
        hues = np.linspace(0.0, 1.0, channels, endpoint=False)
        palette = np.stack([0.5 + 0.5 * np.cos(2 * np.pi * (hues + k / 3)) for k in range(3)], 1)
        image = np.zeros((*state.shape[:2], 3))
        for c in range(channels):
            image[state[..., c]] = palette[c]
        image = (image * 255).astype(np.uint8)
        return np.kron(image, np.ones((_PIXELS, _PIXELS, 1), dtype=np.uint8))


class MinAtarProfile(EnvProfile):
    """MinAtar's games: channels-first float observations, the MinAtar network, no tricks."""

    family = "minatar"
    network = "minatar"

    def observation_view(self, env: gym.Env, env_id: str) -> gym.Env:
        shape = env.observation_space.shape  # (10, 10, C) booleans
        space = spaces.Box(0.0, 1.0, shape=(shape[2], shape[0], shape[1]), dtype=np.float32)
        return gym.wrappers.TransformObservation(
            env, lambda obs: np.ascontiguousarray(np.moveaxis(obs, -1, 0), dtype=np.float32),
            space,
        )

    def play_fps(self, env: gym.Env) -> int | None:
        return 10

    def vector_env(self, env_id: str, num_envs: int, *, routines: Any = None,
                   record_observations: bool = False, env_kwargs: dict[str, Any] | None = None,
                   training: bool = True) -> gym.vector.VectorEnv | None:
        from routine_gym.envs.minatar_vector import MinAtarVectorEnv

        return MinAtarVectorEnv(env_id, num_envs, routines=routines,
                                record_observations=record_observations, env_kwargs=env_kwargs)


PROFILE = MinAtarProfile()


def register() -> None:
    """Register the five games as `MinAtar/{Game}-v1` (replacing MinAtar's own registration)."""
    registry = gym.envs.registration.registry
    for name, game in GAMES.items():
        env_id = f"MinAtar/{name}-v1"
        spec = registry.get(env_id)
        if spec is not None and spec.entry_point == "routine_gym.envs.minatar:MinAtarEnv":
            continue
        registry.pop(env_id, None)
        gym.register(id=env_id, entry_point="routine_gym.envs.minatar:MinAtarEnv",
                     kwargs={"game": game}, max_episode_steps=MAX_EPISODE_STEPS)
