"""`ALEVectorEnv`: N ALE games of the training view, emulated by ale-py's C++ vector env.

The Python path of a training script builds each Atari env as a stack of Gymnasium wrappers
(`AtariEnv` with ALE's frame skip of 4 and grey frames, `RecordEpisodeStatistics`, `NoopReset`,
`EpisodicLife`, `FireReset`, the sign-clipped reward, `ResizeObservation` to 84×84,
`FrameStackObservation` of 4, `RoutineActionWrapper`) and steps them one after the other in a
`SyncVectorEnv`, each emulating, grey-scaling and resizing its frames while the others wait.

Here each game is an `ale_py.AtariVectorEnv` of one env, which emulates the frame skip and
grey-scales and resizes the last frame in C++, on a thread of its own. A vector step sends
every game its first primitive; each game that comes back with more to do (the rest of its
routine, or the no-ops and FIRE of the reset after its episode ended) is sent its next
primitive at once, so a game runs its routine without waiting for the others, and the C++
threads emulate while Python books the games that came back.

What the wrappers add stays in Python, written once for all games, with the wrappers' own
rules: no-op starts (1 to 30 NOOP steps drawn as `NoopReset` draws them), a life loss ending the
training episode and the NOOP step of `EpisodicLife`'s reset after it, FIRE on reset, rewards
clipped to their sign (the C++ clipping is off, so the logged return is the full game's
unclipped score, as `RecordEpisodeStatistics` below the wrappers logs it), the stack of the
last 4 frames (filled with the first frame at a reset), the routines, and the `info` of a
`SyncVectorEnv` with same-step autoreset (ALE's ``lives``, ``episode_frame_number`` and
``frame_number``, the ``routine_*`` keys, ``final_obs`` and ``final_info`` with
``episode`` where a game ended, each with its `_key` mask).

Seeds: `reset(seed=s)` seeds game `i` as `AtariEnv.reset(seed=s + i)` does (ALE's random seed
and the no-op draws from the same `SeedSequence`), so on fixed seeds and actions both paths
return the same observations, rewards, ends and infos (`tests/test_atari_vector.py`), with two
differences, both harmless to a learner:

- ALE's seed is an int32 and the C++ games take only positive ones; for a seed whose ALE seed
  is negative (about half of them) the game gets another, positive one, so its sticky actions
  (v5: probability 0.25 per frame) repeat on other frames than the Python path's, with the same
  probability. Without sticky actions, or with a positive ALE seed, the two paths agree.
- A game that ends in the middle of a frame skip stops there in C++, where the Python `AtariEnv`
  plays the skip's remaining frames; so ``final_obs`` at a game over can differ in its last
  frame. A learner never bootstraps from the state after a game over (it is terminal).

Only the training view is here: evaluation, video capture and demo recording (`--record-demo`
records on a single evaluation env, where the injected steps are marked) keep the Python path.
"""

from __future__ import annotations

import time
from collections.abc import Generator, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv

from routine_gym.macro_info import PAD_ACTION, masked_rows, padded_actions

__all__ = ["ALEVectorEnv", "unsupported_kwargs"]

#: The `gym.make` keyword arguments of ALE's envs that the C++ games take as they are.
_KWARGS = ("game", "obs_type", "frameskip", "repeat_action_probability", "full_action_space",
           "max_num_frames_per_episode")
_SIZE = 84  # the frames' height and width, as `ResizeObservation(env, (84, 84))`
_STACK = 4  # frames per observation, as `FrameStackObservation(env, 4)`
_NOOP_MAX = 30  # as `NoopReset(env, noop_max=30)`

# What a game's step returns to the code that drives it: the new frame, the unclipped reward,
# game over, truncated (ALE's frame limit), and ALE's info (lives, episode and total frames).
_Result = tuple[np.ndarray, float, bool, bool, dict[str, int]]


