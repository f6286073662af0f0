"""MiniQbert: a small pyramid game with the routine structure of Atari Q*bert.

The paper's Figure 1 motivates routines with Q*bert: the agent must land on every cube of a
pyramid to change its colour, and the same traversal is needed again on every level, so the
same action sequences recur throughout a good player's demonstration. `MiniQbertEnv` keeps
exactly that structure and nothing else (no enemies, no discs), so it is fast enough for unit
tests and small experiments and still rewards routines.

Geometry. The pyramid has `size` rows; row `r` holds the cubes `(r, 0) … (r, r)`. Moves are the
four diagonal jumps of Q*bert, with the names and ids of ALE Qbert's minimal action set so that
a routine reads the same in both games::

                  (0,0)                      UP    (2) = up-right    (r-1, c)
               (1,0) (1,1)                   RIGHT (3) = down-right  (r+1, c+1)
            (2,0) (2,1) (2,2)                LEFT  (4) = up-left     (r-1, c-1)
         (3,0) (3,1) (3,2) (3,3)             DOWN  (5) = down-left   (r+1, c)

    NOOP (0) and FIRE (1) do nothing: useless actions exist, as in the Atari game.

Rules and rewards.
- An episode starts on level 0 with the agent on the top cube and every cube uncoloured. Only
  landing colours a cube, so the agent has to jump back onto the top cube at some point.
- Landing on an uncoloured cube colours it: reward `+25`. Landing on a coloured cube: `0`.
- Colouring the last cube gives a level bonus of `+100`; the next level starts at once (colours
  reset, agent back on top). Completing `num_levels` levels terminates the episode.
- Jumping off the pyramid costs a life (reward `0`) and puts the agent back on the top cube;
  the colours stay. Losing the last life terminates the episode.
- The game is deterministic given the actions; nothing in it is random, so `reset(seed=...)`
  only seeds `np_random` for wrappers that use it. Truncation comes from the `TimeLimit` of
  the registration (`MiniQbert-v0`: 500 steps).

Observations.
- `obs_type="vector"` (default): float32 vector of length `2 n + 2` for `n = size (size+1)/2`
  cubes: the colour of each cube (0/1, cube index `r (r+1)/2 + c`), the one-hot position of
  the agent, the fraction of levels completed (`level / num_levels`) and the fraction of lives
  left (`lives / max_lives`). It is the full state of the game, small enough for an MLP.
- `obs_type="rgb"`: a uint8 image of `(14 size + 8)` pixels a side (64×64×3 for the default
  size 4): blue cubes turn yellow when coloured, the agent is an orange square, white dots in
  the top-left corner count the lives left and green dots in the top-right corner the levels
  completed. The same picture is returned by `render()` with `render_mode="rgb_array"`;
  `render_mode="ansi"` returns a text picture.

Info: `lives` (lives left), `level` (levels completed) and `cubes_left` (uncoloured cubes).

Scripted expert. `scripted_expert(size)` plays a fixed boustrophedon route that covers a level
in 11 jumps for the default size 4 (the fewest possible: the test suite checks it by exhaustive
search), so with the default settings it scores `3 × (10 × 25 + 100) = 1050` in `3 × 11 = 33`
steps, repeating the same 11 actions on each level:
`DOWN UP RIGHT RIGHT RIGHT LEFT DOWN LEFT DOWN LEFT DOWN`.

Example:
    >>> import gymnasium as gym
    >>> import routine_gym  # registers MiniQbert-v0
    >>> env = gym.make("MiniQbert-v0")
    >>> expert = scripted_expert(env.unwrapped)
    >>> obs, info = env.reset(seed=0)
    >>> total, steps, done = 0.0, 0, False
    >>> while not done:
    ...     obs, reward, terminated, truncated, info = env.step(expert(obs))
    ...     total, steps, done = total + reward, steps + 1, terminated or truncated
    >>> total, steps
    (1050.0, 33)
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from routine_gym.envs.profile import EnvProfile

NOOP, FIRE, UP, RIGHT, LEFT, DOWN = range(6)
ACTION_MEANINGS: tuple[str, ...] = ("NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN")

# Row and column change of each jump on the triangular grid (see the module docstring).
MOVES: dict[int, tuple[int, int]] = {UP: (-1, 0), RIGHT: (1, 1), LEFT: (-1, -1), DOWN: (1, 0)}

CUBE_REWARD = 25.0
LEVEL_BONUS = 100.0
OBS_TYPES = ("vector", "rgb")

# Picture layout: cubes of 12 pixels on a 14-pixel pitch, a 4-pixel margin all round.
_CUBE_PX = 12
_PITCH = 14
_MARGIN = 4
_AGENT_INSET = 3  # the agent square covers the cube minus this border
_BACKGROUND = (0, 0, 0)
_CUBE_OFF = (50, 70, 200)
_CUBE_ON = (230, 200, 40)
_AGENT = (240, 100, 20)
_LIFE = (255, 255, 255)
_LEVEL = (40, 200, 60)

# pygame's key codes for the arrow keys (SDL2 keycodes), written out so that importing this
# module does not import pygame.
_K_RIGHT, _K_LEFT, _K_DOWN, _K_UP = 1073741903, 1073741904, 1073741905, 1073741906


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def num_cubes(size: int) -> int:
    """Number of cubes of a pyramid with `size` rows: `size (size + 1) / 2`."""
    return size * (size + 1) // 2


def cube_index(row: int, col: int) -> int:
    """Index of cube `(row, col)` in the observation vector: `row (row + 1) / 2 + col`."""
    return row * (row + 1) // 2 + col


@lru_cache(maxsize=32)
def _geometry(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Cube coordinates `(n, 2)` and the jump table `(n, 6)`: landing cube, or -1 off the edge.

    NOOP and FIRE map every cube to itself; the env treats them as "no jump".
    """
    coords = np.array([(r, c) for r in range(size) for c in range(r + 1)], dtype=np.int64)
    table = np.empty((len(coords), len(ACTION_MEANINGS)), dtype=np.int64)
    for i, (r, c) in enumerate(coords):
        table[i, NOOP] = table[i, FIRE] = i
        for action, (dr, dc) in MOVES.items():
            r2, c2 = r + dr, c + dc
            on = 0 <= r2 < size and 0 <= c2 <= r2
            table[i, action] = cube_index(r2, c2) if on else -1
    coords.setflags(write=False)
    table.setflags(write=False)
    return coords, table


