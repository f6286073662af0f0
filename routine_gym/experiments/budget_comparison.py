"""The rl experiment at two budgets side by side: does RAPL-A2C catch up with A2C when both train
ten times as long (`routine-gym experiment report SWEEP --beside OTHER`, issue 28)?

Two sweep folders, each with an rl experiment (`rl.json`) at its own budget: typically the cpu
budget's 10^6 agent steps and the long budget's 10^7. Which side is the shorter budget comes
from the steps of the runs in their manifests, never from the order of the arguments. Each side
holds A2C, RAPL-A2C and, where it ran, RAPL-A2C as the authors' code has it
(`diagnosis.AUTHORS`): the rl experiment's own at the long budget, the diagnosis experiment's
(same flags, same steps) where the rl experiment has none, as at the cpu budget.

The comparison writes, beside the report's usual files in `SWEEP/report/`:

- `budgets_fig2.png/.csv`: Fig. 2 at both budgets, two bars per game (RAPL-A2C's relative
  performance `(S_R − S_A)/|S_A|` over A2C at each budget, error bar the standard error of S_R
  over seeds / |S_A|, as `rl.relative` has it), and the authors' code's where it ran; the CSV
  holds each game at each budget: the runs, S ± s.e. of every method, the relative performances,
  the verdicts, the gradient updates and RAPL's steps per decision.
- `budgets_curves.png/.csv`: per game, the training curves of both budgets on one log-step axis
  (mean over seeds, shaded ± sample std; `curves.mean_curve`), each curve marked where its runs
  had made 10^3, 10^4, 10^5 ... gradient updates (the mean over seeds of the counters' binned
  `updates`), so a reader sees that RAPL made fewer updates by the same step.
- `budgets_routines.png/.csv`: per game and budget, the share of RAPL's decisions that chose each
  routine and the primitive actions over training (mean over seeds of the counters' bins).
- a section of `report.md`: the table of the CSV, the verdicts from one budget to the other and
  the runs that have not finished (the long side may be partial: any subset works, a game
  without runs at a budget is named).

A verdict is Welch's t-test over seeds (`statistics.welch`, two-sided at 5 %): RAPL is
*better* or *worse* than A2C, or there is *no evidence* either way. (Before 2026-12-06 it was a
margin of the larger standard error, which called a noisier RAPL level with A2C.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from routine_gym.experiments.drawing import colour, figure, game_labels
from routine_gym.experiments.paper import diagnosis
from routine_gym.experiments.paper.curves import MeanCurve, mean_curve
from routine_gym.experiments.paper.diagnosis import AUTHORS
from routine_gym.experiments.paper.rl import relative
from routine_gym.experiments.registry import EXPERIMENTS
from routine_gym.experiments.results import RunRecord, load_runs
from routine_gym.experiments.run_counters import mean_bins, mean_routine_shares, run_counter
from routine_gym.experiments.statistics import standard_error, welch
from routine_gym.experiments.writing import Writer, num, pct, table
from routine_gym.plumbing.errors import UsageError

__all__ = ["FILES", "METHODS", "Side", "compare", "load_sides", "section", "steps_label"]

FIG2 = "budgets_fig2"
CURVES = "budgets_curves"
ROUTINES = "budgets_routines"
#: The stems of the files the comparison writes into `SWEEP/report/` (each `.png` and `.csv`).
FILES = (FIG2, CURVES, ROUTINES)
#: The methods compared, in the order of the tables and figures.
METHODS = ("A2C", "RAPL-A2C", AUTHORS)
#: The methods that choose among routines (A2C has none).
ROUTINE_METHODS = ("RAPL-A2C", AUTHORS)
SHORT_NAMES = {"A2C": "A2C", "RAPL-A2C": "RAPL", AUTHORS: "authors"}
NO_RUNS = "no runs"
#: The marker of a curve where its runs had made 10^k gradient updates, by k.
UPDATE_MARKERS = {1: "p", 2: "h", 3: "o", 4: "s", 5: "^", 6: "D", 7: "v", 8: "P"}
#: The colours of the routines (by index) and of the primitive actions in the usage figure.
ROUTINE_COLOURS = ("#ff7f0e", "#2ca02c", "#9467bd", "#e377c2", "#17becf", "#bcbd22",
                   "#8c564b", "#1f77b4")
PRIMITIVE_COLOUR = "#d9d9d9"


class Side(NamedTuple):
    """One sweep's rl experiment at its budget."""

    out: Path
    budget: str  # the manifest's budget name
    steps: int  # the agent steps of its runs
    runs: list[RunRecord]  # every run of METHODS it lists (finished or not), one per key
    authors_from: str | None  # the manifest the authors' runs come from: "rl", "diagnosis"

    @property
    def label(self) -> str:
        return steps_label(self.steps)

    def finished(self, method: str, env_id: str) -> list[RunRecord]:
        return [r for r in self.runs if r.finished and diagnosis.label(r) == method
                and r.env_id == env_id]

    @property
    def games(self) -> list[str]:
        return sorted({r.env_id for r in self.runs})


