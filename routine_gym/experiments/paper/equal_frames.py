"""Equal frames (issue 49, beyond the paper): do routine learners that pay for their routines
beat A2C and PPO at the same agent steps?

Per family (`rapl_a2c.py`: A2C; `rapl_ppo.py`: PPO), on each rl game and seed of a budget with
tuning (the fair protocol: its demos, seeds and tuned learning rates):

- the baseline (A2C, PPO) and RAPL as published (RAPL-A2C, RAPL-PPO): the rl experiment's runs;
- RAPL with each mechanism alone (`MECHANISMS`): rollouts sized in primitive steps (equal
  updates at equal frames), intra-routine policy learning, interruption, a routine's logit
  started at its first primitive's;
- RAPL with all of them at once (`all`, declared before any run: not picked from the results,
  which would favour it);
- on budgets with `leave_one_out` (at `fair`, 10^6: both families), RAPL with all but one
  mechanism (`all but interruption`, ...): which mechanisms carry the combination. Added
  after all four's results, so a diagnosis, not a candidate: the goal does not judge them.

Every RAPL arm learns with RAPL's tuned settings (its method's grid point of the tune
experiment): the mechanisms are not tuned, so an arm that needs another learning rate is at
a disadvantage, not an advantage. The mechanisms' own settings (`--intra-coef 1`, `--interrupt
1`: stop where the policy prefers another action by more than one nat) are fixed here too.

The report: per game, each arm's mean final score ± its standard error and, against the
family's baseline and against RAPL as published, Welch's t-test over seeds (better / worse / no
evidence, with Δ and p); per family the rliable IQMs and P(X > baseline) with their 95 % CIs;
whether an arm meets the issue's goal (at or above the baseline on ≥ 3 of the 5 games and
P(X > baseline) ≥ 0.6 with its interval above 0.5); and what each mechanism closed of RAPL's
gap to the baseline, per game. Figures: each arm's relative performance over its baseline per
game (`equal_frames.png`), and the A2C family's training curves over frames with its update
clock below them (`equal_frames_curves.png`: updates made against frames, per arm).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np

from routine_gym.experiments.drawing import figure, game_labels
from routine_gym.experiments.experiment import Experiment
from routine_gym.experiments.results import RunRecord
from routine_gym.experiments.run_counters import mean_bins, run_counter
from routine_gym.experiments.sections import aggregate, aggregate_lines, group_runs
from routine_gym.experiments.specs import Builder
from routine_gym.experiments.statistics import probability_of_improvement, standard_error, welch
from routine_gym.experiments.training_curves import run_curve
from routine_gym.experiments.writing import Writer, interval, num, pct, table

FILE = "equal_frames"
CURVES_FILE = "equal_frames_curves"
LEAVE_ONE_OUT_FILE = "equal_frames_leave_one_out"
#: Each mechanism's flags (the same on both scripts), in the report's order; `all` is every
#: one of them at once.
MECHANISMS: dict[str, tuple[tuple[str, object], ...]] = {
    "equal updates": (("rollout-unit", "steps"),),
    "intra-routine": (("intra-coef", 1.0),),
    "interruption": (("interrupt", 1.0),),
    "first-action logit": (("routine-logit", "first-action"),),
}
ALL = "all"
#: The families that may have leave-one-out arms (a budget's `leave_one_out` names those it
#: runs): the A2C family's first, whose all four are level with A2C; the PPO family's, whose
#: all four are below PPO on two games (which mechanism does it?), from the wider grid on.
LEAVE_ONE_OUT_FAMILIES = ("A2C", "PPO")
#: (baseline, RAPL as published) of each family.
FAMILIES = {"A2C": ("A2C", "RAPL-A2C"), "PPO": ("PPO", "RAPL-PPO")}
#: The goal of issue 49: at or above the baseline on this many games, P(X > baseline) at least
#: `GOAL_POI` with the lower end of its 95 % interval above 0.5.
GOAL_GAMES, GOAL_POI = 3, 0.6
#: Where an arm meets the rest of the goal and its interval's lower end lies within `GOAL_EDGE`
#: of 0.5, the goal reads the interval again with `GOAL_REPS` resamples (rliable's default): at
#: the report's 2,000 the percentile's Monte Carlo error can decide "above 0.5" (the fair
#: sweep's RAPL-A2C + all: 0.504 at 2,000 with seed 0, 0.496 at 50,000).
GOAL_EDGE, GOAL_REPS = 0.02, 50_000
PALETTE = ("#7f7f7f", "#d62728", "#ff7f0e", "#2ca02c", "#9467bd", "#17becf", "#000000")


def arm(rapl: str, mechanism: str) -> str:
    """An arm's label: `RAPL-A2C + intra-routine`."""
    return f"{rapl} + {mechanism}"


