"""Videos of an agent as animated GIFs, each frame captioned with what the agent executes.

Gymnasium's `RecordVideo` needs moviepy, which routine-gym does not install; these videos need
only Pillow (a dependency of matplotlib). `FrameRecorder` sits on the primitive env (under the
preprocessing and the `RoutineActionWrapper`, so it sees every primitive step) and keeps each
episode's rendered frames: frame `t` is the screen before step `t`'s action, and one more frame
after the last step. `step_captions` names each step from the demo-style record of the episode:
which steps the agent decided and which a wrapper injected, and the agent's decisions in order
(a primitive action, or routine `k` of the library, whose decided steps follow it), so a frame
inside a routine reads `R1 DOWN DOWN DOWN 2/3: DOWN`. `write_gif` draws the captions under the
frames and writes the GIF atomically.

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
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from routine_gym.library import routine_name

__all__ = ["FrameRecorder", "cubic_schedule", "step_captions", "write_gif"]

#: The width of a GIF's frames: small frames are enlarged (nearest neighbour), large ones
#: shrunk, so a caption stays readable and a long episode stays a few megabytes.
GIF_WIDTH = 320


def cubic_schedule(episode: int) -> bool:
    """Episodes 0, 1, 8, 27, ..., 729, then every 1000th: CleanRL's (and Gymnasium's
    `RecordVideo`'s) default choice of which training episodes to film."""
    if episode < 1000:
        return round(episode ** (1.0 / 3)) ** 3 == episode
    return episode % 1000 == 0


class FrameRecorder(gym.Wrapper):
    """Keeps the rendered frames and primitive actions of an env's episodes.

    The env must be made with `render_mode="rgb_array"`. Frame `t` of an episode is
    `env.render()` before step `t`'s action; the frame after the last step ends the list. An
    episode ends when the env terminates or truncates; `on_episode_end(index, frames,
    actions)` is then called (and the episode dropped), else the episodes are kept in
    `episodes` for the caller. Only episodes `record(index)` accepts are rendered, so a
    training env pays for the episodes it films alone.

    Args:
        env: the primitive env, rendering RGB frames.
        record: which episodes (counted from 0) to film; all of them by default.
        on_episode_end: what to do with a filmed episode when it ends (write it).
    """

    def __init__(self, env: gym.Env, record: Callable[[int], bool] | None = None,
                 on_episode_end: Callable[[int, list[np.ndarray], list[int]], None] | None = None
                 ) -> None:
        super().__init__(env)
        if env.render_mode != "rgb_array":
            raise ValueError(f"FrameRecorder needs an env made with render_mode='rgb_array', "
                             f"actual value: {env.render_mode!r}")
        self.record = record or (lambda episode: True)
        self.on_episode_end = on_episode_end
        self.episodes: list[tuple[list[np.ndarray], list[int]]] = []
        self._episode = -1
        self._filming = False

    @property
    def episode(self) -> int:
        """The index of the current episode (-1 before the first reset)."""
        return self._episode

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._episode += 1
        self._filming = self.record(self._episode)
        if self._filming:
            self.episodes.append(([self._frame()], []))
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._filming:
            frames, actions = self.episodes[-1]
            actions.append(int(action))
            frames.append(self._frame())
            if (terminated or truncated) and self.on_episode_end is not None:
                self.on_episode_end(self._episode, *self.episodes.pop())
                self._filming = False
        return obs, reward, terminated, truncated, info

    def _frame(self) -> np.ndarray:
        frame = np.asarray(self.env.render())
        return np.ascontiguousarray(frame[..., :3], dtype=np.uint8)


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


def write_gif(frames: Sequence[np.ndarray], captions: Sequence[str], path: str | os.PathLike,
              fps: float = 15.0) -> None:
    """Write `frames` as an animated GIF with `captions[i]` under frame `i`, atomically.

    The frames are scaled to `GIF_WIDTH` pixels wide (nearest neighbour when enlarged) and
    each get a palette of their own (Pillow's fast octree quantisation).
    """
    from PIL import Image, ImageDraw, ImageFont

    from routine_gym.atomic import atomic_write_bytes

    if len(frames) == 0 or len(frames) != len(captions):
        raise ValueError(f"write_gif needs one caption per frame and at least one frame, got "
                         f"{len(frames)} frames and {len(captions)} captions")
    height, width = np.asarray(frames[0]).shape[:2]
    scale = GIF_WIDTH / width
    size = (GIF_WIDTH, max(1, round(height * scale)))
    resample = Image.Resampling.NEAREST if scale >= 1 else Image.Resampling.BILINEAR
    try:
        font = ImageFont.load_default(size=13)
    except TypeError:  # Pillow without FreeType: the bitmap font
        font = ImageFont.load_default()
    bar = 22
    images = []
    for frame, caption in zip(frames, captions, strict=True):
        image = Image.new("RGB", (size[0], size[1] + bar), "black")
        image.paste(Image.fromarray(np.asarray(frame, dtype=np.uint8)).resize(size, resample))
        ImageDraw.Draw(image).text((4, size[1] + 4), caption, fill="white", font=font)
        images.append(image.quantize(colors=255, method=Image.Quantize.FASTOCTREE))
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:],
                   duration=max(20, math.floor(1000 / fps)), loop=0)
    atomic_write_bytes(path, buffer.getvalue())
