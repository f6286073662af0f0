"""Pictures of routines: what a routine does in its demo, and how often a run calls it.

A routine reads as a line of text (`DOWN DOWN DOWN`); these pictures show it.

- **A demo's routines** (`routine_picture`, drawn by `draw_routine_picture`): for each routine of
  a library, a film strip of the frames of its first occurrence in the demo, frame `j` the
  screen before the routine's action `j`, captioned with that action's name; below, a
  timeline of the demo marking every occurrence of every routine (as the miners count them:
  in the decided steps, overlapping ones included, none across an episode boundary or an
  injected step) and the steps the preprocessing injected. The frames are the demo's own
  observations when it keeps RGB ones, else the env's `render()` while the demo is replayed
  from its seeds, only as far as the last frame needed (`routine_gym.demo.replay.render_frames`).
- **A run's routine usage** (`routine_usage`, drawn by `draw_routine_usage`): the share of the
  agent's decisions that chose each routine and the primitive actions, against agent steps,
  from the `counters/primitive_share` and `counters/share_k` scalars a script logs
  (`routine_gym.plumbing.counters`), binned by decisions as the sweep bins them
  (`routine_gym.experiments.run_counters.counter_record`).

The data a picture is drawn from is returned first (`RoutinePicture`, `RoutineUsage`), so it can
be checked without looking at pixels; the drawing uses matplotlib's Agg canvas (no window) and
`save_png` writes the figure atomically. `routine-gym picture DEMO|RUN_DIR --out OUT.png` is
the command line.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.demo import Demo
from routine_gym.library import Routine, RoutineLibrary, routine_name

__all__ = [
    "Film",
    "RoutinePicture",
    "RoutineUsage",
    "Timeline",
    "demo_timeline",
    "describe_picture",
    "draw_routine_picture",
    "draw_routine_usage",
    "routine_films",
    "routine_picture",
    "routine_usage",
    "save_png",
    "top_routines",
]

#: The routines `routine-gym picture` draws at most (`--max-routines`): a film strip each, and
#: the time to draw grows faster than their number (a 200-routine library took > 3 minutes).
MAX_ROUTINES = 12

#: Frames a film strip holds per row; a longer routine wraps onto further rows.
FRAMES_PER_ROW = 8
#: The colour of the injected steps on the timeline.
INJECTED_COLOUR = "#7f7f7f"
#: The colour of the primitive actions' share in the usage picture.
PRIMITIVE_COLOUR = "#c7c7c7"


def routine_colour(k: int) -> str:
    """Routine `k`'s colour, the same in the film strip, the timeline and the usage picture
    (matplotlib's tab10 without its grey, which marks injected steps)."""
    palette = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
               "#bcbd22", "#17becf")
    return palette[k % len(palette)]


# -- a demo's routines ---------------------------------------------------------------------


@dataclass(frozen=True)
class Film:
    """The frames of one routine's first occurrence in a demo.

    Attributes:
        index: the routine's index `k` in its library.
        routine: its primitive actions.
        name: its actions' names (`"DOWN DOWN DOWN"`).
        frequency: its occurrences in the demo.
        occurrence: `(episode, step)` of its first occurrence, None when it never occurs.
        frames: `(len(routine), H, W, 3)` uint8: frame `j` is the screen before the routine's
            action `j` (the demo's step `step + j`); None when it never occurs.
        captions: the name of each frame's action.
    """

    index: int
    routine: Routine
    name: str
    frequency: int
    occurrence: tuple[int, int] | None
    frames: np.ndarray | None
    captions: tuple[str, ...]


@dataclass(frozen=True)
class Timeline:
    """Where each routine occurs in a demo and which steps were injected, in demo steps (the
    episodes one after the other: episode `e`'s step `t` is `episode_starts[e] + t`).

    Attributes:
        num_steps: the demo's steps, injected ones included.
        episode_starts: the demo step of each episode's first step.
        routine_lengths: the length of each routine.
        starts: for each routine, the demo step of each of its occurrences, ascending.
        injected: the demo steps a wrapper injected (not the demonstrator's decisions).
    """

    num_steps: int
    episode_starts: np.ndarray
    routine_lengths: tuple[int, ...]
    starts: tuple[np.ndarray, ...]
    injected: np.ndarray


@dataclass(frozen=True)
class RoutinePicture:
    """What `draw_routine_picture` draws: a film per routine and the demo's timeline."""

    env_id: str
    source: str
    score: float
    num_decisions: int
    films: tuple[Film, ...]
    timeline: Timeline
    replayed_steps: int
    """Env steps replayed to render the frames (0 when the demo keeps RGB observations)."""


