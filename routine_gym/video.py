"""Videos of an agent as animated GIFs, each frame captioned with what the agent executes.

Gymnasium's `RecordVideo` needs moviepy, which routine-gym does not install; these videos need
only Pillow (a dependency of matplotlib). `FrameRecorder` sits on the primitive env (under the
preprocessing and the `RoutineActionWrapper`, so it sees every primitive step) and keeps each
episode's rendered frames: frame `t` is the screen before step `t`'s action, and one more frame
after the last step. The frames go to disk as they come (a `FrameSpool`, at the GIF's size), and
`write_gif` streams them into the file, so the memory a filmed episode takes is a frame or two
however long it runs (a Freeway episode kept in memory took 1.5 GB). `step_captions` names
each step from the demo-style record of the episode: which steps the agent decided and which
a wrapper injected, and the agent's decisions in order (a primitive action, or routine `k` of
the library, whose decided steps follow it), so a frame inside a routine reads
`R1 DOWN DOWN DOWN 2/3: DOWN`. `write_gif` draws the captions under the
frames and writes the GIF atomically.

A resumed run's training films go on numbering the episodes where its checkpoint left off
(`FrameRecorder(first_episode=...)`), and a name already taken is never overwritten
(`unused_path`: `train-episode-27-2.gif`).

The training scripts' `--capture-video` records the evaluation episodes this way
(`routine_gym.plumbing.evaluation.evaluate_policy`), and the training env 0's episodes on the
capped cubic schedule with each step's primitive action (`routine_gym.envs.factory.make_env`).

Example:
    >>> step_captions(actions=[0, 5, 5, 1], decided=[False, True, True, True],
    ...               choices=[6, 1], num_actions=6, routines=[(5, 5)],
    ...               action_meanings=["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"])
    ['injected: NOOP', 'R0 DOWN DOWN 1/2: DOWN', 'R0 DOWN DOWN 2/2: DOWN', 'FIRE']
"""

from __future__ import annotations

import io
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.library import routine_name

__all__ = ["FrameRecorder", "FrameSpool", "cubic_schedule", "step_captions", "unused_path",
           "write_gif"]

#: The width of a GIF's frames: small frames are enlarged (nearest neighbour), large ones
#: shrunk, so a caption stays readable and a long episode stays a few megabytes.
GIF_WIDTH = 320


def cubic_schedule(episode: int) -> bool:
    """Episodes 0, 1, 8, 27, ..., 729, then every 1000th: CleanRL's (and Gymnasium's
    `RecordVideo`'s) default choice of which training episodes to film."""
    if episode < 1000:
        return round(episode ** (1.0 / 3)) ** 3 == episode
    return episode % 1000 == 0


def _gif_size(height: int, width: int) -> tuple[tuple[int, int], Any]:
    """A frame's size in the GIF (`GIF_WIDTH` wide) and the resampling that gets it there."""
    from PIL import Image

    scale = GIF_WIDTH / width
    resample = Image.Resampling.NEAREST if scale >= 1 else Image.Resampling.BILINEAR
    return (GIF_WIDTH, max(1, round(height * scale))), resample


class FrameSpool(Sequence):
    """An episode's frames in a temporary file, scaled to the GIF's width as they come.

    Memory holds one frame; the file (in `folder`, else the system's temporary folder) has no
    name and is gone when the spool is closed, collected, or the process ends. Read back by
    index or in order, each frame an `[H, W, 3]` uint8 array.

    Example:
        >>> spool = FrameSpool()
        >>> spool.append(np.zeros((10, 20, 3), np.uint8))
        >>> len(spool), spool[0].shape
        (1, (160, 320, 3))
    """

    def __init__(self, folder: str | os.PathLike | None = None) -> None:
        self.folder = folder
        self._file: Any = None
        self._shape: tuple[int, ...] | None = None
        self._count = 0

    def append(self, frame: np.ndarray) -> None:
        """Add a frame (`[H, W, 3+]`, RGB first), scaled to `GIF_WIDTH` pixels wide."""
        from PIL import Image

        frame = np.ascontiguousarray(np.asarray(frame)[..., :3], dtype=np.uint8)
        size, resample = _gif_size(*frame.shape[:2])
        if frame.shape[1::-1] != size:
            frame = np.asarray(Image.fromarray(frame).resize(size, resample))
        if self._file is None:
            if self.folder is not None:
                os.makedirs(self.folder, exist_ok=True)
            self._file = tempfile.TemporaryFile(dir=self.folder)
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise ValueError(f"FrameSpool: a frame of shape {frame.shape} among frames of "
                             f"shape {self._shape}")
        self._file.seek(0, os.SEEK_END)
        self._file.write(frame.tobytes())
        self._count += 1

    def __len__(self) -> int:
        return self._count

    def __getitem__(self, index: int) -> np.ndarray:  # type: ignore[override]
        if not -self._count <= index < self._count:
            raise IndexError(f"frame {index} of {self._count}")
        index %= self._count
        nbytes = int(np.prod(self._shape))
        self._file.seek(index * nbytes)
        return np.frombuffer(self._file.read(nbytes), dtype=np.uint8).reshape(self._shape)

    def __iter__(self) -> Iterator[np.ndarray]:
        for index in range(self._count):
            yield self[index]

    def close(self) -> None:
        """Delete the frames."""
        if self._file is not None:
            self._file.close()
            self._file = None
        self._count = 0