def steps_label(steps: int) -> str:
    """Agent steps as a reader says them: `10^6`, `5·10^5`, else with thousands separators.

    Example:
        >>> steps_label(10_000_000), steps_label(500_000), steps_label(1_234)
        ('10^7', '5·10^5', '1,234')
    """
    digits = str(steps)
    zeros = len(digits) - len(digits.rstrip("0"))
    head = digits[: len(digits) - zeros]
    if steps >= 10 and zeros >= 1 and len(head) == 1:
        return f"10^{zeros}" if head == "1" else f"{head}·10^{zeros}"
    return f"{steps:,}"


def _tex(steps: int) -> str:
    """`steps_label` in matplotlib's mathtext."""
    text = steps_label(steps)
    if "^" not in text:
        return text
    head, _, power = text.rpartition("^")
    return "$" + head.replace("·", r"\cdot ") + "^{" + power + "}$"


def _load_side(out: Path, flag: str) -> Side:
    """`out`'s rl experiment (and the authors' runs of its diagnosis experiment where the rl
    experiment has none); UsageError naming the folder or file for anything else."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: a file, not a sweep folder ({flag} names the --out of "
                         "`routine-gym experiment run`)")
    if not out.is_dir():
        raise UsageError(f"{out}: no such sweep folder ({flag} names the --out of "
                         "`routine-gym experiment run`)")
    if not any((out / f"{name}.json").is_file() for name in EXPERIMENTS):
        raise UsageError(f"{out}: not a sweep folder: none of "
                         f"{', '.join(n + '.json' for n in EXPERIMENTS)} is there")
    results: dict[str, Any] = {}
    rl = load_runs(out, "rl", results)
    if rl is None:
        raise UsageError(f"{out}: no rl experiment there (no rl.json): the budget comparison "
                         "compares the rl experiment's runs at two budgets")
    runs = {r.key: r for r in rl.runs if r.role == "main" and diagnosis.label(r) in METHODS}
    if not any(diagnosis.label(r) in ("A2C", "RAPL-A2C") for r in runs.values()):
        raise UsageError(f"{out / 'rl.json'}: no run of A2C or RAPL-A2C: nothing to compare")
    steps = max(r.steps for r in runs.values())
    authors_from = "rl" if any(diagnosis.label(r) == AUTHORS for r in runs.values()) else None
    if authors_from is None:
        found = load_runs(out, "diagnosis", results)
        extra = [r for r in (found.runs if found else []) if r.role == "main"
                 and diagnosis.label(r) == AUTHORS and r.steps == steps]
        if extra:
            authors_from = "diagnosis"
            runs.update((r.key, r) for r in extra)
    return Side(out, rl.budget, steps, list(runs.values()), authors_from)


def load_sides(out: str | Path, beside: str | Path) -> tuple[Side, Side]:
    """`(shorter, longer)`: the rl experiments of the sweep `out` and of `beside`, ordered by
    the steps of their runs.

    Raises:
        UsageError: one line: a folder missing, a file, not a sweep folder, without an rl
            experiment or without an A2C or RAPL-A2C run in it; both at the same steps.
    """
    sides = [_load_side(Path(out), "the sweep"), _load_side(Path(beside), "--beside")]
    a, b = sides
    if a.steps == b.steps:
        budgets = a.budget if a.budget == b.budget else f"{a.budget} and {b.budget}"
        raise UsageError(f"{a.out} and {b.out}: both at {steps_label(a.steps)} agent steps "
                         f"(budget {budgets}): --beside needs the rl experiment at another "
                         "budget (e.g. cpu's 10^6 steps beside long's 10^7)")
    short, long = sorted(sides, key=lambda s: s.steps)
    return short, long


def compare(scores: Sequence[float], a2c: Sequence[float]) -> str:
    """RAPL's verdict against A2C on a game from the final scores of their runs: Welch's
    t-test over seeds (`statistics.welch`): `better`, `worse` or `no evidence`, with the
    p-value; `no runs` without both.

    Example:
        >>> compare([4, 6, 5], [5, 5, 6]), compare([7, 8, 9], [1, 2, 3]), compare([2, 3], [5])
        ('no evidence (p = 0.667)', 'better (p = 0.018)', 'not enough runs')
    """
    if not scores or not a2c:
        return NO_RUNS
    c = welch(scores, a2c)
    return c.verdict if c.verdict == "not enough runs" else f"{c.verdict} (p = {c.p:.3f})"


class Row(NamedTuple):
    """One game at one budget: a row of `budgets_fig2.csv`."""

    env_id: str
    side: Side
    runs: dict[str, int]  # finished runs per method
    expected: dict[str, int]  # runs the manifest lists per method
    means: dict[str, float]
    errors: dict[str, float]  # standard error over seeds
    relative: dict[str, tuple[float, float]]  # RAPL-A2C, AUTHORS: (relative %, error %)
    verdicts: dict[str, str]  # RAPL-A2C, AUTHORS
    updates: dict[str, float]  # mean over seeds
    steps_per_decision: dict[str, float]
    routine_share: dict[str, float]


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def _row(side: Side, env_id: str) -> Row:
    finished = {m: side.finished(m, env_id) for m in METHODS}
    scores = {m: [r.score for r in rs] for m, rs in finished.items()}
    rel, verdicts = {}, {}
    for m in ROUTINE_METHODS:
        if scores[m] and scores["A2C"]:
            value, error = relative(scores[m], scores["A2C"])
            rel[m] = (100 * value, 100 * error)
        else:
            rel[m] = (math.nan, math.nan)
        verdicts[m] = compare(scores[m], scores["A2C"])
    return Row(
        env_id, side, {m: len(rs) for m, rs in finished.items()},
        {m: sum(1 for r in side.runs if diagnosis.label(r) == m and r.env_id == env_id)
         for m in METHODS},
        {m: float(np.mean(s)) if s else math.nan for m, s in scores.items()},
        {m: standard_error(s) if s else math.nan for m, s in scores.items()},
        rel, verdicts,
        {m: _mean([run_counter(r, "updates") for r in rs]) for m, rs in finished.items()},
        {m: _mean([run_counter(r, "steps_per_decision") for r in rs])
         for m, rs in finished.items()},
        {m: 1.0 - _mean([run_counter(r, "primitive_share") for r in rs])
         for m, rs in finished.items()})


def _csv_row(row: Row) -> tuple[Any, ...]:
    return (row.env_id, row.side.budget, row.side.steps,
            *(row.runs[m] for m in METHODS), *(row.expected[m] for m in METHODS),
            *(x for m in METHODS for x in (row.means[m], row.errors[m])),
            *(x for m in ROUTINE_METHODS for x in row.relative[m]),
            *(row.verdicts[m] for m in ROUTINE_METHODS),
            *(row.updates[m] for m in METHODS),
            *(row.steps_per_decision[m] for m in ROUTINE_METHODS),
            *(row.routine_share[m] for m in ROUTINE_METHODS))


CSV_HEADER = ("env_id", "budget", "steps", "runs_A2C", "runs_RAPL", "runs_authors",
              "expected_A2C", "expected_RAPL", "expected_authors", "S_A", "S_A_se", "S_R",
              "S_R_se", "S_authors", "S_authors_se", "relative_pct", "error_pct",
              "authors_relative_pct", "authors_error_pct", "verdict", "authors_verdict",
              "updates_A2C", "updates_RAPL", "updates_authors", "steps_per_decision_RAPL",
              "steps_per_decision_authors", "routine_share_RAPL", "routine_share_authors")


def section(w: Writer, short: Side, long: Side, here: Path) -> list[str]:
    """Write the comparison's figures and CSVs through `w` and return its lines of `report.md`
    (`here`: the sweep whose report this is)."""
    sides = (short, long)
    games = sorted({g for s in sides for g in s.games})
    rows = {(g, s.steps): _row(s, g) for g in games for s in sides}
    w.csv(FIG2, CSV_HEADER, [_csv_row(rows[g, s.steps]) for g in games for s in sides])
    _draw_fig2(w, games, sides, rows)
    _curves(w, games, sides)
    _routines(w, games, sides)
    return _lines(games, sides, rows, here)


def _present(sides: Sequence[Side], method: str) -> bool:
    return any(diagnosis.label(r) == method and r.finished for s in sides for r in s.runs)


def _same_or_better(rows: dict[tuple[str, int], Row], games: list[str], side: Side
                    ) -> tuple[int, int]:
    """(games where S_R ≥ S_A, games with runs of both) at `side`: Fig. 2's count, so the two
    reports of the same runs say the same (the verdicts' *same* also takes in a RAPL-A2C
    within a standard error below A2C, MiniQbert's 1047.8 against 1050 at 10^6)."""
    judged = [rows[g, side.steps] for g in games
              if rows[g, side.steps].verdicts["RAPL-A2C"] != NO_RUNS]
    return sum(1 for r in judged if r.means["RAPL-A2C"] >= r.means["A2C"]), len(judged)


def _draw_fig2(w: Writer, games: list[str], sides: Sequence[Side],
               rows: dict[tuple[str, int], Row]) -> None:
    from matplotlib.patches import Patch

    series = [(m, s) for m in ROUTINE_METHODS if _present(sides, m) for s in sides]
    labels = game_labels(games)
    fig = figure(max(8.5, 0.45 * len(games) * len(series) + 2.5), 4.8)
    ax = fig.subplots()
    width = 0.8 / len(series)
    x = np.arange(len(games))
    heights = []
    for i, (m, side) in enumerate(series):
        offset = x - 0.4 + width * (i + 0.5)
        values = [rows[g, side.steps].relative[m] for g in games]
        long_side = side is sides[-1]
        ax.bar(offset, [np.nan_to_num(v) for v, _ in values], width * 0.92,
               yerr=[e if math.isfinite(e) else 0.0 for _, e in values],
               color=colour(m, diagnosis.VARIANT_COLOURS), alpha=1.0 if long_side else 0.45,
               hatch=None if long_side else "///", edgecolor="white", capsize=3,
               error_kw={"elinewidth": 1.0})
        heights += [v + e for v, e in values if math.isfinite(v)]
        for xi, g, (v, _) in zip(offset, games, values, strict=True):
            if not math.isfinite(v):
                row = rows[g, side.steps]
                text = NO_RUNS if row.verdicts[m] == NO_RUNS else "n/a"
                ax.text(xi, 0.0, f" {text}", rotation=90, ha="center", va="bottom",
                        fontsize=7, color="#555555")
    ax.axhline(0.0, color="black", linewidth=0.8)
    bottom, top = ax.get_ylim()
    ax.set_ylim(bottom, max(top, 0.2 * (top - bottom)))  # room above 0 for "no runs"
    ax.set_xticks(x, [labels[g] for g in games])
    ax.set_ylabel("relative performance (S − S_A)/|S_A| (%)")
    ax.set_xlabel("game (error bar: standard error of S over seeds / |S_A|; hatched: the "
                  "shorter budget)")
    counts = [_same_or_better(rows, games, s) for s in sides]
    ax.set_title("RAPL-A2C same or better than A2C (S_R ≥ S_A) on "
                 + ", ".join(f"{k} of {n} games at {_tex(s.steps)}" if n else
                             f"no game yet at {_tex(s.steps)}"
                             for (k, n), s in zip(counts, sides, strict=True)), fontsize=10)
    handles = [Patch(facecolor=colour(m, diagnosis.VARIANT_COLOURS),
                     alpha=1.0 if s is sides[-1] else 0.45,
                     hatch=None if s is sides[-1] else "///", edgecolor="white",
                     label=f"{m}, {_tex(s.steps)} steps ({s.budget})") for m, s in series]
    ax.legend(handles=handles, loc="best", fontsize=8, framealpha=0.9)
    fig.suptitle("Fig. 2 at two budgets — does RAPL-A2C catch up with A2C given more steps?")
    w.png(fig, FIG2)


class _Curve(NamedTuple):
    curve: MeanCurve
    updates: np.ndarray | None  # mean cumulative updates at each counters bin's end
    update_steps: np.ndarray | None  # those bins' ends


def _side_curves(side: Side, env_id: str) -> dict[str, _Curve]:
    out = {}
    for m in METHODS:
        runs = side.finished(m, env_id)
        curve = mean_curve(runs, side.steps) if runs else None
        if curve is None:
            continue
        updates = mean_bins(runs, "updates")
        steps = None
        if updates is not None:
            steps = np.linspace(0.0, float(side.steps), len(updates) + 1)[1:]
        out[m] = _Curve(curve, updates, steps)
    return out


def update_marks(curve: _Curve) -> list[tuple[int, float, float]]:
    """`(k, step, return)` where the curve's runs had made 10^k updates on average (linear
    between the counters' bins, from 0 updates at step 0), on the curve (from its first bin
    with a value on)."""
    if curve.updates is None or not np.isfinite(curve.updates).all():
        return []
    made = np.concatenate([[0.0], curve.updates])
    at = np.concatenate([[0.0], curve.update_steps])
    x, mean = curve.curve.steps, curve.curve.mean
    ok = np.isfinite(mean)
    if not ok.any() or np.any(np.diff(made) < 0):
        return []
    marks = []
    for k in UPDATE_MARKERS:
        if 10 ** k > made[-1]:
            break
        step = float(np.interp(10 ** k, made, at))
        if step >= x[ok][0]:
            marks.append((k, step, float(np.interp(step, x[ok], mean[ok]))))
    return marks


def _thousands(value: float) -> str:
    """Updates as read in a figure: `730`, `7.3k`, `125k`; – for none."""
    if not math.isfinite(value):
        return "–"
    if value < 1000:
        return f"{value:.0f}"
    return f"{value / 1000:.1f}k" if value < 100_000 else f"{value / 1000:.0f}k"


def _curves(w: Writer, games: list[str], sides: Sequence[Side]) -> None:
    from matplotlib.lines import Line2D

    curves = {(g, s.steps): _side_curves(s, g) for g in games for s in sides}
    csv_rows = []
    for g in games:
        for s in sides:
            for m, c in curves[g, s.steps].items():
                updates = (np.interp(c.curve.steps, c.update_steps, c.updates)
                           if c.updates is not None else np.full(len(c.curve.steps), np.nan))
                csv_rows += [(g, s.budget, s.steps, m, float(c.curve.steps[i]),
                              c.curve.mean[i], c.curve.std[i], int(c.curve.runs[i]),
                              float(updates[i])) for i in range(len(c.curve.steps))]
    w.csv(CURVES, ("env_id", "budget", "steps", "method", "step", "mean_return", "std_return",
                   "runs", "updates"), csv_rows)

    labels = game_labels(games)
    cols = min(3, max(1, len(games)))
    rows_n = max(1, math.ceil(len(games) / cols))
    fig = figure(max(7.0, 5.0 * cols), 3.9 * rows_n + 1.2)
    axes = np.atleast_1d(fig.subplots(rows_n, cols, squeeze=False)).ravel()
    styles = {sides[0].steps: "--", sides[-1].steps: "-"}
    decades: set[int] = set()
    for ax, g in zip(axes, games, strict=False):
        notes = []
        for s in sides:
            drawn = curves[g, s.steps]
            for m, c in drawn.items():
                col = colour(m, diagnosis.VARIANT_COLOURS)
                x, mean, std = c.curve.steps, c.curve.mean, c.curve.std
                ax.plot(x, mean, color=col, linestyle=styles[s.steps], linewidth=1.5)
                ax.fill_between(x, mean - std, mean + std, color=col, alpha=0.12, linewidth=0)
                for k, step, y in update_marks(c):
                    decades.add(k)
                    ax.plot(step, y, marker=UPDATE_MARKERS[k], color=col, markersize=6.5,
                            markeredgecolor="black", markeredgewidth=0.7, linestyle="")
            made = [f"{SHORT_NAMES[m]} {_thousands(_mean(list(c.updates[-1:])))}"
                    for m, c in drawn.items() if c.updates is not None]
            notes.append(f"{_tex(s.steps)}: " + (", ".join(made) if made else
                                                  ("no updates counted" if drawn
                                                   else "no finished run")))
        ax.set_xscale("log")
        ax.set_title(labels[g])
        ax.set_xlabel("agent steps (log)")
        ax.set_ylabel("episodic return")
        # A legend of text only, so matplotlib puts it where it hides the least of the curves.
        ax.legend(handles=[Line2D([], [], linestyle="") for _ in notes], labels=notes,
                  title="updates made", title_fontsize=7, fontsize=7, loc="best",
                  handlelength=0, handletextpad=0, framealpha=0.6)
    for ax in axes[len(games):]:
        ax.set_visible(False)
    methods = [m for m in METHODS if _present(sides, m)]
    handles = [Line2D([], [], color=colour(m, diagnosis.VARIANT_COLOURS), linewidth=2,
                      label=m) for m in methods]
    handles += [Line2D([], [], color="black", linestyle=styles[s.steps], linewidth=1.5,
                       label=f"{_tex(s.steps)} steps ({s.budget})") for s in sides]
    handles += [Line2D([], [], color="white", marker=UPDATE_MARKERS[k], markersize=7,
                       markeredgecolor="black", markerfacecolor="#999999", linestyle="",
                       label=f"$10^{{{k}}}$ updates") for k in sorted(decades)]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 6),
               fontsize=8)
    fig.suptitle("Training curves at both budgets (mean ± std over seeds); markers: where a "
                 "method's runs had made $10^k$ gradient updates", fontsize=11)
    w.png(fig, CURVES)