def top_routines(library: RoutineLibrary, n: int) -> RoutineLibrary:
    """The `n` best routines of `library` by score (all of them when it has `n` or fewer),
    in the library's order, with their evidence; a library without scores keeps its first `n`.

    Example:
        >>> lib = RoutineLibrary(routines=((0, 1), (1, 2), (2, 0)), scores=(2.0, 5.0, 3.0))
        >>> top_routines(lib, 2).routines
        ((1, 2), (2, 0))
    """
    if n < 1:
        raise ValueError(f"n needs to be ≥ 1, actual value: {n}")
    if len(library) <= n:
        return library
    if library.scores:
        # Best first; among equal scores the earlier routine (a stable sort).
        best = sorted(range(len(library)), key=lambda k: -library.scores[k])[:n]
        kept = sorted(best)
    else:
        kept = list(range(n))

    def pick(values: tuple) -> tuple:
        return tuple(values[k] for k in kept) if values else values

    return RoutineLibrary(
        routines=pick(library.routines), scores=pick(library.scores),
        frequencies=pick(library.frequencies), occurrences=pick(library.occurrences),
        params=library.params, source=library.source, action_meanings=library.action_meanings)


def _routines_of(routines: RoutineLibrary | Sequence[Sequence[int]]) -> list[Routine]:
    return [tuple(int(a) for a in r) for r in routines]


def demo_timeline(demo: Demo, routines: RoutineLibrary | Sequence[Sequence[int]]) -> Timeline:
    """Every occurrence of each routine in `demo`, and its injected steps (`Timeline`).

    Occurrences are found as the miners find them (`routine_gym.mining.demo_occurrences`): in
    the demonstrator's decisions, overlapping ones counted, none across an episode boundary or
    an injected step.
    """
    from routine_gym.mining import demo_occurrences

    routines = _routines_of(routines)
    offsets = demo.episode_offsets.astype(np.int64)
    starts = []
    for pairs in demo_occurrences(demo, routines) if routines else ():
        rows = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        starts.append(np.sort(offsets[rows[:, 0]] + rows[:, 1]))
    return Timeline(
        num_steps=len(demo),
        episode_starts=offsets,
        routine_lengths=tuple(len(r) for r in routines),
        starts=tuple(starts),
        injected=np.flatnonzero(~demo.decisions).astype(np.int64),
    )


def _rgb_observations(demo: Demo) -> bool:
    """Whether the demo keeps observations that are RGB frames (its own frames to show)."""
    obs = demo.observations
    return obs is not None and obs.ndim == 4 and obs.shape[-1] == 3 and obs.dtype == np.uint8


def routine_films(
    demo: Demo, routines: RoutineLibrary | Sequence[Sequence[int]],
    timeline: Timeline | None = None,
) -> tuple[tuple[Film, ...], int]:
    """The film of each routine's first occurrence in `demo`, and the env steps replayed for
    them.

    The frames are the demo's observations when it keeps RGB ones; otherwise each episode that
    holds a first occurrence is replayed from its seed, rendering, as far as the last frame
    needed (`render_frames`).

    Raises:
        ValueError: a routine uses an action outside the demo's actions; the env cannot
            render RGB frames; the demo cannot be replayed (no env id, no seed).
        routine_gym.demo.DemoReplayError: the replay diverged from the record.
    """
    from routine_gym.demo.replay import render_frames

    routines = _routines_of(routines)
    meanings = demo.action_meanings
    for k, routine in enumerate(routines):
        if max(routine) >= demo.num_actions:
            raise ValueError(f"routine {k} ({routine_name(routine)}) uses action "
                             f"{max(routine)}, but the demo's env has {demo.num_actions} "
                             f"actions {list(meanings)}: the routines are of another env")
    timeline = timeline if timeline is not None else demo_timeline(demo, routines)
    offsets = timeline.episode_starts
    firsts: list[tuple[int, int] | None] = []
    for starts in timeline.starts:
        if starts.size == 0:
            firsts.append(None)
            continue
        e = int(np.searchsorted(offsets, starts[0], side="right") - 1)
        firsts.append((e, int(starts[0] - offsets[e])))
    steps: dict[int, set[int]] = {}
    for routine, first in zip(routines, firsts, strict=True):
        if first is not None:
            steps.setdefault(first[0], set()).update(range(first[1], first[1] + len(routine)))
    if _rgb_observations(demo):
        frames = {(e, t): demo.observations[offsets[e] + t] for e, ts in steps.items()
                  for t in ts}
        replayed = 0
    else:
        frames = render_frames(demo, steps)
        replayed = sum(max(ts) for ts in steps.values())
    films = []
    for k, (routine, first) in enumerate(zip(routines, firsts, strict=True)):
        strip = None
        if first is not None:
            e, t = first
            strip = np.stack([frames[(e, t + j)] for j in range(len(routine))])
        films.append(Film(
            index=k, routine=routine, name=routine_name(routine, meanings),
            frequency=int(timeline.starts[k].size), occurrence=first, frames=strip,
            captions=tuple(routine_name([a], meanings) for a in routine),
        ))
    return tuple(films), replayed