def arms(family: str) -> tuple[str, ...]:
    """A family's arms in the report's order: the baseline, RAPL, each mechanism, all."""
    base, rapl = FAMILIES[family]
    return (base, rapl, *(arm(rapl, m) for m in (*MECHANISMS, ALL)))


def without(mechanism: str) -> str:
    """The leave-one-out arm's mechanism name: every mechanism but `mechanism`.

    Example:
        >>> without("interruption")
        'all but interruption'
    """
    return f"{ALL} but {mechanism}"


def leave_one_out_arms(family: str) -> tuple[str, ...]:
    """A family's leave-one-out arms (`RAPL-A2C + all but interruption`, ...), in
    `MECHANISMS`' order; none for a family without them."""
    if family not in LEAVE_ONE_OUT_FAMILIES:
        return ()
    return tuple(arm(FAMILIES[family][1], without(m)) for m in MECHANISMS)


def mechanism_flags(mechanism: str) -> tuple[tuple[str, object], ...]:
    """The flags of one mechanism, of all (`ALL`), or of all but one (`without(m)`)."""
    if mechanism == ALL:
        return tuple(flag for flags in MECHANISMS.values() for flag in flags)
    left_out = {without(m): m for m in MECHANISMS}.get(mechanism)
    if left_out is not None:
        return tuple(flag for m, flags in MECHANISMS.items() if m != left_out for flag in flags)
    return MECHANISMS[mechanism]


def add_runs(b: Builder) -> None:
    """Every arm of both families on each rl game and seed; on a budget without tuning the
    experiment has no runs (its comparisons need the fair protocol's tuned settings)."""
    if not b.budget.tune_seeds:
        b.left_out.append({"experiment": "equal-frames",
                           "why": "a budget without tuning (the fair protocol's only)"})
        return
    for env_id in b.budget.rl_games:
        for seed in b.seeds():
            b.a2c("A2C", env_id, seed)
            b.a2c("RAPL-A2C", env_id, seed)
            b.ppo("PPO", env_id, seed)
            b.ppo("RAPL-PPO", env_id, seed)
            for mechanism in (*MECHANISMS, ALL):
                flags = mechanism_flags(mechanism)
                b.a2c("RAPL-A2C", env_id, seed, {"mechanism": mechanism}, extra=flags)
                b.ppo("RAPL-PPO", env_id, seed, {"mechanism": mechanism}, extra=flags)
            for family in b.budget.leave_one_out:
                add = b.a2c if family == "A2C" else b.ppo
                for left_out in MECHANISMS:
                    name = without(left_out)
                    add(FAMILIES[family][1], env_id, seed, {"mechanism": name},
                        extra=mechanism_flags(name))


def label(run: RunRecord) -> str | None:
    """The arm a run is: a baseline or RAPL without a variant, or RAPL with a mechanism."""
    mechanism = run.variant.get("mechanism")
    if mechanism is None:
        return run.method if not run.variant and run.method in (
            "A2C", "RAPL-A2C", "PPO", "RAPL-PPO") else None
    return arm(run.method, mechanism) if run.method in ("RAPL-A2C", "RAPL-PPO") else None


def verdict(x: Sequence[float], y: Sequence[float]) -> str:
    """Welch's test of arm X against Y over seeds, one cell: `better (Δ +1.2, p = 0.03)`."""
    if len(x) < 2 or len(y) < 2:
        return "–"
    return welch(x, y).describe()