def _routines(w: Writer, games: list[str], sides: Sequence[Side]) -> None:
    panels = [(m, s) for m in ROUTINE_METHODS if _present(sides, m) for s in sides]
    usage: dict[tuple[str, str, int], tuple[np.ndarray, np.ndarray | None, int]] = {}
    csv_rows = []
    for g in games:
        for m, s in panels:
            runs = s.finished(m, g)
            primitive = mean_bins(runs, "primitive_share") if runs else None
            if primitive is None:
                continue
            shares = mean_routine_shares(runs)
            usage[g, m, s.steps] = (primitive, shares, len(runs))
            x = np.linspace(0.0, float(s.steps), len(primitive) + 1)[1:]
            choices = [("primitives", primitive)] + [
                (f"routine {k + 1}", shares[k]) for k in range(len(shares) if shares is not None
                                                              else 0)]
            csv_rows += [(g, s.budget, s.steps, m, float(x[i]), name, values[i], len(runs))
                         for name, values in choices for i in range(len(x))]
    w.csv(ROUTINES, ("env_id", "budget", "steps", "method", "step", "choice", "share", "runs"),
          csv_rows)

    from matplotlib.patches import Patch

    labels = game_labels(games)
    cols = max(1, len(panels))
    fig = figure(max(7.0, 3.4 * cols), 2.3 * len(games) + 1.4)
    axes = fig.subplots(len(games), cols, squeeze=False, sharey=True)
    most = 0
    for r, g in enumerate(games):
        for c, (m, s) in enumerate(panels):
            ax = axes[r, c]
            if r == 0:
                ax.set_title(f"{m}\nat {_tex(s.steps)} steps ({s.budget})", fontsize=9)
            if c == 0:
                ax.set_ylabel(f"{labels[g]}\nshare of decisions")
            ax.set_xlim(0, s.steps)
            ax.set_ylim(0, 1)
            ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
            if (g, m, s.steps) not in usage:
                why = ("no runs at this budget" if g not in s.games else "no finished run yet"
                       if not s.finished(m, g) else "no counters in its runs")
                ax.text(0.5, 0.5, why, ha="center", va="center", transform=ax.transAxes,
                        fontsize=8, color="#555555")
                continue
            primitive, shares, n = usage[g, m, s.steps]
            x = np.linspace(0.0, float(s.steps), len(primitive) + 1)[1:]
            stack = [np.nan_to_num(v) for v in (shares if shares is not None else [])]
            most = max(most, len(stack))
            ax.stackplot(x, *stack, np.nan_to_num(primitive),
                         colors=[*ROUTINE_COLOURS[:len(stack)], PRIMITIVE_COLOUR],
                         linewidth=0)
            ax.text(0.98, 0.04, f"{n} run{'s' if n != 1 else ''}", ha="right", va="bottom",
                    transform=ax.transAxes, fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("agent steps")
    handles = [Patch(color=ROUTINE_COLOURS[k], label=f"routine {k + 1}") for k in range(most)]
    handles.append(Patch(color=PRIMITIVE_COLOUR, label="primitive actions"))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8)
    fig.suptitle("Routine usage over training (mean over seeds): the share of decisions that "
                 "chose\neach routine (bottom) or a primitive action (top)", fontsize=10)
    w.png(fig, ROUTINES)