def _image_side(size: int) -> int:
    return _PITCH * size + 2 * _MARGIN


def _cube_origin(size: int, row: int, col: int) -> tuple[int, int]:
    """Top-left pixel `(y, x)` of a cube: rows step down by one pitch, and each row is
    shifted half a pitch right of the row below so the picture is a pyramid."""
    y = _MARGIN + 1 + row * _PITCH
    x = _MARGIN + 1 + (size - 1 - row) * _PITCH // 2 + col * _PITCH
    return y, x


class MiniQbertEnv(gym.Env):
    """Pyramid game of the paper's Figure 1: land on every cube to colour it, level after level.

    See the module docstring for the rules, rewards, actions and observations.

    Args:
        size: rows of the pyramid (≥ 2); the default 4 gives 10 cubes.
        lives: lives at the start (≥ 1); jumping off the pyramid costs one.
        num_levels: levels to clear before the episode terminates (≥ 1).
        obs_type: `"vector"` (float32 state vector) or `"rgb"` (uint8 image).
        render_mode: `None`, `"rgb_array"` or `"ansi"`.

    Example:
        >>> env = MiniQbertEnv()
        >>> obs, info = env.reset(seed=0)
        >>> obs.shape, info
        ((22,), {'lives': 3, 'level': 0, 'cubes_left': 10})
        >>> _, reward, *_ = env.step(DOWN)  # jump down-left onto the uncoloured cube (1, 0)
        >>> reward
        25.0
    """

    metadata = {"render_modes": ["rgb_array", "ansi"], "render_fps": 4}

    def __init__(
        self,
        size: int = 4,
        lives: int = 3,
        num_levels: int = 3,
        obs_type: str = "vector",
        render_mode: str | None = None,
    ) -> None:
        if not _is_int(size) or size < 2:
            raise ValueError(f"size needs to be an integer ≥ 2, actual value: {size!r}")
        if not _is_int(lives) or lives < 1:
            raise ValueError(f"lives needs to be an integer ≥ 1, actual value: {lives!r}")
        if not _is_int(num_levels) or num_levels < 1:
            raise ValueError(f"num_levels needs to be an integer ≥ 1, actual value: {num_levels!r}")
        if obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type needs to be one of {OBS_TYPES}, actual value: {obs_type!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode needs to be None or one of {self.metadata['render_modes']}, "
                f"actual value: {render_mode!r}"
            )
        self.size = int(size)
        self.max_lives = int(lives)
        self.num_levels = int(num_levels)
        self.obs_type = obs_type
        self.render_mode = render_mode

        self.n_cubes = num_cubes(self.size)
        self._coords, self._jumps = _geometry(self.size)
        self.action_space = spaces.Discrete(len(ACTION_MEANINGS))
        if obs_type == "vector":
            self.observation_space = spaces.Box(0.0, 1.0, (2 * self.n_cubes + 2,), np.float32)
        else:
            side = _image_side(self.size)
            self.observation_space = spaces.Box(0, 255, (side, side, 3), np.uint8)

        self._colours = np.zeros(self.n_cubes, dtype=bool)
        self._pos = 0
        self._lives = self.max_lives
        self._level = 0
        self._needs_reset = True

    # -- Gymnasium API -----------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start a new game: level 0, all lives, every cube uncoloured, agent on top."""
        super().reset(seed=seed)
        self._colours[:] = False
        self._pos = 0
        self._lives = self.max_lives
        self._level = 0
        self._needs_reset = False
        return self._obs(), self._info()

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        """Jump (or idle for NOOP/FIRE) and return `(obs, reward, terminated, False, info)`."""
        if self._needs_reset:
            raise RuntimeError("MiniQbertEnv.step() called before reset() or after the game ended")
        if not self.action_space.contains(action):
            raise ValueError(f"action needs to be in {self.action_space}, actual value: {action!r}")
        action = int(action)
        reward = 0.0
        terminated = False
        if action in MOVES:
            target = int(self._jumps[self._pos, action])
            if target < 0:  # jumped off the pyramid
                self._lives -= 1
                self._pos = 0
                terminated = self._lives == 0
            else:
                self._pos = target
                if not self._colours[target]:
                    self._colours[target] = True
                    reward += CUBE_REWARD
                    if self._colours.all():
                        reward += LEVEL_BONUS
                        self._level += 1
                        terminated = self._level == self.num_levels
                        if not terminated:  # the final observation keeps the finished pyramid
                            self._colours[:] = False
                            self._pos = 0
        self._needs_reset = terminated
        return self._obs(), reward, terminated, False, self._info()

    def render(self) -> np.ndarray | str | None:
        """The picture of `render_mode`: an RGB array, a text picture, or None (with a warning)."""
        if self.render_mode == "rgb_array":
            return self._draw()
        if self.render_mode == "ansi":
            return self._text()
        gym.logger.warn(
            "MiniQbertEnv.render() called without a render_mode; "
            'pass render_mode="rgb_array" or "ansi" to the constructor.'
        )
        return None

    def get_action_meanings(self) -> list[str]:
        """Names of the actions, as ALE's Qbert: NOOP, FIRE, UP, RIGHT, LEFT, DOWN."""
        return list(ACTION_MEANINGS)

    def get_keys_to_action(self) -> dict[tuple[str | int, ...], int]:
        """Keyboard mapping for `gymnasium.utils.play.play(env)` (needs `render_mode="rgb_array"`).

        The letters are ALE Qbert's own (`w`/`d`/`a`/`s`, space for FIRE, `e` for NOOP) and the
        arrow keys do the same: think of the pyramid turned 45° clockwise, so
        ↑/`w` jumps up-right, →/`d` down-right, ←/`a` up-left and ↓/`s` down-left.
        No key pressed is NOOP.
        """
        return {
            ("e",): NOOP,
            (" ",): FIRE,
            ("w",): UP,
            (_K_UP,): UP,
            ("d",): RIGHT,
            (_K_RIGHT,): RIGHT,
            ("a",): LEFT,
            (_K_LEFT,): LEFT,
            ("s",): DOWN,
            (_K_DOWN,): DOWN,
        }

    # -- state read-outs -----------------------------------------------------------------

    @property
    def position(self) -> tuple[int, int]:
        """The agent's cube as `(row, col)`."""
        r, c = self._coords[self._pos]
        return int(r), int(c)

    @property
    def colours(self) -> np.ndarray:
        """A copy of the cube colours (bool, indexed by `cube_index`)."""
        return self._colours.copy()

    @property
    def lives(self) -> int:
        """Lives left."""
        return self._lives

    @property
    def level(self) -> int:
        """Levels completed in this episode."""
        return self._level

    def _info(self) -> dict[str, Any]:
        return {
            "lives": self._lives,
            "level": self._level,
            "cubes_left": int(self.n_cubes - self._colours.sum()),
        }

    def _obs(self) -> np.ndarray:
        if self.obs_type == "rgb":
            return self._draw()
        obs = np.zeros(2 * self.n_cubes + 2, dtype=np.float32)
        obs[: self.n_cubes] = self._colours
        obs[self.n_cubes + self._pos] = 1.0
        obs[-2] = self._level / self.num_levels
        obs[-1] = self._lives / self.max_lives
        return obs

    def _draw(self) -> np.ndarray:
        side = _image_side(self.size)
        img = np.zeros((side, side, 3), dtype=np.uint8)
        img[:] = _BACKGROUND
        for i, (r, c) in enumerate(self._coords):
            y, x = _cube_origin(self.size, int(r), int(c))
            img[y : y + _CUBE_PX, x : x + _CUBE_PX] = _CUBE_ON if self._colours[i] else _CUBE_OFF
        r, c = self._coords[self._pos]
        y, x = _cube_origin(self.size, int(r), int(c))
        a, b = _AGENT_INSET, _CUBE_PX - _AGENT_INSET
        img[y + a : y + b, x + a : x + b] = _AGENT
        # 2×2 dots in the free corners beside the top cube, as many as fit there.
        room = (_cube_origin(self.size, 0, 0)[1] - 1) // 3
        for k in range(min(self._lives, room)):
            img[1:3, 1 + 3 * k : 3 + 3 * k] = _LIFE
        for k in range(min(self._level, room)):
            img[1:3, side - 3 - 3 * k : side - 1 - 3 * k] = _LEVEL
        return img

    def _text(self) -> str:
        lines = [
            f"level {min(self._level + 1, self.num_levels)}/{self.num_levels}  "
            f"lives {self._lives}  cubes left {self.n_cubes - int(self._colours.sum())}"
        ]
        for r in range(self.size):
            cells = []
            for c in range(r + 1):
                i = cube_index(r, c)
                mark = "#" if self._colours[i] else "."
                cells.append(f"<{mark}>" if i == self._pos else f"[{mark}]")
            lines.append("  " * (self.size - 1 - r) + " ".join(cells))
        return "\n".join(lines) + "\n"