def gap_closed(s_arm: float, s_rapl: float, s_base: float) -> float:
    """The share of RAPL's gap to the baseline an arm closes: (S_X − S_R)/(S_B − S_R); NaN
    where RAPL is not below the baseline (no gap).

    Example:
        >>> gap_closed(8.0, 5.0, 11.0), gap_closed(12.0, 5.0, 11.0)
        (0.5, 1.1666666666666667)
        >>> math.isnan(gap_closed(8.0, 12.0, 11.0))
        True
    """
    gap = s_base - s_rapl
    return (s_arm - s_rapl) / gap if gap > 0 else math.nan


def carried(s_all: float, s_without: float, s_rapl: float) -> float:
    """The share of all mechanisms' gain over RAPL that one mechanism carries, read from the
    arm without it: (S_all − S_without)/(S_all − S_R); NaN where all of them are not above
    RAPL (no gain to share). 1: without it the gain is gone; 0: it adds nothing; < 0: the
    combination does better without it.

    Example:
        >>> carried(15.0, 9.0, 5.0), carried(15.0, 16.0, 5.0)
        (0.6, -0.1)
        >>> math.isnan(carried(5.0, 9.0, 6.0))
        True
    """
    gain = s_all - s_rapl
    return (s_all - s_without) / gain if gain > 0 else math.nan


def _scores(runs: list[RunRecord], env_id: str) -> list[float]:
    return [r.score for r in runs if r.env_id == env_id]


def _family_lines(w: Writer, family: str, groups: dict[str, list[RunRecord]],
                  games: list[str]) -> list[str]:
    base, rapl = FAMILIES[family]
    names = [a for a in arms(family) if a in groups]
    if base not in groups:
        return []
    rows, gaps, csv_rows = [], [], []
    for a in names:
        for g in games:
            s = _scores(groups[a], g)
            if not s:
                continue
            s_b, s_r = _scores(groups[base], g), _scores(groups.get(rapl, []), g)
            mean = float(np.mean(s))
            closed = gap_closed(mean, float(np.mean(s_r)), float(np.mean(s_b))) \
                if s_r and s_b and a not in (base, rapl) else math.nan
            rows.append((a, game_labels([g])[g], len(s), f"{num(mean)} ± {num(standard_error(s))}",
                         verdict(s, s_b) if a != base else "",
                         verdict(s, s_r) if a not in (base, rapl) and s_r else "",
                         pct(closed) if math.isfinite(closed) else "–"))
            csv_rows.append((family, a, g, len(s), mean, standard_error(s), closed))
    agg = aggregate(w, {a: groups[a] for a in names})
    goal_rows, reread = [], []
    for a in names[1:]:
        if a not in agg.matrices or base not in agg.matrices:
            continue
        poi = probability_of_improvement(agg.matrices[a], agg.matrices[base], reps=w.reps,
                                         seed=w.seed)
        at_or_above = sum(1 for g in games if _scores(groups[a], g) and _scores(groups[base], g)
                          and np.mean(_scores(groups[a], g)) >= np.mean(_scores(groups[base], g)))
        # The point estimate does not depend on the resamples: only the interval is read again.
        rest = at_or_above >= GOAL_GAMES and poi[0] >= GOAL_POI
        shown = interval(poi, percent=False)
        if rest and abs(poi[1] - 0.5) < GOAL_EDGE and w.reps < GOAL_REPS:
            poi = probability_of_improvement(agg.matrices[a], agg.matrices[base],
                                             reps=GOAL_REPS, seed=w.seed)
            shown = f"{interval(poi, percent=False, digits=3)} ({GOAL_REPS:,} resamples)"
            reread.append(a)
        met = rest and poi[1] > 0.5
        goal_rows.append((a, f"{at_or_above} of {len(games)}", shown,
                          "**yes**" if met else "no"))
        gaps.append(a)
    edge = ([f"{', '.join(reread)}: the interval's lower end lay within {GOAL_EDGE} of 0.5 at "
             f"{w.reps:,} resamples, where the percentile's Monte Carlo error can decide "
             f"\"above 0.5\"; the goal reads it at {GOAL_REPS:,} (rliable's default).", ""]
            if reread else [])
    w.csv(f"{FILE}_{family.lower()}", ("family", "arm", "env_id", "runs", "mean", "se",
                                        "gap_closed"), csv_rows)
    counted = counter_rows(groups, names, games)
    w.csv(f"{FILE}_{family.lower()}_counters", COUNTER_COLUMNS, [
        (family, *row) for row in counted])
    return [f"### The {family} family (`{'rapl_a2c' if family == 'A2C' else 'rapl_ppo'}.py`)",
            "",
            "Mean final score ± standard error over seeds; Welch's t-test over seeds against "
            f"{base} and against {rapl} (as published); the share of {rapl}'s gap to {base} "
            "the arm closes, (S_X − S_R)/(S_B − S_R) (– where RAPL is not below).", "",
            *table(("arm", "game", "runs", "score", f"vs {base}", f"vs {rapl}", "gap closed"),
                   rows),
            *aggregate_lines(w, agg),
            *table(("arm", "IQM [95 % CI]"),
                   [(a, interval(agg.iqm.get(a), agg.percent)) for a in agg.iqm]),
            "What the runs counted (mean over seeds; the interrupted share is of the routine "
            "calls, – without a stop rule or where a run predates the counter):", "",
            *table(("arm", "game", "runs", "updates", "decisions", "steps per decision",
                    "routine share", "interrupted"),
                   [(a, game_labels([g])[g], n, num(u, 0), num(d, 0), num(spd),
                     pct(share), pct(stopped) if math.isfinite(stopped) else "–")
                    for a, g, n, u, d, spd, share, stopped in counted]),
            f"The goal (issue 49): at or above {base} on ≥ {GOAL_GAMES} games and "
            f"P(X > {base}) ≥ {GOAL_POI} with its 95 % interval above 0.5:", "",
            *table(("arm", f"games ≥ {base}", f"P(X > {base}) [95 % CI]", "goal met"),
                   goal_rows),
            *edge]


