"""Procgen games (CoinRun, ...) as Gymnasium envs, set up as in the RAPL paper.

Procgen speaks gym3: one `act` then one `observe` per step, and an episode that ends is reset
inside the C++ game before anything is observed. :class:`ProcgenEnv` turns that into the
Gymnasium API with seeded, replayable resets; it is registered as `procgen/CoinRun-v0`.
"""

from __future__ import annotations

import contextlib
import io
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from routine_gym.envs.profile import EnvProfile

with contextlib.redirect_stderr(io.StringIO()):
    # procgen imports the legacy `gym` package only to register its old envs, and `gym` prints
    # an "unmaintained" notice on import; nothing here uses `gym`, so the notice is noise.
    import procgen
    from procgen.env import DISTRIBUTION_MODE_DICT, ENV_NAMES

__all__ = ["MINIMAL_ACTIONS", "PROCGEN_TIMEOUT", "PROFILE", "ProcgenEnv", "ProcgenProfile"]

#: The paper's CoinRun action set, as (name, button combination) pairs in action order.
MINIMAL_ACTIONS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("LEFT", ("LEFT",)),
    ("DOWN", ("DOWN",)),
    ("UP", ("UP",)),
    ("RIGHT", ("RIGHT",)),
    ("NOOP", ()),
)

#: Steps after which every Procgen game ends an episode by itself (`Game::timeout` in procgen).
PROCGEN_TIMEOUT = 1000

# Procgen seeds are C ints; larger Gymnasium seeds are folded into this range.
_RAND_SEED_RANGE = 2**31

# The keyword arguments ProcgenEnv sets itself; the rest go to `procgen.ProcgenGym3Env`.
_RESERVED_KWARGS = ("num", "env_name", "rand_seed", "render_mode", "num_threads")