# -- scripted expert --------------------------------------------------------------------------


def expert_route(size: int) -> tuple[tuple[int, int], ...]:
    """The cubes the expert lands on in one level, in order, starting from the top cube.

    A boustrophedon over pairs of rows: rows 0-1 by `DOWN UP RIGHT` (the top cube is coloured
    by jumping back onto it), then each following pair of rows zig-zags left or right,
    alternating, so the route ends a pair where the next one starts. Entering a pair costs one
    repeated landing (the end cube of its lower row has a single neighbour above it); a last
    unpaired row (odd `size`) is covered by hopping up and down from the row above.

    Length: `size (size + 2) / 2 − 1` jumps for an even size (3, 11, 23 for sizes 2, 4, 6),
    which is the fewest possible: jumps alternate between odd and even rows, the first landing
    is on row 1, and the odd rows hold `size (size + 2) / 4` cubes. For size 3 it takes 8 jumps,
    also the fewest; for odd sizes from 5 up the last row costs a few extra (20 jumps for
    size 5, where the optimum is 18).
    """
    if not _is_int(size) or size < 2:
        raise ValueError(f"size needs to be an integer ≥ 2, actual value: {size!r}")
    route: list[tuple[int, int]] = [(1, 0), (0, 0), (1, 1)]
    at_left = False  # the route stands at the right end of rows 0-1
    r = 2
    while r < size:
        if r + 1 < size:  # a pair of rows r, r+1
            if at_left:  # (r-1, 0) → right along the pair, ending at (r+1, r+1)
                route += [(r, 0), (r + 1, 0)]
                for c in range(r + 1):
                    route += [(r, c), (r + 1, c + 1)]
            else:  # (r-1, r-1) → left along the pair, ending at (r+1, 0)
                route += [(r, r), (r + 1, r + 1)]
                for c in range(r, -1, -1):
                    route += [(r, c), (r + 1, c)]
            at_left = not at_left
            r += 2
        else:  # a last single row r, from the row above
            if at_left:
                route.append((r, 0))
                for c in range(1, r + 1):
                    route += [(r - 1, c - 1), (r, c)]
            else:
                route.append((r, r))
                for c in range(r - 1, -1, -1):
                    route += [(r - 1, c), (r, c)]
            r += 1
    return tuple(route)