def _leave_one_out_lines(w: Writer, family: str, groups: dict[str, list[RunRecord]],
                         games: list[str]) -> list[str]:
    """The leave-one-out arms of a family: per game against all of them and the baseline, and
    the share of all's gain each mechanism carries; their IQMs and P(X > baseline)."""
    base, rapl = FAMILIES[family]
    every = arm(rapl, ALL)
    names = [a for a in leave_one_out_arms(family) if a in groups]
    if not names or every not in groups:
        return []
    rows, csv_rows = [], []
    for a in names:
        for g in games:
            s = _scores(groups[a], g)
            if not s:
                continue
            s_all, s_b = _scores(groups[every], g), _scores(groups.get(base, []), g)
            s_r = _scores(groups.get(rapl, []), g)
            mean = float(np.mean(s))
            share = carried(float(np.mean(s_all)), mean, float(np.mean(s_r))) \
                if s_all and s_r else math.nan
            (_, _, _, _, _, spd, _, stopped), = counter_rows(groups, [a], [g])
            rows.append((a, game_labels([g])[g], len(s), f"{num(mean)} ± {num(standard_error(s))}",
                         verdict(s, s_all), verdict(s, s_b),
                         pct(share) if math.isfinite(share) else "–", num(spd),
                         pct(stopped) if math.isfinite(stopped) else "–"))
            csv_rows.append((family, a, g, len(s), mean, standard_error(s), share))
    w.csv(f"{FILE}_{family.lower()}_leave_one_out",
          ("family", "arm", "env_id", "runs", "mean", "se", "carried"), csv_rows)
    agg = aggregate(w, {a: groups[a] for a in (base, every, *names) if a in groups})
    poi_rows = []
    for a in names:
        if a not in agg.matrices:
            continue
        cells = [interval(agg.iqm.get(a), agg.percent)]
        for other in (base, every):
            cells.append(interval(probability_of_improvement(
                agg.matrices[a], agg.matrices[other], reps=w.reps, seed=w.seed), percent=False)
                if other in agg.matrices else "–")
        poi_rows.append((a, *cells))
    left_out = ", ".join(MECHANISMS)
    return [f"#### Leave one out: which mechanisms carry {every}",
            "",
            f"{rapl} with every mechanism but one ({left_out}), at {rapl}'s tuned settings, "
            "on the same seeds. Per game: mean ± standard error; Welch's t-test over seeds "
            f"against {every} and against {base}; the share of {every}'s gain over {rapl} "
            "that the mechanism left out carries, (S_all − S_without)/(S_all − S_R) (100 %: "
            "without it the gain is gone; below 0 %: better without it; – where all are not "
            "above RAPL). "
            "These arms were added after the results of all four, as a diagnosis: the goal "
            "does not judge them, and one above all four here would need fresh seeds to be "
            f"called better. Figure: `{LEAVE_ONE_OUT_FILE}.png` (what each mechanism "
            "carries, per game).", "",
            *table(("arm", "game", "runs", "score", f"vs {every}", f"vs {base}", "carried",
                    "steps per decision", "interrupted"), rows),
            *aggregate_lines(w, agg),
            *table(("arm", "IQM [95 % CI]", f"P(X > {base}) [95 % CI]",
                    f"P(X > {every}) [95 % CI]"), poi_rows)]


