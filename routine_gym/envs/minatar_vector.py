"""`MinAtarVectorEnv`: N MinAtar games, with the routines of a library, stepped in one call.

The Python path of a training script builds each env as a stack of Gymnasium wrappers
(`MinAtarEnv`, `PassiveEnvChecker`, `OrderEnforcing`, `TimeLimit`, `RecordEpisodeStatistics`,
the channels-first view, `RoutineActionWrapper`) and steps them one at a time in a
`SyncVectorEnv`, which then merges 16 `info` dicts key by key. On MinAtar the games themselves
are a small part of that: most of the time is the wrappers' Python and the merging. This vector
env does the same work in one loop over the games, with every layer of that stack written out
once:

- each game runs the primitive action or the routine it was given (a routine stops early at the
  end of an episode), counting the episode's steps against the time limit (truncation) and its
  return and length (`info["episode"]`, as `RecordEpisodeStatistics`);
- the observations of all games are turned channels-first float32 in one numpy call;
- the step's `info` is built directly as the vector env's: the ``routine_*`` keys of
  `routine_gym.macro_info` (with routines), `final_obs` and `final_info` of the envs whose
  episode ended, each with its `_key` mask, exactly as `SyncVectorEnv` with same-step autoreset
  arranges them.

Every game has a compiled core (`routine_gym/_native/_minatar_core.cpp`, the games of MinAtar
`routine_gym._native.MINATAR_VERSION`, built by `pip install` where there is a C++17 compiler): the
same game, its random draws (sticky actions, Breakout's serve, Freeway's cars, Asterix's and
Seaquest's spawns) taken from each game's own `RandomState`, stepped for all games in one C++
call that writes the observations straight into the float32 batch. A step of 16 games then
costs 6-11 µs instead of ~50 (Breakout, Asterix), ~70 (Seaquest), ~100 (Freeway) or ~270 (Space
Invaders). With `compiled=False`, or where `routine_gym._native.core("minatar_core")` finds no
core (not built, turned off by `ROUTINE_GYM_NATIVE`, or another MinAtar version installed than
the one it ports), the games go through the Python loop.

`tests/test_minatar_vector.py` checks, on fixed seeds and actions, that it returns what the
Python path returns (observations, rewards, flags and every info array), for plain actions and
routines, episode ends and truncations. `routine_gym.envs.factory.make_vector_env` picks it for
`MinAtar/*` ids; the Python path stays for video capture and `--async-envs`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from routine_gym import _native
from routine_gym.envs.minatar_interrupt import InterruptibleSteps
from routine_gym.macro_info import PAD_ACTION, masked_rows, padded_actions

__all__ = ["MinAtarVectorEnv"]

#: The episodes a step ended: their rows (in order), final observations, and `r`, `l`, `t`.
_Episodes = tuple[list[int], np.ndarray, np.ndarray, np.ndarray, np.ndarray]

#: Per game with a compiled core (by MinAtar's name): the game's variables in the order of a
#: row of the core's int32 array (`_minatar_core.cpp`'s `Field`, the last action after them;
#: Freeway's `cars`, 8 lists of 4, as 32 entries; Asterix's `entities`, 8 slots, as 40;
#: Seaquest's five lists as `_SEAQUEST_LISTS` lays them out), its
#: 10×10 maps in the order of the core's uint8 maps, and the core's step function.
_CORES = {
    "breakout": (("ball_x", "ball_y", "ball_dir", "pos", "strike", "last_x", "last_y"),
                 ("brick_map",), "breakout_step"),
    "space_invaders": (("pos", "alien_dir", "enemy_move_interval", "alien_move_timer",
                        "alien_shot_timer", "ramp_index", "shot_timer", "terminal", "ramping"),
                       ("alien_map", "f_bullet_map", "e_bullet_map"), "space_invaders_step"),
    "freeway": (("pos", "move_timer", "terminate_timer", "terminal", "cars"), (),
                "freeway_step"),
    "asterix": (("player_x", "player_y", "spawn_speed", "spawn_timer", "move_speed",
                 "move_timer", "ramp_timer", "ramp_index", "terminal", "ramping", "entities"),
                (), "asterix_step"),
    "seaquest": (("oxygen", "diver_count", "sub_x", "sub_y", "sub_or", "e_spawn_speed",
                  "e_spawn_timer", "d_spawn_timer", "move_speed", "ramp_index", "shot_timer",
                  "surface", "terminal", "ramping", "next_id", "lists"), (), "seaquest_step"),
}
#: Seaquest's lists in the core's row (`ObjectList`): their values per element and how many
#: elements the core holds (each list: its length, then that many [id, values...] records).
_SEAQUEST_LISTS = (("f_bullets", 3), ("e_bullets", 3), ("e_fish", 4), ("e_subs", 5),
                   ("divers", 4))
_SEAQUEST_CAPACITY = 48
#: The games with a compiled core, by MinAtar's name.
COMPILED_GAMES = tuple(_CORES)


def _core_row(game: Any, fields: tuple[str, ...]) -> list[int]:
    """A game's variables as a row of the compiled core's int32 array (without the last
    action): each field's value, Freeway's cars and Asterix's entity slots flattened."""
    row: list[int] = []
    for name in fields:
        if name == "cars":
            row += [int(v) for car in game.cars for v in car]
        elif name == "entities":  # Asterix's slots: [present, x, y, moves right, gold]
            for entity in game.entities:
                row += [0] * 5 if entity is None else [1, *(int(v) for v in entity)]
        elif name == "next_id":  # Seaquest: the id the core gives its next new object
            row.append(1 + sum(len(getattr(game, lst)) for lst, _ in _SEAQUEST_LISTS))
        elif name == "lists":  # Seaquest's objects, numbered from 1 in the lists' order
            next_id = 1
            for lst, width in _SEAQUEST_LISTS:
                items = getattr(game, lst)
                if len(items) > _SEAQUEST_CAPACITY:
                    raise ValueError(f"Seaquest's {lst} holds {len(items)} objects; the "
                                     f"compiled core holds {_SEAQUEST_CAPACITY}")
                row.append(len(items))
                for item in items:
                    row += [next_id, *(int(v) for v in item)]
                    next_id += 1
                row += [0] * ((_SEAQUEST_CAPACITY - len(items)) * (width + 1))
        else:
            row.append(int(getattr(game, name)))
    return row