class FrameRecorder(gym.Wrapper):
    """Keeps the rendered frames and primitive actions of an env's episodes.

    The env must be made with `render_mode="rgb_array"`. Frame `t` of an episode is
    `env.render()` before step `t`'s action; the frame after the last step ends the list. The
    frames go to a `FrameSpool` on disk as they are rendered (memory: one frame). An episode
    ends when the env terminates or truncates; `on_episode_end(index, frames, actions)` is
    then called (and the episode's frames deleted), else the episodes are kept in `episodes`
    for the caller (who closes their spools). Only episodes `record(index)` accepts are
    rendered, so a training env pays for the episodes it films alone.

    Args:
        env: the primitive env, rendering RGB frames.
        record: which episodes (counted from `first_episode`) to film; all of them by default.
        on_episode_end: what to do with a filmed episode when it ends (write it).
        first_episode: the index of the first episode (a resumed run's count so far).
        spool_dir: where the frames wait on disk (None: the system's temporary folder).
    """

    def __init__(self, env: gym.Env, record: Callable[[int], bool] | None = None,
                 on_episode_end: Callable[[int, FrameSpool, list[int]], None] | None = None,
                 first_episode: int = 0, spool_dir: str | os.PathLike | None = None) -> None:
        super().__init__(env)
        if env.render_mode != "rgb_array":
            raise ValueError(f"FrameRecorder needs an env made with render_mode='rgb_array', "
                             f"actual value: {env.render_mode!r}")
        self.record = record or (lambda episode: True)
        self.on_episode_end = on_episode_end
        self.spool_dir = spool_dir
        self.episodes: list[tuple[FrameSpool, list[int]]] = []
        self._episode = int(first_episode) - 1
        self._filming = False

    @property
    def episode(self) -> int:
        """The index of the current episode (`first_episode - 1` before the first reset)."""
        return self._episode

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        if self._filming and self.on_episode_end is not None:
            self.episodes.pop()[0].close()  # an episode cut short by a reset: not written
        self._episode += 1
        self._filming = self.record(self._episode)
        if self._filming:
            spool = FrameSpool(self.spool_dir)
            spool.append(self._frame())
            self.episodes.append((spool, []))
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._filming:
            frames, actions = self.episodes[-1]
            actions.append(int(action))
            frames.append(self._frame())
            if (terminated or truncated) and self.on_episode_end is not None:
                frames, actions = self.episodes.pop()
                try:
                    self.on_episode_end(self._episode, frames, actions)
                finally:
                    frames.close()
                self._filming = False
        return obs, reward, terminated, truncated, info

    def _frame(self) -> np.ndarray:
        return np.asarray(self.env.render())


def step_captions(actions: Sequence[int], decided: Sequence[bool], choices: Sequence[int],
                  num_actions: int, routines: Sequence[Sequence[int]] | None = None,
                  action_meanings: Sequence[str] | None = None) -> list[str]:
    """What each primitive step of an episode executes, for the frame before it.

    Args:
        actions: the episode's primitive actions.
        decided: per step, whether the agent decided it (False: a wrapper injected it).
        choices: the agent's decisions in order, each an action of `Discrete(n + K)`: `a < n`
            a primitive action, `n + k` routine `k`, whose steps are the decided steps that
            follow (fewer when the episode ends inside it).
        num_actions: n, the primitive actions.
        routines: the K routines (None: primitives only).
        action_meanings: the primitive actions' names (None: their ids).

    Returns:
        A caption per step: `"LEFT"` for a primitive decision, `"R1 UP UP RIGHT 2/3: UP"` for
        the second step of routine 1, `"injected: FIRE"` for a wrapper's step.
    """
    routines = [tuple(r) for r in routines or ()]
    names = [routine_name(r, action_meanings) for r in routines]
    captions, pending = [], iter(choices)
    routine, left = None, 0  # the routine being executed and its steps still to come
    for action, mine in zip(actions, decided, strict=True):
        name = routine_name([int(action)], action_meanings)
        if not mine:
            captions.append(f"injected: {name}")
            continue
        if left == 0:  # a new decision
            k = int(next(pending, -1)) - num_actions
            routine = k if 0 <= k < len(routines) else None
            left = len(routines[routine]) if routine is not None else 1
        left -= 1
        if routine is None:
            captions.append(name)
        else:
            length = len(routines[routine])
            captions.append(f"R{routine} {names[routine]} {length - left}/{length}: {name}")
    return captions


