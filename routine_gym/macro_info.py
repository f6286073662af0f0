"""The `info` contract of the macro-action wrappers: the `routine_*` keys and who fills them.

Two wrappers turn one agent decision into several primitive env steps: `RoutineActionWrapper`
(`routine_gym/wrapper.py`: a routine of RAPL's library, a fixed action sequence) and
`OptionActionWrapper` (`routine_gym/baselines/compile/options.py`: a CompILE option, whose
actions depend on the observations). Both return the last inner observation, the plain
(undiscounted) sum of the executed steps' rewards, the last inner step's
`terminated`/`truncated`, and the last inner `info` extended in place (as Gymnasium's own
`RecordEpisodeStatistics` does) with these keys:

- ``routine_index`` (int): `k` for macro-action `k` (routine or option), `-1` for a primitive.
- ``routine_length`` (int): the primitive steps executed, `1 ≤ ℓ ≤` the macro-action's length
  (a routine's own length, an option's `max_length`); a primitive action is a macro-action of
  length 1, so a learner has one code path.
- ``routine_actions`` (np.int64 array): the executed primitive actions, then `PAD_ACTION` (-1).
- ``routine_rewards`` (np.float64 array): the reward of each executed step, then `0.0`.
- ``routine_terminated``, ``routine_truncated`` (bool arrays): each executed step's flags, then
  `False`; only the last executed entry can be True, since a macro-action stops at the first
  end of episode.
- ``routine_observations`` (array, or the nested structure of the observation space): the
  observation after each executed step, stacked, then zeros; only `RoutineActionWrapper` with
  `record_observations=True` writes it.

Every array of one wrapper has the same length (its longest macro-action), so
`SyncVectorEnv`/`AsyncVectorEnv` can stack the infos of sub-envs that ran macro-actions of
different lengths, and with zero padding `np.sum(gamma ** np.arange(L) * info["routine_rewards"])`
is the discounted macro reward without a mask. The learners read these keys (`algos/rapl_a2c.py`
and `algos/compile_a2c.py` through `routine_gym.wrapper.merge_final`, `algos/rapl_sqil.py`) and
never ask which wrapper wrote them.

The contract lives in a module of its own rather than in `wrapper.py` because it belongs to
neither wrapper: it is the interface between both of them and the learners, and a module of its
own lets the CompILE baseline share it without depending on RAPL's wrapper.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["PAD_ACTION", "ROUTINE_INFO_KEYS", "masked_rows", "new_step_arrays",
           "padded_actions", "write_routine_info"]

#: The action stored in the padding entries of `info["routine_actions"]`; never a valid action.
PAD_ACTION = -1
#: The keys every macro-action step writes (``routine_observations`` is optional, see above).
ROUTINE_INFO_KEYS = ("routine_index", "routine_length", "routine_actions", "routine_rewards",
                     "routine_terminated", "routine_truncated")


def new_step_arrays(
    shape: int | tuple[int, ...],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The per-step arrays of ``routine_actions``, ``routine_rewards``, ``routine_terminated``
    and ``routine_truncated``, filled with their padding (`PAD_ACTION`, `0.0`, `False`).

    Args:
        shape: `L` for one step's arrays, or `(rows, L)` for a block of steps' rows.

    Example:
        >>> actions, rewards, terminated, truncated = new_step_arrays(3)
        >>> actions.tolist(), rewards.tolist(), terminated.tolist()
        ([-1, -1, -1], [0.0, 0.0, 0.0], [False, False, False])
    """
    return (np.full(shape, PAD_ACTION, dtype=np.int64), np.zeros(shape, dtype=np.float64),
            np.zeros(shape, dtype=np.bool_), np.zeros(shape, dtype=np.bool_))


def padded_actions(sequences: tuple[tuple[int, ...], ...], length: int) -> np.ndarray:
    """The ``routine_actions`` row of every action run in full: `[len(sequences), length]`,
    each action's primitive sequence, then `PAD_ACTION`.

    Example:
        >>> padded_actions(((0,), (1,), (1, 0, 1)), 3).tolist()
        [[0, -1, -1], [1, -1, -1], [1, 0, 1]]
    """
    table = np.full((len(sequences), length), PAD_ACTION, dtype=np.int64)
    for a, sequence in enumerate(sequences):
        table[a, : len(sequence)] = sequence
    return table


def write_routine_info(
    info: dict[str, Any],
    index: int,
    length: int,
    actions: np.ndarray,
    rewards: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    observations: Any = None,
) -> dict[str, Any]:
    """Extend the last inner `info` in place with the ``routine_*`` keys of one step.

    Args:
        info: the last inner step's info.
        index: `k` for macro-action `k`, `-1` for a primitive action.
        length: the primitive steps executed.
        actions, rewards, terminated, truncated: the padded per-step arrays
            (`new_step_arrays`), stored as they are (not copied).
        observations: the stacked, padded observations, or None to leave the key out.

    Returns:
        `info`.

    Example:
        >>> actions, rewards, terminated, truncated = new_step_arrays(2)
        >>> actions[0], rewards[0] = 1, 1.0
        >>> info = write_routine_info({}, -1, 1, actions, rewards, terminated, truncated)
        >>> info["routine_index"], info["routine_length"], info["routine_actions"].tolist()
        (-1, 1, [1, -1])
    """
    info["routine_index"] = index
    info["routine_length"] = length
    info["routine_actions"] = actions
    info["routine_rewards"] = rewards
    info["routine_terminated"] = terminated
    info["routine_truncated"] = truncated
    if observations is not None:
        info["routine_observations"] = observations
    return info


def masked_rows(arrays: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """Each array with the rows outside `mask` zeroed, and its `_key` mask: `SyncVectorEnv`'s
    layout for the keys only some sub-envs reported (the vector envs that build their info
    themselves, `routine_gym.envs.minatar_vector` and `atari_vector`, use it).

    Example:
        >>> out = masked_rows({"routine_length": np.array([3, 1])}, np.array([False, True]))
        >>> out["routine_length"].tolist(), out["_routine_length"].tolist()
        ([0, 1], [False, True])
    """
    out: dict[str, np.ndarray] = {}
    for key, value in arrays.items():
        if mask.all():
            out[key] = value
        else:
            masked = np.zeros_like(value)
            masked[mask] = value[mask]
            out[key] = masked
        out[f"_{key}"] = mask.copy()
    return out