class MinAtarVectorEnv(InterruptibleSteps, VectorEnv):
    """`num_envs` MinAtar games of `env_id` as one vector env, same-step autoreset.

    Example:
        >>> import routine_gym
        >>> from routine_gym.envs.minatar_vector import MinAtarVectorEnv
        >>> envs = MinAtarVectorEnv("MinAtar/Breakout-v1", 4, routines=[[1, 1, 2]])
        >>> obs, info = envs.reset(seed=0)
        >>> obs.shape, obs.dtype, envs.single_action_space
        ((4, 4, 10, 10), dtype('float32'), Discrete(4))
        >>> obs, reward, terminated, truncated, info = envs.step(np.array([0, 3, 3, 1]))
        >>> info["routine_length"].tolist(), info["routine_index"].tolist()
        ([1, 3, 3, 1], [-1, 0, 0, -1])
        >>> info["routine_actions"][1].tolist()
        [1, 1, 2]

    Args:
        env_id: a registered `MinAtar/*` id.
        num_envs: the number of games.
        routines: the routines to add as actions (a `RoutineLibrary` or action sequences), or
            None for the primitive actions alone (then `info` has no ``routine_*`` keys).
        record_observations: with routines, return each inner step's observation in
            ``info["routine_observations"]``.
        env_kwargs: `gym.make` keyword arguments (`sticky_action_prob`, `difficulty_ramping`,
            `max_episode_steps`).
        compiled: step the games in the compiled core: None uses it where the game has one (all
            five do) and `routine_gym._native.core` finds it, True requires it, False keeps the
            Python loop.
            A stop rule (`set_stop_rule`, `routine_gym.interruption`) may end routines early.
            With the core the games' state lives in it between resets: reseed and reset them
            through this env's `reset`, not through `games[i]`.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, env_id: str, num_envs: int, *,
                 routines: Sequence[Sequence[int]] | None = None,
                 record_observations: bool = False,
                 env_kwargs: dict[str, Any] | None = None,
                 compiled: bool | None = None) -> None:
        from routine_gym.wrapper import _validate_routines

        spec = gym.spec(env_id)
        if spec.entry_point != "routine_gym.envs.minatar:MinAtarEnv":
            raise ValueError(f"MinAtarVectorEnv runs MinAtar's games, not {env_id!r}")
        kwargs = {**spec.kwargs, **(env_kwargs or {})}
        self.max_episode_steps = kwargs.pop("max_episode_steps", spec.max_episode_steps)
        # `MinAtarEnv` through its registered entry point (`minatar.py` builds this class in
        # its profile, so importing it here would be an import cycle).
        make_game = gym.envs.registration.load_env_creator(spec.entry_point)
        self.games = [make_game(**kwargs) for _ in range(num_envs)]
        self.num_envs = num_envs
        self.spec = spec

        n = self.games[0].action_space.n
        self.routines = _validate_routines(routines, n) if routines is not None else ()
        self.has_routines = routines is not None and len(self.routines) > 0
        self.num_primitive_actions = n
        self.max_routine_length = max((len(r) for r in self.routines), default=1)
        self.record_observations = bool(record_observations) and self.has_routines
        sequences = tuple((a,) for a in range(n)) + self.routines
        # Each action's primitives, as MinAtar's own action numbers.
        action_set = self.games[0].action_set
        self._sequences = tuple(tuple(action_set[a] for a in s) for s in sequences)
        self._padded_actions = padded_actions(sequences, self.max_routine_length)

        h, w, c = self.games[0].observation_space.shape
        self._state_shape = (h, w, c)
        self.single_observation_space = spaces.Box(0.0, 1.0, shape=(c, h, w), dtype=np.float32)
        self.single_action_space = spaces.Discrete(n + len(self.routines))
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self.metadata = {**self.metadata, "render_modes": []}
        self.render_mode = None
        self.closed = False

        self._games = [env.game for env in self.games]  # MinAtar's own Environment objects
        self._start_times = [0.0] * num_envs
        game_name = kwargs["game"]
        if compiled and game_name not in COMPILED_GAMES:
            raise ValueError(f"compiled=True: {env_id} has no compiled core (the games with one: "
                             f"{', '.join(COMPILED_GAMES)})")
        if compiled and (reason := _native.unavailable("minatar_core")) is not None:
            raise ImportError(f"compiled=True needs the compiled core 'minatar_core': {reason}")
        core = _native.core("minatar_core") if compiled is not False else None
        self.compiled = core is not None and game_name in COMPILED_GAMES
        if self.compiled:
            # The games' state lives in these arrays between resets (`_load_core`); each game's
            # sticky action is drawn from its own RandomState, kept alive here.
            self._core_fields, self._core_maps, step_name = _CORES[game_name]
            self._core_step = getattr(core, step_name)
            width = len(_core_row(self._games[0].env, self._core_fields)) + 1
            self._core = np.zeros((num_envs, width), dtype=np.int32)
            self._maps = np.zeros((num_envs, len(self._core_maps), h, w), dtype=np.uint8)
            self._rng_owners: list[np.random.BitGenerator] = []
            self._core_sequences = padded_actions(self._sequences, self.max_routine_length)
            self._core_lengths = np.array([len(seq) for seq in self._sequences], dtype=np.int64)
            stickies = {environment.sticky_action_prob for environment in self._games}
            self._sticky = float(stickies.pop())
            limit = self.max_episode_steps
            self._limit = -1 if limit is None else int(limit)
            self._elapsed: Any = np.zeros(num_envs, dtype=np.int64)
            self._returns: Any = np.zeros(num_envs, dtype=np.float64)
            self._lengths: Any = np.zeros(num_envs, dtype=np.int64)
            self._executed_scratch = np.zeros(num_envs, dtype=np.int64)
            self._episode_returns = np.zeros(num_envs, dtype=np.float64)
            self._episode_lengths = np.zeros(num_envs, dtype=np.int64)
            self._batch_shape = (num_envs, c, h, w)
            self._final_scratch = np.zeros((num_envs, c, h, w), dtype=np.float32)
            self._load_core()  # the games as MinAtar built them, as the Python loop finds them
        else:
            self._elapsed = [0] * num_envs
            self._returns = [0.0] * num_envs
            self._lengths = [0] * num_envs

    def get_action_meanings(self) -> list[str]:
        """The names of the primitive actions, then one per routine, as the routine wrapper."""
        from routine_gym.library import routine_name

        meanings = self.games[0].get_action_meanings()
        return meanings + [f"R{k}:{routine_name(r, meanings)}"
                           for k, r in enumerate(self.routines)]

    def _view(self, states: np.ndarray) -> np.ndarray:
        """(..., H, W, C) booleans to (..., C, H, W) float32, the agent's view (a transpose
        and one copy; `np.moveaxis` costs three times as much in Python around them)."""
        d = states.ndim
        return states.transpose(*range(d - 3), d - 1, d - 3, d - 2).astype(np.float32,
                                                                         order="C")

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset needs {self.num_envs} seeds, got {len(seeds)}")
        states = np.empty((self.num_envs, *self._state_shape), dtype=bool)
        for i, game in enumerate(self.games):
            states[i], _ = game.reset(seed=seeds[i])
            self._start_episode(i)
        if self.compiled:
            self._load_core()
        return self._view(states), {}

    def _load_core(self) -> None:
        """Copy the games' state (after their reset in Python) into the compiled core's arrays."""
        for i, environment in enumerate(self._games):
            self._core[i, :-1] = _core_row(environment.env, self._core_fields)
            self._core[i, -1] = int(environment.last_action)
            for k, name in enumerate(self._core_maps):
                self._maps[i, k] = getattr(environment.env, name) != 0
        # The bit generators themselves (a RandomState can swap its own for a new one).
        self._rng_owners = [environment.random._bit_generator for environment in self._games]
        self._rngs = self._rng_addresses()

    def __getstate__(self) -> dict[str, Any]:
        """What `copy` and `pickle` keep: all but the compiled core's generator addresses, which
        belong to this process's objects (`__setstate__` takes them from the copied games)."""
        state = self.__dict__.copy()
        state.pop("_rngs", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        if self.compiled:
            self._rngs = self._rng_addresses()

    def _rng_addresses(self) -> np.ndarray:
        """Where each game's `bitgen_t` is, in this process: what the compiled core draws from."""
        return np.array([bits.ctypes.bit_generator.value for bits in self._rng_owners],
                        dtype=np.uint64)

    def _start_episode(self, i: int) -> None:
        self._elapsed[i] = 0
        self._returns[i] = 0.0
        self._lengths[i] = 0
        self._start_times[i] = time.perf_counter()

    def step(self, actions: np.ndarray):
        if self._stop_rule is not None:  # routines that may stop early (`minatar_interrupt`)
            return self._step_interruptible(actions)
        if self.compiled:
            return self._step_compiled(actions)
        actions = self._checked(actions)
        # Python ints: a numpy element costs more than the game
        return self._finish(actions, *self._run_python(actions.tolist(), actions))

    def _checked(self, actions: Any) -> np.ndarray:
        """`actions` as an array of `num_envs` actions of the action space, or a one-line error."""
        e = self.num_envs
        actions = np.asarray(actions)
        if actions.shape != (e,):
            raise ValueError(f"step needs {e} actions, got an array of shape {actions.shape}")
        if actions.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers, got an array of {actions.dtype}")
        chosen = actions.tolist()
        if min(chosen) < 0 or max(chosen) >= len(self._sequences):
            outside = next(a for a in chosen if not 0 <= a < len(self._sequences))
            raise ValueError(f"action {outside} is outside the action space "
                             f"{self.single_action_space}")
        return actions

    def _run_python(self, chosen: list[int], actions: np.ndarray):
        """Step the games one after the other in Python; what `_finish` takes."""
        e, length = self.num_envs, self.max_routine_length
        states = np.empty((e, *self._state_shape), dtype=bool)
        final_states = np.empty((e, *self._state_shape), dtype=bool)
        rewards, terminated, truncated = [0.0] * e, [False] * e, [False] * e
        routines, record = self.has_routines, self.record_observations
        if routines:
            step_lengths = [1] * e
            step_rewards = np.zeros((e, length), dtype=np.float64)
            step_terminated = np.zeros((e, length), dtype=bool)
            step_truncated = np.zeros((e, length), dtype=bool)
            step_actions = self._padded_actions[actions]  # a copy: fancy indexing
            if record:
                inner_states = np.zeros((e, length, *self._state_shape), dtype=bool)
        episodes: list[tuple[int, float, int, float]] = []
        sequences, games, limit = self._sequences, self._games, self.max_episode_steps
        elapsed, returns, lengths = self._elapsed, self._returns, self._lengths

        # Python numbers and lists inside the loop: a numpy element costs more than the game.
        # MinAtar's `Environment.act` written out (the sticky action, then the game's own `act`),
        # and the game's own `state`: one Python call less each, per primitive step; the
        # equivalence tests compare with the public `act` of the Python path.
        for i, a in enumerate(chosen):
            environment = games[i]
            game, sticky = environment.env, environment.sticky_action_prob
            total, executed, term, trunc = 0.0, 0, False, False
            for primitive in sequences[a]:
                if environment.random.rand() < sticky:
                    primitive = environment.last_action
                environment.last_action = primitive
                reward, term = game.act(primitive)
                reward, term = float(reward), bool(term)
                elapsed[i] += 1
                trunc = limit is not None and elapsed[i] >= limit
                total += reward
                if routines:
                    step_rewards[i, executed] = reward
                    if record:
                        inner_states[i, executed] = game.state()
                executed += 1
                if term or trunc:
                    break
            returns[i] += total
            lengths[i] += executed
            rewards[i], terminated[i], truncated[i] = total, term, trunc
            if routines:
                step_lengths[i] = executed
                if executed < len(sequences[a]):
                    step_actions[i, executed:] = PAD_ACTION
                step_terminated[i, executed - 1] = term
                step_truncated[i, executed - 1] = trunc
            if term or trunc:
                final_states[i] = inner_states[i, executed - 1] if record else game.state()
                episodes.append((i, returns[i], lengths[i],
                                 round(time.perf_counter() - self._start_times[i], 6)))
                # `MinAtarEnv.reset()` without a seed, written out (the game was seeded by the
                # vector env's first reset): MinAtar's sticky action does not carry over.
                environment.last_action = 0
                environment.reset()
                states[i] = game.state()
                self._start_episode(i)
            else:
                states[i] = inner_states[i, executed - 1] if record else game.state()
        rewards = np.array(rewards, dtype=np.float64)
        terminated = np.array(terminated, dtype=bool)
        truncated = np.array(truncated, dtype=bool)
        done = terminated | truncated
        routine = None
        if routines:
            routine = {"routine_length": np.array(step_lengths, dtype=np.int64),
                       "routine_actions": step_actions, "routine_rewards": step_rewards,
                       "routine_terminated": step_terminated,
                       "routine_truncated": step_truncated}
            if record:
                routine["routine_observations"] = self._view(inner_states)
        ended = None
        if episodes:
            r, l, t = np.zeros(e), np.zeros(e, dtype=np.int64), np.zeros(e)
            for i, ret, steps, seconds in episodes:
                r[i], l[i], t[i] = ret, steps, seconds
            ended = ([i for i, *_ in episodes], self._view(final_states[done]), r, l, t)
        return self._view(states), rewards, terminated, truncated, done, routine, ended

    def _step_compiled(self, actions: Any):
        """`step` in the compiled core: the games, their episodes' sums and resets in one call,
        and no more Python around it than the step's `info` needs (a step with no routines
        and no episode end returns an empty `info` after four allocations and the call)."""
        e = self.num_envs
        if type(actions) is not np.ndarray or actions.dtype != np.int64 \
                or actions.shape != (e,) or not actions.flags.c_contiguous:
            actions = np.ascontiguousarray(self._checked(actions), dtype=np.int64)
        routines = self.has_routines
        rewards = np.empty(e, dtype=np.float64)
        terminated, truncated = np.empty(e, dtype=bool), np.empty(e, dtype=bool)
        states = np.empty(self._batch_shape, dtype=np.float32)
        if routines:  # returned as `routine_length` (a new array); else only counted
            executed = np.empty(e, dtype=np.int64)
            step_rewards = np.zeros((e, self.max_routine_length), dtype=np.float64)
            inner = np.zeros((e, self.max_routine_length, *self._batch_shape[1:]),
                             dtype=np.float32) if self.record_observations else None
        else:
            executed, step_rewards, inner = self._executed_scratch, None, None
        try:
            ended = self._core_step(
                self._core, self._maps, self._rngs, self._sticky, actions,
                self._core_sequences, self._core_lengths, self._elapsed, self._limit, rewards,
                terminated, truncated, executed, step_rewards, inner, states,
                self._final_scratch, self._returns, self._lengths, self._episode_returns,
                self._episode_lengths)
        except ValueError:
            self._checked(actions)  # an action outside the space: the Python path's message
            raise
        if not (ended or routines):
            return states, rewards, terminated, truncated, {}
        done = terminated | truncated
        routine, episodes = None, None
        if routines:
            rows, length = np.arange(e), self.max_routine_length
            step_terminated = np.zeros((e, length), dtype=bool)
            step_truncated = np.zeros((e, length), dtype=bool)
            step_terminated[rows, executed - 1] = terminated
            step_truncated[rows, executed - 1] = truncated
            step_actions = self._padded_actions[actions]  # a copy: fancy indexing
            step_actions[np.arange(length) >= executed[:, None]] = PAD_ACTION
            routine = {"routine_length": executed, "routine_actions": step_actions,
                       "routine_rewards": step_rewards, "routine_terminated": step_terminated,
                       "routine_truncated": step_truncated}
            if inner is not None:
                routine["routine_observations"] = inner
        if ended:
            # The core has ended the episodes (their returns and lengths) and started the next;
            # their clocks start here.
            rows = np.flatnonzero(done).tolist()
            seconds, now, starts = np.zeros(e), time.perf_counter(), self._start_times
            for i in rows:
                seconds[i], starts[i] = round(now - starts[i], 6), now
            episodes = (rows, self._final_scratch[rows], self._episode_returns.copy(),
                        self._episode_lengths.copy(), seconds)
        return self._finish(actions, states, rewards, terminated, truncated, done, routine,
                            episodes)

    def _finish(self, actions: np.ndarray, states: np.ndarray, rewards: np.ndarray,
                terminated: np.ndarray, truncated: np.ndarray, done: np.ndarray,
                routine: dict | None, episodes: _Episodes | None):
        """The step's return: `info` arranged as `SyncVectorEnv` with same-step autoreset does.

        `done`: `terminated | truncated`. `episodes`: None, or the ended envs' rows (in order),
        their final observations, and the `RecordEpisodeStatistics` arrays `r`, `l`, `t` of all
        envs (0 where none ended)."""
        e = self.num_envs
        info: dict[str, Any] = {}
        if routine is not None:
            routine = {"routine_index": np.where(actions >= self.num_primitive_actions,
                                                 actions - self.num_primitive_actions, -1),
                       **routine}
            # The envs whose episode ended report their step in final_info (the top level is
            # their reset's, which has no routine keys), as SyncVectorEnv arranges it.
            if not done.all():
                info.update(masked_rows(routine, ~done))
        if episodes is not None:
            rows, finals, r, l, t = episodes
            final_info: dict[str, Any] = {}
            if routine is not None:
                final_info.update(masked_rows(routine, done))
            # The envs with an episode end are the done ones, in order.
            episode = {"r": r, "l": l, "t": t, "_r": done.copy(), "_l": done.copy(),
                       "_t": done.copy()}
            final_info["episode"], final_info["_episode"] = episode, done.copy()
            final_obs = np.empty(e, dtype=object)  # None but where an episode ended
            for i, view in zip(rows, finals, strict=True):
                final_obs[i] = view
            info["final_obs"], info["_final_obs"] = final_obs, done.copy()
            info["final_info"], info["_final_info"] = final_info, done.copy()
        return states, rewards, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        for game in self.games:
            game.close()