class ProcgenEnv(gym.Env[np.ndarray, int]):
    """A Procgen game with the Gymnasium API; by default the RAPL paper's CoinRun setting.

    Observations are the 64×64×3 uint8 frames. With `use_minimal_actions=True` the actions are
    the paper's `LEFT, DOWN, UP, RIGHT, NOOP` (mapped to Procgen's button combinations 1, 3, 5,
    7 and 4), otherwise Procgen's full 15 combinations (named like `"LEFT+UP"` and `"D"`).
    Velocity painting is off unless `paint_vel_info=True` is passed through.

    Episode ends. Procgen resets a finished level inside the game before the step's observation
    is rendered, so the terminal frame is never available: the observation returned with
    `terminated` or `truncated` is the first frame of the next episode, and the `reset()` that
    follows returns that same frame without skipping a level (so a training loop and the
    level sequence stay in step). `truncated` is reported when Procgen's own timeout
    (:data:`PROCGEN_TIMEOUT` steps) ended the episode and the level was not completed;
    the one indistinguishable case, dying on exactly the last step, also reads as truncated.

    Seeding. Procgen draws each episode's level from a generator seeded once, when the game is
    created. `reset(seed=s)` therefore re-creates the game with `rand_seed = s mod 2**31`
    (about a millisecond; only the first game of a process loads the assets, about 2 s), so
    the episodes that follow, and everything in them, depend only on `s` and the actions: a
    demonstration replays exactly from its seed. `reset()` without a seed starts the next
    level of the same generator (forcing the end of an unfinished episode), which is also
    reproducible after a seeded reset.

    Info: `reset` gives ``level_seed`` (the Procgen level being played); `step` gives
    ``level_seed`` (the level the step was taken in) and ``level_complete`` (True only on the
    step that completed the level, e.g. reached CoinRun's coin).

    Example:
        >>> import gymnasium as gym
        >>> import routine_gym  # registers procgen/CoinRun-v0
        >>> env = gym.make("procgen/CoinRun-v0")
        >>> env.unwrapped.get_action_meanings()
        ['LEFT', 'DOWN', 'UP', 'RIGHT', 'NOOP']
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, obs.dtype
        ((64, 64, 3), dtype('uint8'))
        >>> obs, reward, terminated, truncated, info = env.step(3)  # RIGHT
        >>> sorted(info)
        ['level_complete', 'level_seed']

    Attributes:
        env_name: the Procgen game.
        combos: the Procgen button combination of each action, e.g. `("RIGHT",)`; `()` is NOOP.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(
        self,
        env_name: str = "coinrun",
        num_levels: int = 100,
        start_level: int = 0,
        distribution_mode: str = "easy",
        use_minimal_actions: bool = True,
        render_mode: str | None = None,
        **procgen_kwargs: Any,
    ):
        """Create the game.

        Args:
            env_name: the Procgen game, one of `procgen.env.ENV_NAMES`.
            num_levels: how many distinct levels to draw from (0: unlimited); the paper trains
                on 100.
            start_level: the first level seed of that range.
            distribution_mode: `"easy"` (the paper's training levels), `"hard"`, ...
            use_minimal_actions: the paper's 5 actions instead of Procgen's 15.
            render_mode: None or `"rgb_array"` (Procgen's 512×512 frame).
            **procgen_kwargs: passed to `procgen.ProcgenGym3Env` (`paint_vel_info`,
                `use_backgrounds`, `center_agent`, ...).

        Raises:
            ValueError: an unknown game, distribution mode or render mode, or a negative level.
            TypeError: a keyword that ProcgenEnv sets itself (`rand_seed`: use `reset(seed=)`).
        """
        if env_name not in ENV_NAMES:
            raise ValueError(f"env_name must be one of {ENV_NAMES}, actual value: {env_name!r}")
        if distribution_mode not in DISTRIBUTION_MODE_DICT:
            raise ValueError(
                f"distribution_mode must be one of {sorted(DISTRIBUTION_MODE_DICT)}, "
                f"actual value: {distribution_mode!r}"
            )
        if num_levels < 0 or start_level < 0:
            raise ValueError(
                "num_levels and start_level must be ≥ 0, actual values: "
                f"num_levels={num_levels}, start_level={start_level}"
            )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"actual value: {render_mode!r}"
            )
        reserved = sorted(set(procgen_kwargs) & set(_RESERVED_KWARGS))
        if reserved:
            raise TypeError(
                f"ProcgenEnv sets {reserved} itself (seed the game with reset(seed=...)); "
                "remove them from the keyword arguments"
            )

        self.env_name = env_name
        self.render_mode = render_mode
        self._game_kwargs = {
            "env_name": env_name,
            "num_levels": num_levels,
            "start_level": start_level,
            "distribution_mode": distribution_mode,
            "paint_vel_info": False,
            **procgen_kwargs,
        }
        self._game = self._make_game(rand_seed=None)
        combos = [tuple(combo) for combo in self._game.combos]
        if use_minimal_actions:
            self.combos = tuple(combo for _, combo in MINIMAL_ACTIONS)
            self._action_meanings = [name for name, _ in MINIMAL_ACTIONS]
        else:
            self.combos = tuple(combos)
            self._action_meanings = ["+".join(combo) or "NOOP" for combo in combos]
        self._combo_of_action = np.array([combos.index(c) for c in self.combos], dtype=np.int32)

        self.observation_space = spaces.Box(0, 255, shape=(64, 64, 3), dtype=np.uint8)
        self.action_space = spaces.Discrete(len(self._combo_of_action))

        # True while the game shows the first frame of an episode no reset() has returned yet.
        self._episode_pending = True
        self._elapsed_steps = 0
        self._level_seed = int(self._game.get_info()[0]["level_seed"])

    def _make_game(self, rand_seed: int | None) -> procgen.ProcgenGym3Env:
        """A new gym3 game; `rand_seed=None` lets Procgen pick one at random."""
        return procgen.ProcgenGym3Env(
            num=1,
            num_threads=0,  # a single game: stepping it on the calling thread is fastest
            rand_seed=rand_seed,
            render_mode=self.render_mode,
            **self._game_kwargs,
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; with `seed`, re-create the game so the episodes that follow replay.

        Args:
            seed: re-creates the Procgen game with `rand_seed = seed mod 2**31`.
            options: unused.

        Returns:
            The first frame of the episode and `{"level_seed": ...}`.
        """
        super().reset(seed=seed)
        if seed is not None:
            _close_game(self._game)
            self._game = self._make_game(rand_seed=int(seed) % _RAND_SEED_RANGE)
        elif not self._episode_pending:
            # -1 is Procgen's "end this episode now" action: the game resets to its next level.
            self._game.act(np.array([-1], dtype=np.int32))
        _, observation, _ = self._game.observe()
        self._episode_pending = False
        self._elapsed_steps = 0
        self._level_seed = int(self._game.get_info()[0]["level_seed"])
        return observation["rgb"][0], {"level_seed": self._level_seed}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Play one frame.

        Args:
            action: an action of :attr:`action_space`.

        Returns:
            The next frame (the next episode's first frame at an episode end), the reward,
            `terminated`, `truncated` and `{"level_seed", "level_complete"}`.

        Raises:
            ValueError: `action` is not in the action space.
        """
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r} is outside the action space {self.action_space}")
        self._game.act(self._combo_of_action[int(action) : int(action) + 1])
        reward, observation, first = self._game.observe()
        self._episode_pending = False
        self._elapsed_steps += 1
        terminated = truncated = False
        info: dict[str, Any] = {"level_seed": self._level_seed, "level_complete": False}
        if first[0]:
            game_info = self._game.get_info()[0]
            info["level_complete"] = bool(game_info["prev_level_complete"])
            if not info["level_complete"] and self._elapsed_steps >= PROCGEN_TIMEOUT:
                truncated = True
            else:
                terminated = True
            self._episode_pending = True
            self._elapsed_steps = 0
            self._level_seed = int(game_info["level_seed"])
        return observation["rgb"][0], float(reward[0]), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """The current 512×512 frame in `render_mode="rgb_array"`, None without a render mode."""
        if self.render_mode is None:
            gym.logger.warn(
                "ProcgenEnv.render() was called without a render mode; "
                'create the env with render_mode="rgb_array"'
            )
            return None
        return self._game.get_info()[0]["rgb"]

    def get_action_meanings(self) -> list[str]:
        """The names of the actions, e.g. `['LEFT', 'DOWN', 'UP', 'RIGHT', 'NOOP']`."""
        return list(self._action_meanings)

    def close(self) -> None:
        """Free the Procgen game."""
        _close_game(self._game)
        super().close()


def _close_game(game: Any) -> None:
    """Close a gym3 game and drop its C buffers, which hold exported views of its numpy arrays:
    left to the garbage collector, such a view can be cleared while still exported, and the
    interpreter crashes (a segfault at exit after several games were made and closed)."""
    game.close()
    for name in ("_c_buffers", "_c_ob_buffers", "_c_ac_buffers", "_c_info_buffers",
                 "_c_rew_buffer", "_c_first_buffer"):
        if hasattr(game, name):
            setattr(game, name, None)


class ProcgenProfile(EnvProfile):
    """Procgen (CoinRun): no frame stack, the IMPALA CNN, trained on some levels and evaluated
    on unseen ones (SPEC §5: 100 easy training levels; unseen easy or hard levels)."""

    family = "procgen"
    network = "impala_cnn"
    has_levels = True

    def level_kwargs(self, num_levels: int, start_level: int, distribution_mode: str,
                     eval_distribution_mode: str, *, training: bool) -> dict[str, Any]:
        if training:
            return {"num_levels": num_levels, "start_level": start_level,
                    "distribution_mode": distribution_mode}
        # Evaluation: the levels after the training ones, never seen in training.
        return {"num_levels": 0, "start_level": start_level + num_levels,
                "distribution_mode": eval_distribution_mode}


PROFILE = ProcgenProfile()
