"""`RoutineActionWrapper`: add routines (macro-actions of primitive actions) to a Discrete env.

The wrapper of the RAPL paper: the agent chooses among the `n` primitive actions and the `K`
routines of a library, and a routine runs its primitive actions one inner step each. The
primitive transitions it went through come back in `info`, so a learner can use them (RAPL's
primitive-level critic update) while any other consumer sees an ordinary env whose reward is
the true, undiscounted return.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.core import ObsType
from gymnasium.vector.utils import concatenate, create_empty_array

from routine_gym.interruption import StopRule
from routine_gym.library import RoutineLibrary, routine_name
from routine_gym.macro_info import (
    new_step_arrays,
    padded_actions,
    write_routine_info,
)

__all__ = ["RoutineActionWrapper", "merge_final"]

#: Steps served by one allocation of the `routine_*` info arrays (see `_new_info_blocks`).
_BLOCK_ROWS = 256
# What `_new_buffers` makes: views of per-instance scratch memory, left out of a copy.
_BUFFERS = ("_sequence_buffers", "_rows", "_actions_out", "_rewards_out", "_terminated_out",
            "_truncated_out")
# Observation spaces whose samples are numpy arrays (or integers) of a fixed shape and dtype.
_ARRAY_SPACES = (spaces.Box, spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)


class RoutineActionWrapper(
    gym.Wrapper[ObsType, int, ObsType, int], gym.utils.RecordConstructorArgs
):
    """Extends a `Discrete(n)` action space with `K` routines to `Discrete(n + K)`.

    Action `a < n` is the primitive action `a`; action `n + k` runs routine `k`, a fixed
    sequence of primitive actions, one inner `env.step` per primitive. A routine stops early
    when the inner env terminates or truncates. Like :class:`gymnasium.wrappers.RepeatAction`,
    one wrapper step may be several inner steps and the reward is their plain (undiscounted) sum,
    so `RecordEpisodeStatistics`, Stable-Baselines3 or a person reading the returns see the true
    return; unlike `RepeatAction`, each action has its own sequence, and every executed primitive
    transition is reported in `info`, so a learner can discount them itself (RAPL) or ignore them
    (the MacroAction baseline).

    The step returns the last inner observation, the summed reward, the last inner step's
    `terminated`/`truncated`, and the last inner `info` extended with the ``routine_*`` keys of
    `routine_gym.macro_info` (the contract it shares with CompILE's `OptionActionWrapper`):
    the routine's index (`-1` for a primitive action), the primitive steps it executed, and
    their actions, rewards, flags and (with `record_observations=True`) observations.

    A primitive action is reported as a routine of length 1, so a learner has one code path.
    Every array has the same length, :attr:`max_routine_length` (the longest routine, 1 with no
    routines): the first `routine_length` entries are the executed steps and the rest padding
    (action `-1`, reward `0.0`, flags `False`, observation zeros), which is what lets the vector
    envs stack the infos of sub-envs that ran routines of different lengths.

    Recording observations copies one observation per primitive step, plus padding; pass
    `record_observations=False` when the learner does not need the intermediate states.

    Example:
        >>> import gymnasium as gym
        >>> from routine_gym.wrapper import RoutineActionWrapper
        >>> env = RoutineActionWrapper(gym.make("CartPole-v1"), [[0, 1], [1, 1, 1]])
        >>> env.action_space
        Discrete(4)
        >>> env.get_action_meanings()
        ['0', '1', 'R0:0 1', 'R1:1 1 1']
        >>> obs, info = env.reset(seed=123)
        >>> obs, reward, terminated, truncated, info = env.step(3)  # routine 1: push right 3 times
        >>> reward  # sum of 3 inner-step rewards
        3.0
        >>> info["routine_index"], info["routine_length"], info["routine_actions"]
        (1, 3, array([1, 1, 1]))
        >>> info["routine_rewards"], info["routine_observations"].shape
        (array([1., 1., 1.]), (3, 4))
        >>> obs, reward, terminated, truncated, info = env.step(0)  # a primitive: length 1
        >>> info["routine_index"], info["routine_length"], info["routine_actions"]
        (-1, 1, array([ 0, -1, -1]))
        >>> info["routine_rewards"]
        array([1., 0., 0.])

    Attributes:
        routines: the routines, each a tuple of primitive actions, routine `k` being action `n + k`.
        num_primitive_actions: `n`, the size of the inner env's action space.
        max_routine_length: the length of every `routine_*` array in `info`.
        record_observations: whether `info` carries ``routine_observations``.
        library: the `RoutineLibrary` given to the constructor, or None for plain sequences.
    """

    #: What may stop a routine early (`set_stop_rule`); None runs every routine in full.
    _stop_rule: StopRule | None = None

    def __init__(
        self,
        env: gym.Env[ObsType, Any],
        routines: RoutineLibrary | Sequence[Sequence[int]],
        record_observations: bool = True,
    ):
        """Wrap `env`, adding one action per routine.

        Args:
            env: the env to wrap; its action space must be `Discrete(n)` (with `start=0`).
            routines: a :class:`~routine_gym.library.RoutineLibrary`, or a sequence of routines,
                each a non-empty sequence of primitive actions in `[0, n)` (lists, tuples or
                integer numpy arrays). An empty sequence gives `Discrete(n)` back unchanged but
                with the `routine_*` info keys.
            record_observations: whether to stack the intermediate observations into
                ``info["routine_observations"]``.

        Raises:
            TypeError: the action space is not `Discrete`, or a routine is not a sequence.
            ValueError: the action space starts at a value other than 0, a routine is empty,
                or a routine holds something that is not a primitive action of the env.
        """
        action_space = env.action_space
        if not isinstance(action_space, spaces.Discrete):
            raise TypeError(
                "RoutineActionWrapper needs an env with a Discrete action space, "
                f"actual action space: {action_space!r}"
            )
        if int(action_space.start) != 0:
            # Routines, the info arrays and the -1 padding all speak of actions 0..n-1; an env
            # that numbers its actions from elsewhere can be shifted by a small ActionWrapper.
            raise ValueError(
                "RoutineActionWrapper needs a Discrete action space starting at 0, "
                f"actual action space: {action_space!r}"
            )
        n = int(action_space.n)
        routine_tuples = _validate_routines(routines, n)

        # Plain lists of ints, so that `env.spec` is JSON-serialisable and `gym.make(env.spec)`
        # re-creates the wrapper (a RoutineLibrary's scores and provenance are not kept there).
        gym.utils.RecordConstructorArgs.__init__(
            self,
            routines=[list(r) for r in routine_tuples],
            record_observations=bool(record_observations),
        )
        gym.Wrapper.__init__(self, env)

        self.routines: tuple[tuple[int, ...], ...] = routine_tuples
        self.num_primitive_actions: int = n
        self.max_routine_length: int = max((len(r) for r in routine_tuples), default=1)
        self.record_observations: bool = bool(record_observations)
        self.library: RoutineLibrary | None = (
            routines if isinstance(routines, RoutineLibrary) else None
        )
        self.action_space = spaces.Discrete(n + len(routine_tuples))

        # The primitive sequence of every action of Discrete(n + K), primitives included.
        self._sequences: tuple[tuple[int, ...], ...] = (
            tuple((a,) for a in range(n)) + routine_tuples
        )
        # Array observations are written straight into a per-step array; structured ones
        # (Dict, Tuple, ...) go through Gymnasium's batching helpers, which cost ~10x more.
        obs_space = env.observation_space
        self._array_observations = isinstance(obs_space, _ARRAY_SPACES)
        if self._array_observations:
            self._stacked_shape = (self.max_routine_length, *obs_space.shape)
            self._observation_dtype = obs_space.dtype
        elif self.record_observations:
            self._pad_observation = _zero_observation(obs_space)
        self._new_buffers()

    def _new_buffers(self) -> None:
        """The memoryviews `step` writes through: each action's primitives, copied into the
        info row of a routine's step, and the first info blocks (`_new_info_blocks`)."""
        self._sequence_buffers = [
            memoryview(row) for row in padded_actions(self._sequences, self.max_routine_length)
        ]
        self._new_info_blocks()

    def __getstate__(self) -> dict[str, Any]:
        """The state `copy` and `pickle` save: all but the memoryviews (which neither can
        save) and the info blocks they view; a copy makes its own (`__setstate__`)."""
        state = self.__dict__.copy()
        for key in _BUFFERS:
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._new_buffers()

    def _new_info_blocks(self) -> None:
        """Allocate the arrays the next `_BLOCK_ROWS` steps take their info rows from.

        Four new small arrays per step are most of the wrapper's cost. A row of a pre-filled
        block is a cheaper new array (a view; taken by iterating the block, which costs about
        half of indexing it), its padding is already in place, and it shares no memory with
        any other step's row, so a consumer may keep or modify what it was given. The
        executed steps are written through memoryviews of the blocks: one entry costs about
        half of numpy's item assignment.
        """
        length = self.max_routine_length
        blocks = new_step_arrays((_BLOCK_ROWS, length))
        # Each step takes the next (start of its row in the flattened blocks, four rows).
        self._rows = zip(range(0, _BLOCK_ROWS * length, length), *blocks, strict=True)
        (self._actions_out, self._rewards_out, self._terminated_out,
         self._truncated_out) = (memoryview(block.reshape(-1)) for block in blocks)

    def step(self, action: int) -> tuple[ObsType, SupportsFloat, bool, bool, dict[str, Any]]:
        """Run the primitive action or routine `action`, stopping early at the end of episode.

        Args:
            action: an action of `Discrete(n + K)`.

        Returns:
            The last observation, the summed reward, the last `terminated` and `truncated`, and
            the last inner info extended with the ``routine_*`` keys (see the class docstring).

        Raises:
            ValueError: `action` is not an integer of the wrapper's action space.
        """
        try:
            a = operator.index(action)
        except TypeError:
            raise ValueError(
                f"action {action!r} is not an integer action of {self.action_space}"
            ) from None
        sequences = self._sequences
        if not 0 <= a < len(sequences):
            raise ValueError(f"action {action!r} is outside the action space {self.action_space}")
        n = self.num_primitive_actions
        # This step's rows of the info blocks (see `_new_info_blocks`), which hold the padding
        # already: only the executed steps are written.
        try:
            start, actions_row, rewards_row, terminated_row, truncated_row = next(self._rows)
        except StopIteration:
            self._new_info_blocks()
            start, actions_row, rewards_row, terminated_row, truncated_row = next(self._rows)
        # Observations are recorded as they arrive (an env may return one array it updates in
        # place): array ones straight into the stacked, zero-padded array, structured ones
        # into a list that Gymnasium's batching helpers stack at the end.
        stacked = observations = None
        if self.record_observations:
            if self._array_observations:
                # np.zeros: the padding is zero already (and large arrays are zeroed lazily).
                stacked = np.zeros(self._stacked_shape, dtype=self._observation_dtype)
            else:
                observations = []
        if a < n:
            # A primitive goes to the inner env as the caller gave it, as it would without the
            # wrapper; one inner step needs no loop.
            obs, reward, terminated, truncated, info = self.env.step(action)
            total_reward = float(reward)
            self._rewards_out[start] = total_reward
            self._actions_out[start] = a
            executed = 1
            if stacked is not None:
                stacked[0] = obs
            elif observations is not None:
                observations.append(obs)
        elif self._stop_rule is not None:
            obs, total_reward, terminated, truncated, info, executed, interrupted = \
                self._run_interruptible(sequences[a], start, stacked, observations)
            self._actions_out[start : start + executed] = self._sequence_buffers[a][:executed]
        else:
            env_step = self.env.step
            rewards_out = self._rewards_out
            total_reward = 0.0
            executed = 0
            for primitive in sequences[a]:
                obs, reward, terminated, truncated, info = env_step(primitive)
                reward = float(reward)
                total_reward += reward
                rewards_out[start + executed] = reward
                if stacked is not None:
                    stacked[executed] = obs
                elif observations is not None:
                    observations.append(obs)
                executed += 1
                if terminated or truncated:
                    break
            if executed == 1:
                self._actions_out[start] = sequences[a][0]
            else:
                self._actions_out[start : start + executed] = self._sequence_buffers[a][:executed]
        if terminated:
            self._terminated_out[start + executed - 1] = True
        if truncated:
            self._truncated_out[start + executed - 1] = True

        if observations is not None:
            stacked = self._stack_structured(observations)
        write_routine_info(
            info, a - n if a >= n else -1, executed, actions_row, rewards_row, terminated_row,
            truncated_row, stacked)
        if self._stop_rule is not None:
            info["routine_interrupted"] = a >= n and interrupted
        return obs, total_reward, terminated, truncated, info

    def set_stop_rule(self, rule: StopRule | None) -> None:
        """Let `rule` stop a routine before each inner step j ≥ 1 (None: run routines in full).

        The rule is shown the observation the routine reached (as a batch of one) and the
        primitive it would take next (`routine_gym.interruption.StopRule`); where it says
        stop, the routine ends with `routine_length` j, padded as at an episode's end, and
        `info["routine_interrupted"]` (reported at every step while a rule is set) is True.
        """
        self._stop_rule = rule

    def _run_interruptible(self, sequence: tuple[int, ...], start: int, stacked: Any,
                           observations: list | None):
        """Run a routine's primitives, asking the stop rule before each one after the first;
        what `step` needs: the last step's five values, the steps executed, and whether the
        rule stopped the routine."""
        rule, rewards_out = self._stop_rule, self._rewards_out
        total_reward, executed, interrupted = 0.0, 0, False
        obs: Any = None  # the observation reached, set by the first step (never asked about)
        for primitive in sequence:
            if executed and rule(np.asarray(obs)[None], np.array([primitive]))[0]:
                interrupted = True
                break
            obs, reward, terminated, truncated, info = self.env.step(primitive)
            reward = float(reward)
            total_reward += reward
            rewards_out[start + executed] = reward
            if stacked is not None:
                stacked[executed] = obs
            elif observations is not None:
                observations.append(obs)
            executed += 1
            if terminated or truncated:
                break
        return obs, total_reward, terminated, truncated, info, executed, interrupted

    def _stack_structured(self, observations: list[Any]) -> Any:
        """Structured (Dict, Tuple, ...) observations stacked and zero-padded to
        `max_routine_length`."""
        padding = [self._pad_observation] * (self.max_routine_length - len(observations))
        out = create_empty_array(self.observation_space, n=self.max_routine_length, fn=np.empty)
        return concatenate(self.observation_space, observations + padding, out)

    def get_action_meanings(self) -> list[str]:
        """Names of the `n + K` actions: the inner env's, then `"R{k}:{routine}"` per routine.

        The primitive names come from `env.unwrapped.get_action_meanings()` when the inner env
        has it (ALE, Procgen, MiniQbert), else from the routine library, else they are the action
        ids (`"0"`, `"1"`, ...). A routine is named by its index and its actions separated by
        spaces, as :meth:`RoutineLibrary.name` prints it: `"R0:UP UP RIGHT"`.
        """
        n = self.num_primitive_actions
        meanings: list[str] | None = None
        inner = getattr(self.env.unwrapped, "get_action_meanings", None)
        if callable(inner):
            meanings = [str(m) for m in inner()]
        elif self.library is not None and self.library.action_meanings is not None:
            meanings = list(self.library.action_meanings)
        if meanings is None or len(meanings) != n:
            meanings = [str(a) for a in range(n)]
        return meanings + [
            f"R{k}:{routine_name(routine, meanings)}" for k, routine in enumerate(self.routines)
        ]


def _validate_routines(
    routines: RoutineLibrary | Sequence[Sequence[int]], n: int
) -> tuple[tuple[int, ...], ...]:
    """The routines as tuples of ints, after checking every action is one of `range(n)`."""
    if isinstance(routines, RoutineLibrary):
        routines = routines.routines
    if isinstance(routines, str | bytes) or not isinstance(routines, Sequence | np.ndarray):
        raise TypeError(
            f"routines must be a RoutineLibrary or a sequence of action sequences, "
            f"actual value: {routines!r}"
        )
    result = []
    for k, routine in enumerate(routines):
        if isinstance(routine, str | bytes) or not isinstance(routine, Sequence | np.ndarray):
            raise TypeError(
                f"routine {k} must be a sequence of primitive actions, actual value: {routine!r} "
                "(for a single routine pass a list holding it, e.g. [[0, 1, 1]])"
            )
        if len(routine) == 0:
            raise ValueError(f"routine {k} is empty; a routine needs at least one action")
        actions = []
        for a in routine:
            if isinstance(a, bool | np.bool_) or not isinstance(a, int | np.integer):
                raise ValueError(
                    f"routine {k} has action {a!r} of type {type(a).__name__}; actions must be "
                    f"integers in [0, {n})"
                )
            if not 0 <= a < n:
                raise ValueError(
                    f"routine {k} has action {int(a)}, outside the env's primitive actions [0, {n})"
                )
            actions.append(int(a))
        result.append(tuple(actions))
    return tuple(result)


def _zero_observation(space: spaces.Space) -> Any:
    """The all-zeros observation of `space`, which pads ``routine_observations``."""
    if isinstance(space, _ARRAY_SPACES):
        return create_empty_array(space, n=1, fn=np.zeros)[0]
    if isinstance(space, spaces.Dict):
        return {key: _zero_observation(sub) for key, sub in space.spaces.items()}
    if isinstance(space, spaces.Tuple):
        return tuple(_zero_observation(sub) for sub in space.spaces)
    raise TypeError(
        "record_observations=True needs an observation space built from Box, Discrete, "
        f"MultiDiscrete, MultiBinary, Dict and Tuple, actual space: {space!r}; "
        "pass record_observations=False"
    )


def merge_final(info: dict, key: str, done: np.ndarray) -> np.ndarray:
    """`info[key]` of a vector env per env, from `final_info` for envs whose episode just ended.

    With same-step autoreset the step that ends an episode returns the reset's info, and the
    ended step's info (the routine it ran) moves to `info["final_info"]`.

    Example:
        >>> info = {"routine_length": np.array([2, 0]), "_routine_length": np.array([True, False]),
        ...         "final_info": {"routine_length": np.array([0, 3]),
        ...                        "_routine_length": np.array([False, True])}}
        >>> merge_final(info, "routine_length", np.array([False, True])).tolist()
        [2, 3]
    """
    value = info[key].copy() if key in info else None
    if done.any():
        final = info["final_info"]
        mask = final[f"_{key}"]
        if value is None:
            value = np.zeros_like(final[key])
        value[mask] = final[key][mask]
    return value