def _route_actions(route: tuple[tuple[int, int], ...]) -> tuple[int, ...]:
    by_delta = {delta: action for action, delta in MOVES.items()}
    actions, prev = [], (0, 0)
    for cube in route:
        actions.append(by_delta[(cube[0] - prev[0], cube[1] - prev[1])])
        prev = cube
    return tuple(actions)


@lru_cache(maxsize=32)
def _distances(size: int) -> np.ndarray:
    """Fewest jumps between every two cubes (breadth-first search from each cube)."""
    _, jumps = _geometry(size)
    n = len(jumps)
    dist = np.full((n, n), -1, dtype=np.int64)
    for src in range(n):
        dist[src, src] = 0
        frontier = [src]
        while frontier:
            nxt = []
            for i in frontier:
                for action in MOVES:
                    j = int(jumps[i, action])
                    if j >= 0 and dist[src, j] < 0:
                        dist[src, j] = dist[src, i] + 1
                        nxt.append(j)
            frontier = nxt
    dist.setflags(write=False)
    return dist


class ScriptedExpert:
    """A MiniQbert policy `obs -> action` that follows `expert_route(size)`, with optional noise.

    It reads the colours and the agent's cube from the observation (vector or RGB), picks the
    first cube of the route that is still uncoloured and jumps along a shortest path to it,
    preferring coloured cubes on the way (so it never colours a cube out of turn unless noise
    forced it off the route). Without noise it therefore repeats `level_actions` on every
    level; after a random action it walks back to the route, and it never jumps off the
    pyramid by itself.

    With the default env (size 4, 3 lives, 3 levels) and `noise=0` it scores
    `3 × (10 × 25 + 100) = 1050` in 33 steps.

    Args:
        size: rows of the pyramid the observations come from.
        noise: probability of replacing the action with one drawn uniformly from all 6.
        rng: a `np.random.Generator` or a seed for the noise.
    """

    def __init__(
        self, size: int = 4, noise: float = 0.0, rng: np.random.Generator | int | None = None
    ) -> None:
        if not _is_int(size) or size < 2:
            raise ValueError(f"size needs to be an integer ≥ 2, actual value: {size!r}")
        if not 0.0 <= float(noise) <= 1.0:
            raise ValueError(f"noise needs to be in [0, 1], actual value: {noise!r}")
        self.size = int(size)
        self.noise = float(noise)
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self.route = expert_route(self.size)
        self.level_actions = _route_actions(self.route)
        self.n_cubes = num_cubes(self.size)
        order = []
        for r, c in self.route:
            i = cube_index(r, c)
            if i not in order:
                order.append(i)
        self._order = tuple(order)
        self._jumps = _geometry(self.size)[1]
        self._dist = _distances(self.size)
        origins = [_cube_origin(self.size, r, c) for r in range(self.size) for c in range(r + 1)]
        self._pixel_y = np.array([y for y, _ in origins])
        self._pixel_x = np.array([x for _, x in origins])

    def __call__(self, obs: np.ndarray) -> int:
        """The action for one observation."""
        colours, pos = self.decode(obs)
        if self.noise > 0.0 and self.rng.random() < self.noise:
            return int(self.rng.integers(len(ACTION_MEANINGS)))
        return self.act(colours, pos)

    def decode(self, obs: np.ndarray) -> tuple[np.ndarray, int]:
        """Cube colours (bool) and the agent's cube index from a vector or RGB observation."""
        obs = np.asarray(obs)
        side = _image_side(self.size)
        if obs.shape == (2 * self.n_cubes + 2,):
            colours = obs[: self.n_cubes] > 0.5
            pos = int(np.argmax(obs[self.n_cubes : 2 * self.n_cubes]))
            return colours, pos
        if obs.shape == (side, side, 3):
            # A cube's top-left pixel shows its colour; its centre shows the agent, if there.
            corner = obs[self._pixel_y, self._pixel_x]
            colours = np.all(corner == _CUBE_ON, axis=-1)
            mid = _CUBE_PX // 2
            centre = obs[self._pixel_y + mid, self._pixel_x + mid]
            pos = int(np.argmax(np.all(centre == _AGENT, axis=-1)))
            return colours, pos
        raise ValueError(
            f"observation of shape {obs.shape} is not a MiniQbert observation for size "
            f"{self.size}: expected {(2 * self.n_cubes + 2,)} or {(side, side, 3)}"
        )

    def act(self, colours: np.ndarray, pos: int) -> int:
        """The noise-free action for a state given as cube colours and the agent's cube."""
        target = next((i for i in self._order if not colours[i]), None)
        if target is None:  # a finished pyramid is never observed mid-game
            return NOOP
        # Standing on the target (the top cube after a respawn) does not colour it: jump to
        # a neighbour, which is then one jump from the target.
        wanted = self._dist[pos, target] - 1 if target != pos else 1
        best, best_key = NOOP, None
        for action in MOVES:  # fixed order: UP, RIGHT, LEFT, DOWN
            j = int(self._jumps[pos, action])
            if j < 0 or self._dist[j, target] != wanted:
                continue
            # Prefer landing on coloured cubes (or the target itself) on the way.
            key = 0 if (j == target or colours[j]) else 1
            if best_key is None or key < best_key:
                best, best_key = action, key
        return best


