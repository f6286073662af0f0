"""Drawing a report's figures: one colour per method in every figure, figures on the Agg canvas
(no pyplot, no window), short game names for the axes, the IQM bar chart.

matplotlib loads when a figure is drawn, not on import.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from routine_gym.experiments.sections import Aggregate

__all__ = ["COLOURS", "OTHER_COLOUR", "colour", "figure", "game_labels", "iqm_bars",
           "legend_line"]

#: One colour per method, the same in every figure (matplotlib's tab10).
COLOURS = {
    "A2C": "#7f7f7f",
    "RAPL-A2C": "#d62728",
    "MacroAction": "#1f77b4",
    "OptionCritic": "#2ca02c",
    "CompILE": "#9467bd",
    "BC": "#8c564b",
    "GAIL": "#e377c2",
    "SQIL": "#17becf",
    "RAPL-SQIL": "#ff7f0e",
    # The PPO family (rl at the budgets with `rl_ppo`), darker shades of their A2C kin.
    "PPO": "#252525",
    "RAPL-PPO": "#843c39",
    "MacroAction-PPO": "#3182bd",
}
#: The colour of a label no method or experiment has a colour for.
OTHER_COLOUR = "#333333"


def figure(width: float, height: float) -> Any:
    """A matplotlib figure of `width` × `height` inches, constrained layout."""
    # A figure on the Agg canvas directly: no pyplot, no global backend, no window.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def colour(name: str, extra: Mapping[str, str] | None = None) -> str:
    """The colour of method `name` (`COLOURS`), else of a label of an experiment's own
    (`extra`, e.g. the ablation's variants), else `OTHER_COLOUR`."""
    return COLOURS.get(name, (extra or {}).get(name, OTHER_COLOUR))


_VERSION = re.compile(r"-v\d+$")


def game_labels(env_ids: Iterable[str]) -> dict[str, str]:
    """Short names for the axes: `MinAtar/Breakout-v1` → `Breakout`, with the suite kept
    where two suites share a game."""
    env_ids = list(dict.fromkeys(env_ids))
    full = {e: _VERSION.sub("", e.rpartition(":")[2]) for e in env_ids}
    short = {e: name.rpartition("/")[2] for e, name in full.items()}
    clash = {s for s in short.values() if list(short.values()).count(s) > 1}
    return {e: full[e] if short[e] in clash else short[e] for e in env_ids}


def iqm_bars(ax: Any, names: Sequence[str], agg: Aggregate, colours: Sequence[str]) -> None:
    """Bars of each name's IQM with its 95 % CI (in % when `agg` is normalised)."""
    scale = 100.0 if agg.percent else 1.0
    x = np.arange(len(names))
    points = np.array([agg.iqm.get(n, (np.nan,) * 3) for n in names], dtype=np.float64)
    heights = points[:, 0] * scale
    yerr = np.abs(np.vstack([points[:, 0] - points[:, 1], points[:, 2] - points[:, 0]])) * scale
    ax.bar(x, np.nan_to_num(heights), yerr=yerr, color=colours, capsize=5,
           error_kw={"elinewidth": 1.2})
    ax.set_xticks(x, names)
    ax.axhline(0.0, color="black", linewidth=0.8)


def legend_line(method: str) -> Any:
    """A legend entry: a line in `method`'s colour."""
    from matplotlib.lines import Line2D

    return Line2D([], [], color=colour(method), linewidth=2, label=method)
