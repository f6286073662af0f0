"""The agent's replay memory of `algos/rapl_sqil.py`: one stream of decisions over one stream of
frames, each frame stored once, frame stacks rebuilt by index."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["FrameReplayMemory"]


class FrameReplayMemory:
    """Replay memory of one env's decisions that stores each frame once (uint8 Atari stacks).

    Entries are the observations of one stream of decisions. `start_episode(obs)` writes an
    episode's first observation; `add(action, length, terminated, next_obs)` records the
    decision taken at the newest entry (`length` primitive steps, ℓ, as executed) and writes
    `next_obs` as the next entry. At the end of an episode `next_obs` is the final observation,
    which is stored (so a truncated episode can bootstrap from it) but never starts a transition.

    With `frame_stack = F > 1`, observations are `(F, *frame)` stacks (Gymnasium's
    `FrameStackObservation`, oldest frame first). The stack sits *under* the
    `RoutineActionWrapper`, so a routine of ℓ steps pushes ℓ frames into it, and the stacks of
    the next few decisions hold frames from inside the routine. The memory therefore keeps a
    ring of frames apart from its ring of decisions: `add` appends the newest `min(ℓ, F)` frames
    of `next_obs` (no later stack can reach further back), and each entry points at its newest
    frame. A stack is rebuilt by stepping back through the frames, repeating the episode's first
    frame before its start, which is how `FrameStackObservation` pads (`padding_type="reset"`).
    The rebuilt stacks are exactly the observations the env returned. An entry whose stack
    reaches a frame already overwritten is never sampled.

    Memory cost: `capacity` counts *frames*; the ring of decisions has as many slots, at about
    40 B each. An entry keeps `min(ℓ, F)` frames (one for an episode's first observation), so
    the memory holds `capacity` decisions with primitive actions only (plain SQIL) and down to
    `capacity / F` when every decision is a routine of `F` or more steps. 10^6 Atari frames
    take 10^6 × 84 × 84 B ≈ 7 GB instead of 28 GB for the stacks (56 GB with the next stacks);
    the arrays are allocated lazily. With `F = 1` each entry stores its whole observation.

    Example:
        A routine of 3 steps pushes 3 frames: the stack after it (and the one after that) is
        rebuilt from frames of the routine, not from the entries of earlier decisions.

        >>> memory = FrameReplayMemory(8, (3, 1), np.uint8, frame_stack=3)
        >>> memory.start_episode(np.array([[1], [1], [1]], np.uint8))
        >>> memory.add(0, 1, False, np.array([[1], [1], [2]], np.uint8))
        >>> memory.add(6, 3, False, np.array([[3], [4], [5]], np.uint8))  # a routine, ℓ = 3
        >>> memory.add(2, 1, True, np.array([[4], [5], [6]], np.uint8))
        >>> memory.frames[:, 0].tolist()  # 1 + 1 + 3 + 1 frames stored, the rest never written
        [1, 2, 3, 4, 5, 6, 0, 0]
        >>> len(memory), memory.stacks(np.array([0, 1, 2, 3]))[:, :, 0].tolist()
        (3, [[1, 1, 1], [1, 1, 2], [3, 4, 5], [4, 5, 6]])
    """

    def __init__(
        self,
        capacity: int,
        obs_shape: Sequence[int],
        obs_dtype: Any,
        frame_stack: int = 1,
    ) -> None:
        if capacity < frame_stack + 2:
            raise ValueError(f"capacity needs to be ≥ frame_stack + 2, actual value: {capacity}")
        if frame_stack < 1:
            raise ValueError(f"frame_stack needs to be ≥ 1, actual value: {frame_stack}")
        obs_shape = tuple(obs_shape)
        if frame_stack > 1 and (len(obs_shape) < 2 or obs_shape[0] != frame_stack):
            raise ValueError(
                f"with frame_stack={frame_stack}, observations must be ({frame_stack}, *frame) "
                f"stacks, got shape {obs_shape}"
            )
        self.capacity = int(capacity)
        self.obs_shape = obs_shape
        self.frame_stack = int(frame_stack)
        frame_shape = obs_shape[1:] if frame_stack > 1 else obs_shape
        # The ring of frames: frame number g (counting every frame ever written) is in slot
        # g % capacity, until frame g + capacity overwrites it.
        self.frames = np.zeros((self.capacity, *frame_shape), dtype=obs_dtype)
        self.num_frames = 0
        # The ring of decisions: entry number d (counted likewise) is in slot d % capacity.
        self.actions = np.zeros(self.capacity, dtype=np.int64)
        self.lengths = np.ones(self.capacity, dtype=np.int64)
        self.terminated = np.zeros(self.capacity, dtype=bool)
        self.has_next = np.zeros(self.capacity, dtype=bool)
        self.newest_frame = np.zeros(self.capacity, dtype=np.int64)  # the entry's, by number
        self.episode_frame = np.zeros(self.capacity, dtype=np.int64)  # its episode's first
        self.pos = 0  # the slot written next
        self.full = False
        self._num_entries = 0
        # For an O(1) len: transitions recorded in all, and before each entry was written.
        self._num_transitions = 0
        self._transitions_before = np.zeros(self.capacity, dtype=np.int64)
        self._oldest_valid = 0  # number of the oldest entry whose stack is kept
        self._episode_frame = 0  # number of the current episode's first frame

    def __len__(self) -> int:
        """Transitions that can be sampled."""
        if self._oldest_valid == self._num_entries:
            return 0
        slot = self._oldest_valid % self.capacity
        return self._num_transitions - int(self._transitions_before[slot])

    def _append_frames(self, frames: np.ndarray) -> None:
        slots = (self.num_frames + np.arange(len(frames))) % self.capacity
        self.frames[slots] = frames
        self.num_frames += len(frames)

    def _write(self, first: bool) -> None:
        if first:
            self._episode_frame = self.num_frames - 1
        p = self.pos
        self.newest_frame[p] = self.num_frames - 1
        self.episode_frame[p] = self._episode_frame
        self.has_next[p] = False
        self._transitions_before[p] = self._num_transitions
        self._num_entries += 1
        self.pos = (p + 1) % self.capacity
        self.full = self.full or self.pos == 0
        # Entries leave `_valid` oldest first: when the ring of decisions overwrites them, or
        # when their stacks reach overwritten frames.
        oldest = max(self._oldest_valid, self._num_entries - self.capacity)
        while not self._stack_kept(self.newest_frame[oldest % self.capacity]):
            oldest += 1  # stops at the newest entry, whose stack always is kept
        self._oldest_valid = oldest

    def start_episode(self, obs: np.ndarray) -> None:
        """Write the first observation of an episode (for stacks: all frames equal)."""
        obs = np.asarray(obs)
        if obs.shape != self.obs_shape:
            raise ValueError(f"observation of shape {obs.shape}, expected {self.obs_shape}")
        if self.frame_stack > 1 and not (obs == obs[-1:]).all():
            raise ValueError(
                "the first observation of an episode must be a stack of one repeated frame "
                "(FrameStackObservation pads with the reset frame)"
            )
        self._append_frames(obs[-1:] if self.frame_stack > 1 else obs[None])
        self._write(first=True)

    def add(self, action: int, length: int, terminated: bool, next_obs: np.ndarray) -> None:
        """Record the decision at the newest entry and write the observation it led to.

        `length` is the number of primitive steps the decision executed (`info["routine_length"]`
        of the `RoutineActionWrapper`): that many new frames are at the end of `next_obs`.
        """
        if self._num_entries == 0:
            raise RuntimeError("call start_episode(obs) before add(...)")
        if length < 1:
            raise ValueError(f"length needs to be ≥ 1, actual value: {length}")
        next_obs = np.asarray(next_obs)
        if next_obs.shape != self.obs_shape:
            raise ValueError(f"observation of shape {next_obs.shape}, expected {self.obs_shape}")
        last = (self.pos - 1) % self.capacity
        self.actions[last] = action
        self.lengths[last] = length
        self.terminated[last] = terminated
        self.has_next[last] = True
        self._num_transitions += 1
        if self.frame_stack > 1:
            self._append_frames(next_obs[-min(int(length), self.frame_stack):])
        else:
            self._append_frames(next_obs[None])
        self._write(first=False)

    def stacks(self, index: np.ndarray) -> np.ndarray:
        """The observations at entries `index` (frame stacks rebuilt for `frame_stack > 1`)."""
        index = np.asarray(index, dtype=np.int64)
        newest = self.newest_frame[index]
        if self.frame_stack == 1:
            return self.frames[newest % self.capacity]
        back = np.arange(self.frame_stack - 1, -1, -1)  # oldest frame first
        numbers = np.maximum(newest[..., None] - back, self.episode_frame[index][..., None])
        return self.frames[numbers % self.capacity]

    def _stack_kept(self, newest: Any) -> Any:
        """Whether the `F` frames up to frame number(s) `newest` are all still in the ring.

        An entry near its episode's start needs fewer, but asking for all `F` keeps plain SQIL
        (one frame per entry) sampling exactly what the memory of one frame per decision did.
        """
        if self.num_frames < self.capacity:
            return np.ones(np.shape(newest), dtype=bool)
        return newest - (self.frame_stack - 1) >= self.num_frames - self.capacity

    def _valid(self, index: np.ndarray) -> np.ndarray:
        """Whether the entries `index` start transitions that can be sampled."""
        return self.has_next[index] & self._stack_kept(self.newest_frame[index])

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """`batch_size` transitions, uniformly with replacement: `obs`, `actions`, `lengths`,
        `next_obs`, `terminated`."""
        if len(self) == 0:
            raise ValueError("the replay memory holds no transition yet")
        size = self.capacity if self.full else self.pos
        index = rng.integers(0, size, size=batch_size)
        # Rejection is cheap: at least about one slot in F holds a transition that can be sampled.
        bad = ~self._valid(index)
        while bad.any():
            index[bad] = rng.integers(0, size, size=int(bad.sum()))
            bad = ~self._valid(index)
        return {
            "obs": self.stacks(index),
            "actions": self.actions[index],
            "lengths": self.lengths[index],
            "next_obs": self.stacks((index + 1) % self.capacity),
            "terminated": self.terminated[index],
        }