def relative_bar(s_x: Sequence[float], s_b: Sequence[float]) -> tuple[float, float]:
    """An arm's bar over its baseline, in %: 100 (S̄_X − S̄_B)/|S̄_B| and its error bar,
    100 √(se_X² + se_B²)/|S̄_B| (the standard error of the difference over the baseline's
    mean; an arm of one seed has se 0). NaN and NaN without scores or with S̄_B = 0.

    Example:
        >>> relative_bar([4.0, 6.0], [9.0, 11.0])  # se 1 each: −50 % ± 100·√2/10
        (-50.0, 14.142135623730951)
    """
    if not len(s_x) or not len(s_b) or abs(float(np.mean(s_b))) <= 1e-9:
        return math.nan, math.nan
    mean_b = float(np.mean(s_b))
    value = 100 * (float(np.mean(s_x)) - mean_b) / abs(mean_b)
    error = 100 * math.hypot(standard_error(s_x), standard_error(s_b)) / abs(mean_b)
    return value, error


#: The counters CSV's columns (`equal_frames_{family}_counters.csv`).
COUNTER_COLUMNS = ("family", "arm", "env_id", "runs", "updates", "decisions",
                   "steps_per_decision", "routine_share", "interrupted_share")


def counter_rows(groups: dict[str, list[RunRecord]], names: Sequence[str], games: Sequence[str]
                 ) -> list[tuple[str, str, int, float, float, float, float, float]]:
    """Per arm and game: (arm, game, runs, and the mean over its runs of updates, decisions,
    steps per decision, routine share (1 − primitive share) and interrupted share), each mean
    over the runs that have the counter (NaN where none has)."""
    rows = []
    for a in names:
        for g in games:
            rs = [r for r in groups.get(a, []) if r.env_id == g]
            if not rs:
                continue

            def mean(field: str, rs: list[RunRecord] = rs) -> float:
                values = [v for v in (run_counter(r, field) for r in rs) if math.isfinite(v)]
                return float(np.mean(values)) if values else math.nan

            rows.append((a, g, len(rs), mean("updates"), mean("decisions"),
                         mean("steps_per_decision"), 1.0 - mean("primitive_share"),
                         mean("interrupted_share")))
    return rows


