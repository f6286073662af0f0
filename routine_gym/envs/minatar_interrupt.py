"""`MinAtarVectorEnv`'s routines with a stop rule: all games' inner steps in lockstep.

Without a stop rule each game runs its whole routine in one go (the compiled core's one call,
or the Python loop's inner loop), and nothing here runs. With one (`set_stop_rule`, see
`routine_gym.interruption`), a step runs inner step j of every game still inside its routine
together: before each j ≥ 1 the rule is asked once, for all of them (one batched forward pass
of the policy), with the observations they reached and their next primitives; a game it stops,
or whose episode ended, or whose routine is done, leaves the step there. Each inner step goes
through the same game code as before, the compiled core called on the rows still running (a
routine of one primitive each) or the Python loop's steps, so the games see the same actions
and draw the same random numbers (each game has its own `RandomState`): with a rule that never
stops, a step returns what it returns without one (`tests/test_interruption.py`).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from routine_gym.interruption import StopRule
from routine_gym.macro_info import PAD_ACTION

__all__ = ["InterruptibleSteps"]

#: The episodes one inner step ended, by env: (final observation, return, length, seconds).
_Ended = dict[int, tuple[np.ndarray, float, int, float]]


class InterruptibleSteps:
    """`MinAtarVectorEnv`'s stop rule and the step that asks it (a mixin of that class only:
    it reads the env's games, core and bookkeeping)."""

    #: What may stop a routine early; None runs every routine in full (the plain `step`).
    _stop_rule: StopRule | None = None

    def set_stop_rule(self, rule: StopRule | None) -> None:
        """Let `rule` stop a routine before each inner step j ≥ 1 (None: run routines in full).

        Where it says stop, the routine ends with `routine_length` j, its info padded as at an
        episode's end, and ``routine_interrupted`` (a key of every step's info while a rule is
        set) is True. Without routines there is nothing to interrupt and the rule is not kept.
        """
        env: Any = self
        self._stop_rule = rule if env.has_routines else None
        self._action_lengths = (env._padded_actions != PAD_ACTION).sum(axis=1)

    def _step_interruptible(self, actions: Any):
        """`step` with the stop rule: the games' inner steps in lockstep (the module's doc)."""
        env: Any = self
        actions = np.ascontiguousarray(env._checked(actions), dtype=np.int64)
        e, length = env.num_envs, env.max_routine_length
        shape = env.single_observation_space.shape
        plan = env._padded_actions[actions]  # each game's primitives (a copy), then padding
        lengths = self._action_lengths[actions]
        states = np.empty((e, *shape), dtype=np.float32)
        rewards = np.zeros(e, dtype=np.float64)
        terminated, truncated = np.zeros(e, dtype=bool), np.zeros(e, dtype=bool)
        executed, interrupted = np.zeros(e, dtype=np.int64), np.zeros(e, dtype=bool)
        step_rewards = np.zeros((e, length), dtype=np.float64)
        inner = (np.zeros((e, length, *shape), dtype=np.float32) if env.record_observations
                 else None)
        ended: _Ended = {}
        rows = np.arange(e)
        for j in range(length):
            if j:
                rows = rows[~(terminated[rows] | truncated[rows]) & (lengths[rows] > j)]
                if rows.size:
                    stop = np.asarray(self._stop_rule(states[rows], plan[rows, j]), dtype=bool)
                    interrupted[rows[stop]] = True
                    rows = rows[~stop]
                if not rows.size:
                    break
            step = self._compiled_primitives if env.compiled else self._python_primitives
            reward, term, trunc, reached, after = step(rows, plan[rows, j], ended)
            rewards[rows] += reward  # from 0.0, step by step: the routine's sum as before
            step_rewards[rows, j] = reward
            terminated[rows], truncated[rows] = term, trunc
            executed[rows] += 1
            states[rows] = after
            if inner is not None:
                inner[rows, j] = reached

        plan[np.arange(length) >= executed[:, None]] = PAD_ACTION
        last = (np.arange(e), executed - 1)
        step_terminated = np.zeros((e, length), dtype=bool)
        step_truncated = np.zeros((e, length), dtype=bool)
        step_terminated[last], step_truncated[last] = terminated, truncated
        routine = {"routine_length": executed, "routine_actions": plan,
                   "routine_rewards": step_rewards, "routine_terminated": step_terminated,
                   "routine_truncated": step_truncated}
        if inner is not None:
            routine["routine_observations"] = inner
        routine["routine_interrupted"] = interrupted
        episodes = None
        if ended:
            done_rows = sorted(ended)
            r, l, t = np.zeros(e), np.zeros(e, dtype=np.int64), np.zeros(e)
            for i in done_rows:
                _, r[i], l[i], t[i] = ended[i]
            episodes = (done_rows, np.stack([ended[i][0] for i in done_rows]), r, l, t)
        return env._finish(actions, states, rewards, terminated, truncated,
                           terminated | truncated, routine, episodes)

    def _python_primitives(self, rows: np.ndarray, primitives: np.ndarray, ended: _Ended):
        """One primitive step of the games `rows` in Python, as the Python loop steps them:
        their rewards, flags, the observations reached and those after (a new episode's first
        where one ended, recorded in `ended`)."""
        env: Any = self
        k, limit = len(rows), env.max_episode_steps
        rewards, terminated, truncated = [0.0] * k, [False] * k, [False] * k
        reached = np.empty((k, *env._state_shape), dtype=bool)
        after = np.empty((k, *env._state_shape), dtype=bool)
        for m, (i, a) in enumerate(zip(rows.tolist(), primitives.tolist(), strict=True)):
            environment = env._games[i]
            game = environment.env
            primitive = env._sequences[a][0]  # MinAtar's own number of primitive a
            if environment.random.rand() < environment.sticky_action_prob:
                primitive = environment.last_action
            environment.last_action = primitive
            reward, term = game.act(primitive)
            reward, term = float(reward), bool(term)
            env._elapsed[i] += 1
            trunc = limit is not None and env._elapsed[i] >= limit
            env._returns[i] += reward
            env._lengths[i] += 1
            rewards[m], terminated[m], truncated[m] = reward, term, trunc
            reached[m] = game.state()
            if term or trunc:
                ended[i] = (env._view(reached[m]), env._returns[i], env._lengths[i],
                            round(time.perf_counter() - env._start_times[i], 6))
                environment.last_action = 0  # `MinAtarEnv.reset()`, as the Python loop's
                environment.reset()
                after[m] = game.state()
                env._start_episode(i)
            else:
                after[m] = reached[m]
        return rewards, terminated, truncated, env._view(reached), env._view(after)

    def _compiled_primitives(self, rows: np.ndarray, primitives: np.ndarray, ended: _Ended):
        """One primitive step of the games `rows` in the compiled core (their rows of its
        arrays, copied out and back unless all games run): what `_python_primitives` returns."""
        env: Any = self
        k, whole = len(rows), len(rows) == env.num_envs
        arrays = [env._core, env._maps, env._rngs, env._elapsed, env._returns, env._lengths]
        if not whole:
            arrays = [a[rows] for a in arrays]
        core, maps, rngs, elapsed, returns, lengths = arrays
        rewards = np.empty(k, dtype=np.float64)
        terminated, truncated = np.empty(k, dtype=bool), np.empty(k, dtype=bool)
        executed = np.empty(k, dtype=np.int64)
        after = np.empty((k, *env._batch_shape[1:]), dtype=np.float32)
        finals = np.empty_like(after)
        episode_returns, episode_lengths = np.empty(k), np.empty(k, dtype=np.int64)
        count = env._core_step(
            core, maps, rngs, env._sticky, np.ascontiguousarray(primitives, dtype=np.int64),
            env._core_sequences, env._core_lengths, elapsed, env._limit, rewards, terminated,
            truncated, executed, None, None, after, finals, returns, lengths, episode_returns,
            episode_lengths)
        if not whole:
            (env._core[rows], env._maps[rows], env._elapsed[rows], env._returns[rows],
             env._lengths[rows]) = core, maps, elapsed, returns, lengths
        reached = after
        if count:
            done = np.flatnonzero(terminated | truncated)
            reached = after.copy()
            reached[done] = finals[done]
            now, starts = time.perf_counter(), env._start_times
            for m in done.tolist():
                i = int(rows[m])
                ended[i] = (finals[m], float(episode_returns[m]), int(episode_lengths[m]),
                            round(now - starts[i], 6))
                starts[i] = now
        return rewards, terminated, truncated, reached, after