def unused_path(path: str | os.PathLike) -> str:
    """`path` when nothing is there, else the first free `{stem}-2{suffix}`, `-3`, ...: a file
    of an earlier run (a resumed one's first leg) is never overwritten."""
    path = os.fspath(path)
    stem, suffix = os.path.splitext(path)
    candidate, k = path, 1
    while os.path.lexists(candidate):
        k += 1
        candidate = f"{stem}-{k}{suffix}"
    return candidate


def write_gif(frames: Sequence[np.ndarray], captions: Sequence[str], path: str | os.PathLike,
              fps: float = 15.0) -> None:
    """Write `frames` as an animated GIF with `captions[i]` under frame `i`, atomically.

    The frames are scaled to `GIF_WIDTH` pixels wide (nearest neighbour when enlarged) and
    each get a palette of their own (Pillow's fast octree quantisation). The file is written
    frame by frame as `frames` (a list, or a `FrameSpool` on disk) is read: memory holds one
    frame, whatever the episode's length. A frame identical to the one before it lengthens
    that one's display instead (as Pillow's own writer does).
    """
    from routine_gym.plumbing.atomic import atomic_write_chunks

    if len(frames) == 0 or len(frames) != len(captions):
        raise ValueError(f"write_gif needs one caption per frame and at least one frame, got "
                         f"{len(frames)} frames and {len(captions)} captions")
    delay = max(20, math.floor(1000 / fps)) // 10  # GIF delays are in hundredths of a second
    atomic_write_chunks(path, _gif_stream(frames, captions, delay))


def _gif_stream(frames: Iterable[np.ndarray], captions: Sequence[str],
                delay: int) -> Iterator[bytes]:
    """The bytes of the animated GIF, one frame at a time (header, frames, trailer)."""
    from PIL import Image, ImageDraw, ImageFont

    try:
        font = ImageFont.load_default(size=13)
    except TypeError:  # Pillow without FreeType: the bitmap font
        font = ImageFont.load_default()
    bar = 22
    pending, pending_delay = None, 0  # the last frame, held back in case the next repeats it
    for index, (frame, caption) in enumerate(zip(frames, captions, strict=True)):
        frame = np.asarray(frame, dtype=np.uint8)[..., :3]
        size, resample = _gif_size(*frame.shape[:2])
        picture = Image.fromarray(np.ascontiguousarray(frame))
        if picture.size != size:
            picture = picture.resize(size, resample)
        image = Image.new("RGB", (size[0], size[1] + bar), "black")
        image.paste(picture)
        ImageDraw.Draw(image).text((4, size[1] + 4), caption, fill="white", font=font)
        block = _image_block(image.quantize(colors=255, method=Image.Quantize.FASTOCTREE))
        if index == 0:
            yield _gif_header(*image.size)
        if block == pending and pending_delay + delay <= 0xFFFF:
            pending_delay += delay
            continue
        if pending is not None:
            yield _frame_chunk(pending, pending_delay)
        pending, pending_delay = block, delay
    if pending is not None:
        yield _frame_chunk(pending, pending_delay)
    yield b";"  # the trailer


def _gif_header(width: int, height: int) -> bytes:
    """GIF89a, the canvas with no global palette (each frame has its own), looping forever."""
    screen = width.to_bytes(2, "little") + height.to_bytes(2, "little") + b"\x00\x00\x00"
    loop = b"!\xff\x0bNETSCAPE2.0\x03\x01\x00\x00\x00"
    return b"GIF89a" + screen + loop


def _frame_chunk(block: bytes, delay: int) -> bytes:
    """A frame: its graphic control extension (the delay, in 1/100 s) and its image block."""
    return b"!\xf9\x04\x00" + delay.to_bytes(2, "little") + b"\x00\x00" + block


def _image_block(image: Any) -> bytes:
    """A palette image as a GIF image block with a local palette: Pillow encodes it as a
    one-frame GIF, whose global palette becomes the block's local one."""
    buffer = io.BytesIO()
    image.save(buffer, format="GIF")
    data = buffer.getvalue()
    flags, pos = data[10], 13
    palette = b""
    if flags & 0x80:
        palette = data[pos:pos + 3 * (2 << (flags & 7))]
        pos += len(palette)
    while data[pos] == 0x21:  # extensions (Pillow writes none for one frame, but may)
        pos += 2
        while data[pos]:
            pos += data[pos] + 1
        pos += 1
    if data[pos] != 0x2C:
        raise ValueError("write_gif: Pillow's one-frame GIF has no image block")
    descriptor, local = data[pos + 1:pos + 9], data[pos + 9]
    pos += 10
    if local & 0x80:  # a local palette of its own wins
        palette = data[pos:pos + 3 * (2 << (local & 7))]
        pos += len(palette)
        flags = local
    bits = flags & 7
    if data[-1] != 0x3B:
        raise ValueError("write_gif: Pillow's one-frame GIF has no trailer")
    return b"," + descriptor + bytes([0x80 | bits]) + palette + data[pos:-1]