def _draw_relative(w: Writer, groups: dict[str, list[RunRecord]], games: list[str]) -> None:
    """Per family a panel: each RAPL arm's (S_X − S_B)/|S_B| per game, in %, with ±1 s.e. of
    the difference (`relative_bar`), each arm in the same colour whatever arms have runs."""
    fig = figure(12.0, 8.0)
    axes = fig.subplots(2, 1)
    labels = game_labels(games)
    for ax, family in zip(axes, FAMILIES, strict=True):
        base = FAMILIES[family][0]
        every = arms(family)
        names = [a for a in every[1:] if a in groups]
        ax.set_title(f"{family} family: each arm over {base} at equal frames", fontsize=10)
        if not names or base not in groups:
            ax.text(0.5, 0.5, f"no finished runs of {base} and its RAPL arms", ha="center",
                    va="center", transform=ax.transAxes)
            ax.set_axis_off()
            continue
        width = 0.8 / len(names)
        x = np.arange(len(games))
        for i, a in enumerate(names):
            bars = [relative_bar(_scores(groups[a], g), _scores(groups[base], g)) for g in games]
            values, errors = np.array(bars, dtype=np.float64).T
            drawn = np.isfinite(values)  # a game without the arm's runs has no bar
            ax.bar((x + (i - (len(names) - 1) / 2) * width)[drawn], values[drawn], width,
                   yerr=errors[drawn], capsize=2, error_kw={"linewidth": 0.8},
                   color=PALETTE[every.index(a) % len(PALETTE)], label=a)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.set_xticks(x, [labels[g] for g in games])
        ax.set_ylabel(f"(S_X − S_{base}) / |S_{base}| (%)")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    w.png(fig, FILE)


def carried_bar(s_all: Sequence[float], s_without: Sequence[float], s_rapl: Sequence[float]
                ) -> tuple[float, float]:
    """A mechanism's bar, in %: 100 · `carried` of the means, and its error bar, the standard
    error of S̄_all − S̄_without over the gain, 100 √(se_all² + se_without²)/(S̄_all − S̄_R)
    (the gain's own noise left out). NaN and NaN without scores or without a gain.

    Example:
        >>> carried_bar([14.0, 16.0], [8.0, 10.0], [4.0, 6.0])  # (15 − 9)/(15 − 5), se 1 each
        (60.0, 14.142135623730951)
    """
    if not len(s_all) or not len(s_without) or not len(s_rapl):
        return math.nan, math.nan
    mean_all, mean_rapl = float(np.mean(s_all)), float(np.mean(s_rapl))
    share = carried(mean_all, float(np.mean(s_without)), mean_rapl)
    if not math.isfinite(share):
        return math.nan, math.nan
    error = math.hypot(standard_error(s_all), standard_error(s_without)) / (mean_all - mean_rapl)
    return 100 * share, 100 * error


def _draw_leave_one_out(w: Writer, groups: dict[str, list[RunRecord]], games: list[str]
                        ) -> None:
    """Per family with leave-one-out arms, a panel: per game, the share of all four's gain
    over RAPL that each mechanism carries (`carried_bar`), one bar per mechanism; no figure
    without those arms."""
    families = [f for f in LEAVE_ONE_OUT_FAMILIES
                if any(a in groups for a in leave_one_out_arms(f))
                and arm(FAMILIES[f][1], ALL) in groups and FAMILIES[f][1] in groups]
    if not families:
        return
    fig = figure(10.0, 4.0 * len(families) + 0.5)
    axes = fig.subplots(len(families), 1, squeeze=False)[:, 0]
    labels = game_labels(games)
    width = 0.8 / len(MECHANISMS)
    x = np.arange(len(games))
    for ax, family in zip(axes, families, strict=True):
        rapl = FAMILIES[family][1]
        every = arm(rapl, ALL)
        for i, mechanism in enumerate(MECHANISMS):
            a = arm(rapl, without(mechanism))
            if a not in groups:
                continue
            bars = [carried_bar(_scores(groups[every], g), _scores(groups[a], g),
                                _scores(groups[rapl], g)) for g in games]
            values, errors = np.array(bars, dtype=np.float64).T
            drawn = np.isfinite(values)  # a game without runs, or all not above RAPL
            ax.bar((x + (i - (len(MECHANISMS) - 1) / 2) * width)[drawn], values[drawn], width,
                   yerr=errors[drawn], capsize=2, error_kw={"linewidth": 0.8},
                   color=PALETTE[(2 + i) % len(PALETTE)], label=mechanism)
        ax.axhline(0.0, color="black", linewidth=0.8)
        ax.axhline(100.0, color="grey", linewidth=0.8, linestyle="--")
        ax.set_xticks(x, [labels[g] for g in games])
        ax.set_ylabel("share of all four's gain it carries (%)", fontsize=8)
        ax.set_title(f"Leave one out: the share of {every}'s gain over {rapl} each mechanism "
                     "carries\n(100 %: without it the gain is gone; 0 %: it adds nothing; "
                     "±1 s.e.; no bar where all four are not above RAPL)", fontsize=10)
        ax.legend(fontsize=8, title="the mechanism left out", title_fontsize=8,
                  loc="upper left", bbox_to_anchor=(1.01, 1.0))
    w.png(fig, LEAVE_ONE_OUT_FILE)