def scripted_expert(
    env_or_size: gym.Env | int = 4,
    noise: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> ScriptedExpert:
    """A `ScriptedExpert` for a MiniQbert env (possibly wrapped) or a pyramid size.

    Default settings score 1050 in 33 steps; see `ScriptedExpert`.
    """
    if isinstance(env_or_size, gym.Env):
        env = env_or_size.unwrapped
        if not isinstance(env, MiniQbertEnv):
            raise TypeError(
                f"scripted_expert needs a MiniQbertEnv or a size, got {type(env).__name__}"
            )
        size = env.size
    elif _is_int(env_or_size):
        size = int(env_or_size)
    else:
        raise TypeError(f"scripted_expert needs a MiniQbertEnv or an int size, got {env_or_size!r}")
    return ScriptedExpert(size, noise=noise, rng=rng)


class MiniQbertProfile(EnvProfile):
    """MiniQbert, a Qbert in miniature, trains as Qbert does: a life loss ends the training
    episode (otherwise falling off is a free teleport back to the top, and agents learn to
    spend lives on it until the last one runs out). Evaluation plays the full game. Its 25-
    and 100-point rewards swamp A2C's value loss at scale 1 (every mode stalls near 150-225),
    so the scripts learn at 0.01 unless `--reward-scale` says otherwise
    (`bench/results/learning_miniqbert_scaled.md`)."""

    family = "miniqbert"
    reward_scale = 0.01

    def preprocess(self, env: gym.Env, env_id: str, *, training: bool = True,
                   serve_lives: bool = True) -> gym.Env:
        from routine_gym.envs.atari import EpisodicLife

        return EpisodicLife(env) if training else env

    def scripted_expert(self, env: gym.Env, noise: float, rng: Any) -> ScriptedExpert:
        return scripted_expert(env.unwrapped, noise=noise, rng=rng)


PROFILE = MiniQbertProfile()