def unsupported_kwargs(env_id: str, kwargs: dict[str, Any]) -> str | None:
    """Why `ALEVectorEnv` cannot build `env_id` with these `gym.make` keyword arguments (the
    Python path then builds it), or None."""
    spec = gym.spec(env_id)
    if spec.entry_point != "ale_py.env:AtariEnv":
        return f"{env_id} is not one of ALE's envs"
    kwargs = {**spec.kwargs, **kwargs}
    other = sorted(set(kwargs) - set(_KWARGS))
    if other:
        return f"the C++ games take no {', '.join(other)}"
    if kwargs.get("obs_type") != "grayscale":
        return "the C++ games give grey frames only"
    if not isinstance(kwargs.get("frameskip"), int) or isinstance(kwargs["frameskip"], bool):
        return "the C++ games need a fixed frame skip"
    if spec.max_episode_steps is not None:
        return "the C++ games have no TimeLimit"
    return None


class ALEVectorEnv(VectorEnv):
    """`num_envs` games of ALE env `env_id` in the training view, same-step autoreset.

    Example:
        >>> import numpy as np
        >>> from routine_gym.envs.atari_vector import ALEVectorEnv
        >>> envs = ALEVectorEnv("ALE/Qbert-v5", 2, routines=[[5, 5, 5]],
        ...                     env_kwargs={"frameskip": 4, "obs_type": "grayscale"})
        >>> obs, info = envs.reset(seed=0)
        >>> obs.shape, obs.dtype, envs.single_action_space
        ((2, 4, 84, 84), dtype('uint8'), Discrete(7))
        >>> obs, reward, terminated, truncated, info = envs.step(np.array([6, 0]))
        >>> info["routine_length"].tolist(), info["routine_actions"][0].tolist()
        ([3, 1], [5, 5, 5])
        >>> envs.close()

    Args:
        env_id: a registered ALE id (`ALE/Qbert-v5`, `QbertNoFrameskip-v4`).
        num_envs: the number of games.
        routines: the routines to add as actions (a `RoutineLibrary` or action sequences), or
            None for the primitive actions alone (then `info` has no ``routine_*`` keys).
        record_observations: with routines, return each inner step's observation in
            ``info["routine_observations"]``.
        env_kwargs: `gym.make` keyword arguments over the registered ones (routine-gym's
            defaults: ``frameskip=4``, ``obs_type="grayscale"``); `unsupported_kwargs` says which
            the C++ games cannot take.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, env_id: str, num_envs: int, *,
                 routines: Sequence[Sequence[int]] | None = None,
                 record_observations: bool = False,
                 env_kwargs: dict[str, Any] | None = None) -> None:
        import ale_py

        from routine_gym.wrapper import _validate_routines

        reason = unsupported_kwargs(env_id, env_kwargs or {})
        if reason is not None:
            raise ValueError(f"ALEVectorEnv cannot build {env_id}: {reason}")
        spec = gym.spec(env_id)
        kwargs = {**spec.kwargs, **(env_kwargs or {})}
        # One C++ vector env per game, so that each game is sent its next primitive alone.
        self._games = [ale_py.AtariVectorEnv(
            kwargs["game"], 1, num_threads=1, frameskip=kwargs["frameskip"],
            repeat_action_probability=kwargs.get("repeat_action_probability", 0.25),
            full_action_space=kwargs.get("full_action_space", False),
            max_num_frames_per_episode=2**31 - 1,  # the limit is kept below (`_result`)
            img_height=_SIZE, img_width=_SIZE, grayscale=True, stack_num=1, maxpool=False,
            noop_max=0, use_fire_reset=False, episodic_life=False, life_loss_info=False,
            reward_clipping=False) for _ in range(num_envs)]
        self._ales = [game.ale for game in self._games]
        # ALE's frame limit (`AtariEnv`'s truncation), kept here: the C++ game does not show the
        # frame it truncates at (it returns the step before's).
        self._max_frames = kwargs.get("max_num_frames_per_episode", 108_000) or 0
        self.num_envs = num_envs
        self.spec = spec

        names = {action: name for name, action in ale_py.Action.__members__.items()}
        self._meanings = [names[a] for a in self._ales[0].get_action_set()]
        if self._meanings[0] != "NOOP":
            raise ValueError(f"{env_id}: no-op starts need action 0 to be NOOP")
        self._fire = self._meanings.index("FIRE") if "FIRE" in self._meanings else None
        n = len(self._meanings)
        self.routines = _validate_routines(routines, n) if routines is not None else ()
        self.has_routines = routines is not None and len(self.routines) > 0
        self.num_primitive_actions = n
        self.max_routine_length = max((len(r) for r in self.routines), default=1)
        self.record_observations = bool(record_observations) and self.has_routines
        self._sequences = tuple((a,) for a in range(n)) + self.routines
        self._padded_actions = padded_actions(self._sequences, self.max_routine_length)

        self.single_observation_space = spaces.Box(0, 255, shape=(_STACK, _SIZE, _SIZE),
                                                   dtype=np.uint8)
        self.single_action_space = spaces.Discrete(n + len(self.routines))
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space,
                                                              num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, num_envs)
        self.metadata = {**self.metadata, "render_modes": []}
        self.render_mode = None
        self.closed = False

        self._stacks = np.zeros((num_envs, _STACK, _SIZE, _SIZE), dtype=np.uint8)
        self._lives = [0] * num_envs  # EpisodicLife's lives
        self._game_over = [True] * num_envs  # EpisodicLife's game_over
        self._returns = [0.0] * num_envs  # RecordEpisodeStatistics' counters
        self._lengths = [0] * num_envs
        self._start_times = [0.0] * num_envs
        self._noops = [np.random.default_rng() for _ in range(num_envs)]  # NoopReset's draws

    def get_action_meanings(self) -> list[str]:
        """The names of the primitive actions, then one per routine, as the routine wrapper."""
        from routine_gym.library import routine_name

        return self._meanings + [f"R{k}:{routine_name(r, self._meanings)}"
                                 for k, r in enumerate(self.routines)]

    # -- one game ---------------------------------------------------------------------------

    def _result(self, i: int, out: tuple) -> _Result:
        obs, reward, terminated, truncated, info = out
        frame = obs[0, 0]
        reward = float(reward[0])
        self._returns[i] += reward
        self._lengths[i] += 1
        ale = {"lives": int(info["lives"][0]),
               "episode_frame_number": int(info["episode_frame_number"][0]),
               "frame_number": int(info["frame_number"][0])}
        truncated = 0 < self._max_frames <= ale["episode_frame_number"]
        return frame, reward, bool(terminated[0]), truncated, ale

    def _new_game(self, i: int, seed: int | None) -> _Result:
        """`RecordEpisodeStatistics.reset` over `AtariEnv.reset(seed=seed)`: a new game (with a
        seed: ALE's random seed and the no-op draws seeded as `AtariEnv.seed_game` seeds them)."""
        ale_seed = -1
        if seed is not None:
            np_seed, ale_seed = np.random.SeedSequence(seed).generate_state(n_words=2)
            self._noops[i] = gym.utils.seeding.np_random(int(np_seed))[0]
            # ALE's seed as `AtariEnv` sets it (an int32); the C++ games take positive seeds
            # only, so a negative one is made positive: that game's sticky actions then repeat
            # on other frames than the Python path's (the same probability).
            ale_seed = int(np.int32(ale_seed))
            if ale_seed <= 0:
                ale_seed = (ale_seed & 0x7FFFFFFF) or 1
        obs, info = self._ales[i].reset([0], [ale_seed])
        result = self._result(i, (obs, np.zeros(1), np.zeros(1, bool), np.zeros(1, bool), info))
        self._returns[i], self._lengths[i] = 0.0, 0
        self._start_times[i] = time.perf_counter()
        return result

    def _noop_reset(self, i: int, seed: int | None) -> Generator[int, _Result, _Result]:
        """`NoopReset.reset`: a new game, then 1..30 NOOP steps (a new game if one ends it)."""
        result = self._new_game(i, seed)
        for _ in range(int(self._noops[i].integers(1, _NOOP_MAX + 1))):
            result = yield 0
            if result[2] or result[3]:
                result = self._new_game(i, None)
        return result

    def _episodic_reset(self, i: int, seed: int | None) -> Generator[int, _Result, _Result]:
        """`EpisodicLife.reset`: after a game over (or with a seed) a new game, else only a
        NOOP step, the same life's game going on."""
        if self._game_over[i] or seed is not None:
            result = yield from self._noop_reset(i, seed)
        else:
            result = yield 0
            if result[2] or result[3]:
                result = yield from self._noop_reset(i, None)
        self._game_over[i] = False
        self._lives[i] = result[4]["lives"]
        return result

    def _step_life(self, i: int, result: _Result) -> bool:
        """`EpisodicLife.step`'s books for a step's result: whether it ends the training
        episode (game over, or a life lost while lives remain)."""
        lives = result[4]["lives"]
        self._game_over[i] = result[2] or result[3]
        life_lost = 0 < lives < self._lives[i]
        self._lives[i] = lives
        return result[2] or life_lost

    def _reset(self, i: int, seed: int | None = None) -> Generator[int, _Result, _Result]:
        """The whole reset of the training view: `FireReset.reset` (FIRE after
        `EpisodicLife.reset`; that reset again if FIRE ends the episode), then the frame stack
        filled with the first frame (`FrameStackObservation`)."""
        result = yield from self._episodic_reset(i, seed)
        if self._fire is not None:
            result = yield self._fire
            if self._step_life(i, result) or result[3]:
                result = yield from self._episodic_reset(i, None)
        self._stacks[i] = result[0]
        return result

    def _step(self, i: int, action: int, books: _StepBooks) -> Generator[int, _Result, None]:
        """Game `i`'s part of a vector step: the primitive or routine `action` (a routine stops
        at the end of the training episode), and with an episode's end the same-step reset."""
        record = self.record_observations
        executed = 0
        for primitive in self._sequences[action]:
            result = yield primitive
            terminated, truncated = self._step_life(i, result), result[3]
            stack = self._stacks[i]
            stack[:-1] = stack[1:]
            stack[-1] = result[0]
            reward = result[1]
            books.rewards[i, executed] = (reward > 0) - (reward < 0)  # the sign of the reward
            if record:
                books.observations[i, executed] = stack
            executed += 1
            if terminated or truncated:
                break
        books.lengths[i], books.step_infos[i] = executed, result[4]
        books.terminated[i, executed - 1], books.truncated[i, executed - 1] = (terminated,
                                                                               truncated)
        if terminated or truncated:
            books.final_obs[i] = self._stacks[i].copy()
            if result[2] or result[3]:  # the game itself ended: RecordEpisodeStatistics logs it
                books.episodes[i] = (self._returns[i], self._lengths[i],
                                     round(time.perf_counter() - self._start_times[i], 6))
            reset = yield from self._reset(i)
            books.reset_infos[i] = reset[4]

    # -- all games --------------------------------------------------------------------------

    def _drive(self, programs: dict[int, Generator[int, _Result, Any]]) -> dict[int, Any]:
        """Run each game's program to its end: every game with a primitive to take is sent it,
        and each one that comes back is sent its next at once. Returns the programs' values."""
        ales, values, pending = self._ales, {}, []
        for i, program in programs.items():
            try:
                action = next(program)
            except StopIteration as stop:
                values[i] = stop.value
                continue
            ales[i].send([action], [1.0])
            pending.append(i)
        while pending:
            going = []
            for i in pending:
                result = self._result(i, ales[i].recv())
                try:
                    action = programs[i].send(result)
                except StopIteration as stop:
                    values[i] = stop.value
                    continue
                ales[i].send([action], [1.0])
                going.append(i)
            pending = going
        return values

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset needs {self.num_envs} seeds, got {len(seeds)}")
        results = self._drive({i: self._reset(i, s) for i, s in enumerate(seeds)})
        return self._stacks.copy(), _merged([results[i][4] for i in range(self.num_envs)])

    def step(self, actions: np.ndarray):
        e = self.num_envs
        actions = np.asarray(actions)
        if actions.shape != (e,):
            raise ValueError(f"step needs {e} actions, got an array of shape {actions.shape}")
        outside = (actions < 0) | (actions >= len(self._sequences))
        if outside.any():
            raise ValueError(f"action {actions[outside][0]} is outside the action space "
                             f"{self.single_action_space}")
        books = _StepBooks(e, self.max_routine_length, self.record_observations)
        self._drive({i: self._step(i, a, books) for i, a in enumerate(actions.tolist())})

        rewards = books.rewards.sum(axis=1)
        terminated = books.terminated.any(axis=1)
        truncated = books.truncated.any(axis=1)
        done = terminated | truncated
        top = [books.reset_infos[i] if done[i] else books.step_infos[i] for i in range(e)]
        info = _merged(top)
        if self.has_routines:
            actions_taken = self._padded_actions[actions]  # a copy: fancy indexing
            for i in range(e):
                actions_taken[i, books.lengths[i]:] = PAD_ACTION
            routine = {"routine_index": np.where(actions >= self.num_primitive_actions,
                                                 actions - self.num_primitive_actions, -1),
                       "routine_length": books.lengths, "routine_actions": actions_taken,
                       "routine_rewards": books.rewards,
                       "routine_terminated": books.terminated,
                       "routine_truncated": books.truncated}
            if self.record_observations:
                routine["routine_observations"] = books.observations
            # The envs whose episode ended report their step in final_info (the top level is
            # their reset's, which has no routine keys), as SyncVectorEnv arranges it.
            if not done.all():
                info.update(masked_rows(routine, ~done))
        if done.any():
            ended = np.flatnonzero(done)
            final_info = _merged([books.step_infos[i] if done[i] else None for i in range(e)])
            if self.has_routines:
                final_info.update(masked_rows(routine, done))
            if books.episodes:
                logged = np.zeros(e, dtype=bool)
                logged[list(books.episodes)] = True
                episode = {"r": np.zeros(e, dtype=np.float64), "l": np.zeros(e, dtype=np.int64),
                           "t": np.zeros(e, dtype=np.float64)}
                for i, (ret, steps, seconds) in books.episodes.items():
                    episode["r"][i], episode["l"][i], episode["t"][i] = ret, steps, seconds
                for key in ("r", "l", "t"):
                    episode[f"_{key}"] = logged.copy()
                final_info["episode"], final_info["_episode"] = episode, logged
            final_obs = np.full(e, None, dtype=object)
            for i in ended:
                final_obs[i] = books.final_obs[i]
            info["final_obs"], info["_final_obs"] = final_obs, done.copy()
            info["final_info"], info["_final_info"] = final_info, done.copy()
        return self._stacks.copy(), rewards, terminated, truncated, info

    def close_extras(self, **kwargs: Any) -> None:
        self._ales.clear()
        self._games.clear()  # the C++ envs stop their threads when freed


class _StepBooks:
    """What the games' programs write during one vector step (rows: games)."""

    def __init__(self, num_envs: int, length: int, record: bool) -> None:
        self.lengths = np.zeros(num_envs, dtype=np.int64)
        self.rewards = np.zeros((num_envs, length), dtype=np.float64)  # clipped, per step
        self.terminated = np.zeros((num_envs, length), dtype=bool)
        self.truncated = np.zeros((num_envs, length), dtype=bool)
        self.observations = (np.zeros((num_envs, length, _STACK, _SIZE, _SIZE), dtype=np.uint8)
                             if record else None)
        self.step_infos: list[dict[str, int]] = [{}] * num_envs
        self.reset_infos: list[dict[str, int]] = [{}] * num_envs
        self.final_obs: dict[int, np.ndarray] = {}
        self.episodes: dict[int, tuple[float, int, float]] = {}


def _merged(infos: list[dict[str, int] | None]) -> dict[str, Any]:
    """ALE's per-game info (`lives`, `episode_frame_number`, `frame_number`) as `SyncVectorEnv`
    merges it: an int64 array per key with its `_key` mask (None: a game that gave none)."""
    mask = np.array([i is not None for i in infos])
    out: dict[str, Any] = {}
    for key in ("lives", "episode_frame_number", "frame_number"):
        out[key] = np.array([0 if i is None else i[key] for i in infos], dtype=np.int64)
        out[f"_{key}"] = mask.copy()
    return out