def _draw_curves(w: Writer, groups: dict[str, list[RunRecord]], games: list[str]) -> None:
    """The A2C family per game: mean training return over frames (top) and updates made
    against frames (bottom), one line per arm."""
    names = [a for a in arms("A2C") if a in groups]
    if not names or not games:
        return
    fig = figure(3.2 * len(games) + 1.0, 6.5)
    axes = np.atleast_2d(fig.subplots(2, len(games), squeeze=False))
    labels = game_labels(games)
    for col, g in enumerate(games):
        top, bottom = axes[0, col], axes[1, col]
        for a in names:
            i = arms("A2C").index(a)
            runs = [r for r in groups[a] if r.env_id == g]
            curves = [c for r in runs if (c := run_curve(r, r.steps)) is not None]
            if not curves:
                continue
            x = curves[0][0]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a bin no run has: NaN
                mean = np.nanmean([c[1] for c in curves], axis=0)
            top.plot(x, mean, label=a,
                     color=PALETTE[i % len(PALETTE)], linewidth=1.2)
            updates = mean_bins(runs, "updates")
            if updates is not None and len(updates) == len(x):
                bottom.plot(x, updates, color=PALETTE[i % len(PALETTE)], marker=".",
                            markersize=3, linewidth=0.8)
        top.set_title(labels[g], fontsize=10)
        bottom.set_xlabel("agent steps (frames)")
    axes[0, 0].set_ylabel("training return (mean over seeds)")
    axes[1, 0].set_ylabel("updates made")
    handles, names_drawn = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, names_drawn, loc="outside lower center", ncols=4, fontsize=8)
    w.png(fig, CURVES_FILE)


def section(w: Writer, runs: list[RunRecord]) -> list[str]:
    """Both families' tables, aggregates and goal; the two figures."""
    groups = group_runs(runs, label)
    games = sorted({r.env_id for rs in groups.values() for r in rs})
    _draw_relative(w, groups, games)
    _draw_curves(w, groups, games)
    _draw_leave_one_out(w, groups, games)
    lines = [f"Figures: `{FILE}.png` (each arm over its baseline per game, ±1 s.e. of the "
             "difference) and "
             f"`{CURVES_FILE}.png` (the A2C family's training curves and update clocks). "
             "Every arm at its method's tuned settings (RAPL's for the mechanisms); the "
             "mechanisms' flags: " + "; ".join(
                 f"{m}: `{' '.join(f'--{k} {v}' for k, v in flags)}`"
                 for m, flags in MECHANISMS.items()) + ".", ""]
    for family in FAMILIES:
        lines += _family_lines(w, family, groups, games)
        lines += _leave_one_out_lines(w, family, groups, games)
    return lines


EXPERIMENT = Experiment(
    name="equal-frames", version=1,
    title="Equal frames (beyond the paper): routine learners against A2C and PPO",
    figure="beyond the paper", file=FILE, add_runs=add_runs, section=section,
    methods=(*arms("A2C"), *leave_one_out_arms("A2C"), *arms("PPO"), *leave_one_out_arms("PPO")),
    colours={a: PALETTE[i % len(PALETTE)] for family in FAMILIES
             for i, a in enumerate((*arms(family), *leave_one_out_arms(family)))},
    extra_files=(CURVES_FILE, LEAVE_ONE_OUT_FILE,
                 *(f"{FILE}_{family.lower()}{part}" for family in FAMILIES
                                for part in ("", "_counters")),
                 *(f"{FILE}_{family.lower()}_leave_one_out" for family in LEAVE_ONE_OUT_FAMILIES)))