def _seeds(runs: list[RunRecord]) -> str:
    seeds = sorted(r.seed for r in runs)
    return f"seed{'s' if len(seeds) > 1 else ''} {', '.join(str(s) for s in seeds)}"


def _missing_lines(games: list[str], side: Side) -> list[str]:
    missing = [r for r in side.runs if not r.finished]
    head = (f"At {side.label} steps (budget {side.budget}, `{side.out}`): "
            f"{len(side.runs) - len(missing)} of {len(side.runs)} runs finished")
    where = f" (the authors' code's from its `{side.authors_from}.json`)" \
        if side.authors_from == "diagnosis" else ""
    lines = [f"- {head}{where}" + (":" if missing else ".")]
    for g in games:
        if g not in side.games:
            lines.append(f"  - {g}: no runs at this budget (not in this sweep's rl experiment).")
            continue
        parts = [f"{m} {_seeds(rs)}" for m in METHODS
                 if (rs := [r for r in missing if r.env_id == g and diagnosis.label(r) == m])]
        if parts:
            lines.append(f"  - {g}: " + "; ".join(parts) + " not finished.")
    return lines


def _cell(row: Row, m: str) -> str:
    if row.runs[m] == 0:
        return "–"
    return f"{num(row.means[m])} ± {num(row.errors[m])}"