def routine_picture(demo: Demo, library: RoutineLibrary | Sequence[Sequence[int]],
                    source: str | None = None) -> RoutinePicture:
    """The data of a demo's picture of routines: a film per routine and the timeline.

    Args:
        demo: the demo (its env must render RGB frames unless it keeps RGB observations).
        library: the routines (a `RoutineLibrary` or action sequences); their occurrences are
            found in this demo, whatever demo they were mined from.
        source: how the demo is named in the title (its path).
    """
    if len(library) == 0:
        raise ValueError("there are no routines to draw: the library is empty")
    named = getattr(library, "action_meanings", None)
    if named is not None and tuple(named) != tuple(demo.action_meanings):
        raise ValueError(f"the routines are made of the actions {list(named)}, the demo's "
                         f"env has {list(demo.action_meanings)}: the routines are of another env")
    timeline = demo_timeline(demo, library)
    films, replayed = routine_films(demo, library, timeline)
    return RoutinePicture(
        env_id=str(demo.env_id), source=source or "", score=demo.score,
        num_decisions=demo.num_decisions, films=films, timeline=timeline,
        replayed_steps=replayed,
    )


def _runs(steps: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive steps as `(start, length)` spans: `[3, 4, 5, 9]` → `[(3, 3), (9, 1)]`."""
    if steps.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(steps) != 1) + 1
    return [(int(run[0]), int(run.size)) for run in np.split(steps, breaks)]


def draw_routine_picture(picture: RoutinePicture) -> Any:
    """The matplotlib figure of a `RoutinePicture`: a film strip per routine (its colour on the
    frames' border), then the demo's timeline."""
    from routine_gym.experiments.drawing import figure

    films = picture.films
    shown = [f for f in films if f.frames is not None]
    longest = max((len(f.routine) for f in shown), default=1)
    columns = min(longest, FRAMES_PER_ROW)
    height, width = shown[0].frames.shape[1:3] if shown else (1, 1)
    frame_w = 1.3
    frame_h = frame_w * height / width
    rows = [math.ceil(len(f.routine) / columns) if f.frames is not None else 0 for f in films]
    strip_heights = [0.45 + r * (frame_h + 0.5) for r in rows]
    timeline_height = 1.3 + 0.32 * (len(films) + 1)
    fig_w = max(columns * (frame_w + 0.15) + 0.3, 8.0)
    fig = figure(fig_w, sum(strip_heights) + timeline_height)
    parts = fig.subfigures(len(films) + 1, 1, height_ratios=[*strip_heights, timeline_height])
    for film, part, r in zip(films, parts[:-1], rows, strict=True):
        colour = routine_colour(film.index)
        if film.frames is None:
            part.suptitle(f"routine {film.index}: {film.name}: does not occur in this demo",
                          color=colour, fontsize=10, x=0.01, ha="left")
            continue
        e, t = film.occurrence
        part.suptitle(f"routine {film.index}: {film.name}   (f = {film.frequency}; first at "
                      f"episode {e}, step {t})", color=colour, fontsize=10, x=0.01, ha="left",
                      fontweight="bold")
        axes = np.atleast_1d(part.subplots(r, columns, squeeze=False)).ravel()
        for j, ax in enumerate(axes):
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(film.routine):
                ax.set_axis_off()
                continue
            # Small frames enlarged pixel for pixel; large ones (CoinRun's 512²) smoothed down.
            ax.imshow(film.frames[j], interpolation="nearest" if width <= 160 else "antialiased")
            ax.set_title(film.captions[j], fontsize=8, pad=2)
            ax.set_xlabel(f"step {t + j}", fontsize=7, labelpad=1)
            for spine in ax.spines.values():
                spine.set_edgecolor(colour)
                spine.set_linewidth(2)
    _draw_timeline(parts[-1], picture)
    return fig


def _draw_timeline(part: Any, picture: RoutinePicture) -> None:
    timeline, films = picture.timeline, picture.films
    ax = part.subplots()
    labels = []
    for row, film in enumerate(films):
        colour = routine_colour(film.index)
        length = timeline.routine_lengths[row]
        starts = timeline.starts[row]
        ax.broken_barh([(int(s), length) for s in starts], (row - 0.35, 0.7),
                       facecolors=colour, alpha=0.55, linewidth=0, gid=f"routine {film.index}")
        if starts.size:  # the filmed occurrence
            ax.broken_barh([(int(starts[0]), length)], (row - 0.42, 0.84), facecolors="none",
                           edgecolors="black", linewidth=1.2)
            ax.plot([starts[0] + length / 2], [row - 0.5], marker="v", color="black",
                    markersize=6, clip_on=False)
        labels.append(f"routine {film.index} (f = {starts.size})")
    injected_row = len(films)
    ax.broken_barh(_runs(timeline.injected), (injected_row - 0.35, 0.7),
                   facecolors=INJECTED_COLOUR, linewidth=0, gid="injected")
    labels.append(f"injected ({timeline.injected.size})")
    for start in timeline.episode_starts[1:]:
        ax.axvline(int(start), color="black", linestyle="--", linewidth=0.8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.set_ylim(len(labels) - 0.5, -0.6)
    ax.set_xlim(0, max(timeline.num_steps, 1))
    episodes = timeline.episode_starts.size
    ax.set_xlabel("demo step" + (" (episodes split by dashed lines)" if episodes > 1 else ""),
                  fontsize=8)
    ax.tick_params(axis="x", labelsize=8)
    source = f" ({picture.source})" if picture.source else ""
    ax.set_title(
        f"{picture.env_id}{source}, score {picture.score:g}\n{timeline.num_steps} steps "
        f"({picture.num_decisions} decided + {timeline.injected.size} injected), {episodes} "
        "episode(s): where each routine occurs (▼ the one filmed above)", fontsize=9)


# -- a run's routine usage -----------------------------------------------------------------


@dataclass(frozen=True)
class RoutineUsage:
    """The share of a run's decisions that chose each routine (option) and the primitive
    actions, per bin of agent steps.

    Attributes:
        run: the run folder's name.
        steps: each bin's right edge in agent (primitive) steps (bins without an update
            are left out).
        bin_width: the bins' width in agent steps.
        primitive_share: per bin, the share of the decisions that chose a primitive action.
        shares: `(K, bins)`: per routine, the share of the decisions that chose it.
        names: each routine's name (its actions', from the run's `routines.json`), or
            `option k` for a run with options and no library.
        overall: the whole run's primitive share, then each routine's.
        decisions: the decisions the run made; `primitive_steps` the agent steps it ran.
    """

    run: str
    steps: np.ndarray
    bin_width: float
    primitive_share: np.ndarray
    shares: np.ndarray
    names: tuple[str, ...]
    overall: tuple[float, ...]
    decisions: int
    primitive_steps: int


#: Bins of agent steps of the usage picture (fewer when the run logged fewer updates).
USAGE_BINS = 50


def routine_usage(run_dir: str | os.PathLike, bins: int = USAGE_BINS) -> RoutineUsage:
    """A run's routine usage over training, from its TensorBoard logs (`RoutineUsage`).

    Each bin's share is the decisions-weighted mean of the shares logged at the updates in
    it, so a bin's shares sum to 1 (`counter_record`, what the sweep keeps).

    Raises:
        FileNotFoundError: no folder at `run_dir`.
        ValueError: the folder has no TensorBoard log with `counters/primitive_share` (naming
            which scripts log it).
    """
    from routine_gym.experiments.run_counters import counter_record
    from routine_gym.experiments.training_curves import read_scalars

    folder = Path(run_dir)
    if not folder.is_dir():
        raise FileNotFoundError(f"no run folder at {run_dir}")
    if not any(folder.glob("events.out.tfevents.*")):
        raise ValueError(f"{run_dir} holds no TensorBoard log (events.out.tfevents.*): give a "
                         "run folder of a script in algos/, or a demo file")
    scalars = {tag: series for tag, series in read_scalars(folder).items()
               if tag.startswith("counters/")}
    logged = scalars.get("counters/primitive_share")
    if logged is None or logged[0].size == 0 or "counters/decisions" not in scalars:
        raise ValueError(f"{run_dir}'s TensorBoard log has no counters/primitive_share: only "
                         "the scripts that choose among primitives and routines or options log "
                         "it (rapl_a2c.py, option_critic.py, compile_a2c.py)")
    record = counter_record(scalars, bins=max(1, min(bins, logged[0].size)))
    binned = record["bins"]
    edges = np.linspace(0.0, float(binned["total_steps"]), binned["bins"] + 1)[1:]

    def values(row: Sequence[float | None]) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in row], dtype=np.float64)

    primitive = values(binned["primitive_share"])
    shares = np.array([values(row) for row in binned["shares"]]).reshape(-1, edges.size)
    keep = ~np.isnan(primitive)  # bins without an update
    names = _routine_names(folder, shares.shape[0])
    return RoutineUsage(
        run=folder.resolve().name, steps=edges[keep],
        bin_width=float(binned["total_steps"]) / binned["bins"], primitive_share=primitive[keep],
        shares=shares[:, keep], names=names,
        overall=(record["primitive_share"], *record["shares"]),
        decisions=record["decisions"], primitive_steps=record["primitive_steps"],
    )


def _routine_names(folder: Path, count: int) -> tuple[str, ...]:
    """Routine `k`'s actions' names from the run's `routines.json`; `option k` without one."""
    path = folder / "routines.json"
    if not path.is_file():
        return tuple(f"option {k}" for k in range(count))
    library = RoutineLibrary.load(path)
    return tuple(library.name(k) if k < len(library) else f"routine {k}" for k in range(count))


def draw_routine_usage(usage: RoutineUsage) -> Any:
    """The matplotlib figure of a `RoutineUsage`: the shares stacked, primitives at the bottom,
    against agent steps."""
    from routine_gym.experiments.drawing import figure

    fig = figure(8.0, 4.2)
    ax = fig.subplots()
    overall = usage.overall
    labels = [f"primitive actions ({_percent(overall[0])} of all decisions)"]
    labels += [f"routine {k}: {_short(name)} ({_percent(overall[k + 1])})"
               for k, name in enumerate(usage.names)]
    colours = [PRIMITIVE_COLOUR] + [routine_colour(k) for k in range(len(usage.names))]
    # Each bin's shares held over the bin: the first value is repeated at its left edge.
    x = np.concatenate([[usage.steps[0] - usage.bin_width], usage.steps])
    ys = [np.concatenate([[y[0]], y]) for y in (usage.primitive_share, *usage.shares)]
    ax.stackplot(x, *ys, labels=labels, colors=colours, alpha=0.85, step="pre")
    ax.set_xlim(0, float(usage.steps[-1]))
    ax.set_ylim(0, 1)
    ax.set_xlabel("agent steps (primitive)")
    ax.set_ylabel("share of decisions")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False,
              reverse=True)
    fig.suptitle(f"{usage.run}\nroutine usage: {usage.decisions:,} decisions over "
                 f"{usage.primitive_steps:,} agent steps", fontsize=9)
    return fig


def _percent(share: float | None) -> str:
    return "–" if share is None or math.isnan(share) else f"{100 * share:.1f} %"


def _short(name: str, limit: int = 40) -> str:
    return name if len(name) <= limit else name[: limit - 1] + "…"


def save_png(fig: Any, path: str | os.PathLike, dpi: int = 100) -> None:
    """Write the figure as a PNG of 256 colours, atomically (a crash never leaves half a
    picture). The palette keeps a picture of textured game frames (CoinRun's) a few hundred
    kilobytes where full colour takes a megabyte."""
    from PIL import Image

    from routine_gym.atomic import atomic_write_bytes

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    buffer.seek(0)
    with Image.open(buffer) as image:
        palette = image.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    out = io.BytesIO()
    palette.save(out, format="PNG", optimize=True)
    atomic_write_bytes(path, out.getvalue())


def describe_picture(picture: RoutinePicture) -> str:
    """What the picture shows, as lines for the command line."""
    lines = []
    for film in picture.films:
        where = "does not occur" if film.occurrence is None else (
            f"f = {film.frequency}, first at episode {film.occurrence[0]}, step "
            f"{film.occurrence[1]}")
        lines.append(f"  routine {film.index}: {film.name}  ({where})")
    return "\n".join(lines)