def _rel(row: Row, m: str) -> str:
    value, error = row.relative[m]
    if row.verdicts[m] == NO_RUNS:
        return "–"
    if not math.isfinite(value):
        return "n/a"
    return f"{pct(value / 100)} ± {pct(error / 100)}"


def _lines(games: list[str], sides: Sequence[Side], rows: dict[tuple[str, int], Row],
           here: Path) -> list[str]:
    short, long = sides
    other = long if short.out == here else short
    authors = _present(sides, AUTHORS)
    lines = [f"## Fig. 2 at two budgets — does RAPL-A2C catch up with A2C at {long.label} "
             "steps? (`--beside`)", "",
             f"The rl experiment of this sweep (`{here}`) beside `{other.out}`'s: "
             f"{short.label} agent steps (budget {short.budget}) and {long.label} (budget "
             f"{long.budget}); which is which comes from the steps of their runs. "
             f"Figures: `{FIG2}.png` (relative performance per game at both budgets), "
             f"`{CURVES}.png` (training curves of both budgets on one log-step axis, marked "
             f"where the runs had made 10^k gradient updates), `{ROUTINES}.png` (RAPL's routine "
             f"usage over training); data: `{FIG2}.csv`, `{CURVES}.csv`, `{ROUTINES}.csv`.", "",
             "S = mean over seeds of the final evaluation's mean return ± its standard error "
             "over seeds; relative = (S − S_A)/|S_A| ± s.e. of S / |S_A| (Fig. 2's); verdict: "
             "Welch's t-test over seeds, two-sided at 5 % (ν = the smaller count − 1): "
             "*better*, *worse* or *no evidence*, with its p-value; "
             "updates: gradient updates per run, steps/decision: agent steps per decision "
             "(mean over seeds, from the runs' counters)."
             + (f" {AUTHORS} (`--authors`) is the authors' preset: its own columns, never "
                "in S_R." if authors else ""), ""]
    header = ("game", "steps", "runs A2C/RAPL" + ("/authors" if authors else ""), "S_A", "S_R",
              *(("S_authors",) if authors else ()), "RAPL relative", "RAPL",
              *(("authors relative", "authors") if authors else ()), "updates A2C",
              "updates RAPL", *(("updates authors",) if authors else ()),
              "RAPL steps/decision", *(("authors steps/decision",) if authors else ()))
    methods = METHODS if authors else METHODS[:2]
    body = []
    for g in games:
        for s in sides:
            row = rows[g, s.steps]
            body.append((
                g, s.label, "/".join(f"{row.runs[m]}" for m in methods),
                _cell(row, "A2C"), _cell(row, "RAPL-A2C"),
                *((_cell(row, AUTHORS),) if authors else ()),
                _rel(row, "RAPL-A2C"), row.verdicts["RAPL-A2C"],
                *((_rel(row, AUTHORS), row.verdicts[AUTHORS]) if authors else ()),
                *(num(row.updates[m], 0) for m in methods),
                num(row.steps_per_decision["RAPL-A2C"]),
                *((num(row.steps_per_decision[AUTHORS]),) if authors else ())))
    lines += table(header, body)
    counts = [_same_or_better(rows, games, s) for s in sides]
    lines += ["**RAPL-A2C same or better than A2C (S_R ≥ S_A, as Fig. 2 counts) on "
              + " and ".join(f"{k} of {n} games at {s.label} steps" if n else
                             f"no game yet at {s.label} steps"
                             for (k, n), s in zip(counts, sides, strict=True))
              + "** (a game counts at a budget once A2C and RAPL-A2C have finished runs "
              "there; *no runs* in the table: not yet; the verdicts' *same* is level within "
              "a standard error).", ""]
    changes = []
    for g in games:
        before, after = rows[g, short.steps], rows[g, long.steps]
        if NO_RUNS in (before.verdicts["RAPL-A2C"], after.verdicts["RAPL-A2C"]):
            continue
        changes.append(f"{g}: {before.verdicts['RAPL-A2C']} → {after.verdicts['RAPL-A2C']} "
                       f"({_rel(before, 'RAPL-A2C')} → {_rel(after, 'RAPL-A2C')})")
    if changes:
        lines += [f"From {short.label} to {long.label} steps, RAPL-A2C against A2C: "
                  + "; ".join(changes) + ".", ""]
    else:
        lines += [f"No game has finished runs of A2C and RAPL-A2C at both budgets yet: no "
                  f"verdict from {short.label} to {long.label} steps.", ""]
    lines += ["Runs:", "", *_missing_lines(games, short), *_missing_lines(games, long), ""]
    return lines
