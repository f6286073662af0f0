"""The report of a sweep (`routine-gym experiment report OUT`, SPEC §8): the paper's Table 1 and
Figures 2–6 from the runs `routine-gym experiment run` left in `OUT`.

`write_report(OUT)` reads the manifests `OUT/{experiment}.json` and each run's
`OUT/runs/{key}/result.json` (and, for the curves, its TensorBoard log) and writes into
`OUT/report/`:

- per experiment a figure and the CSV behind it: `table1_imitation`, `fig2_rl`, `fig3_curves`,
  `fig4_coinrun`, `fig5_scalability`, `fig6_ablation` (`.png` and `.csv`), each written by its
  experiment's `section` (`routine_gym/experiments/paper/`);
- `report.md`: the sweep's budget, the date of its latest finished run, which runs are
  missing, and a table per experiment with the paper's numbers where it gives them;
- `reference_scores.json`: the scores each game is normalised with (a cache: the random
  policy's score is played once);
- with `beside=OTHER` (`report OUT --beside OTHER`), the rl experiment at the two budgets of
  `OUT` and `OTHER` side by side (`budget_comparison`): `budgets_fig2`, `budgets_curves`,
  `budgets_routines` (`.png` and `.csv`) and its section of `report.md`.

A run's score is its final evaluation's mean return (`eval.mean_return` of `result.json`).
Scores are normalised per game (`reference.Reference`): human-normalised with the published
table where the env's profile has a key in it (Atari), else demo-normalised
`(score − random)/(demo − random)` with the shipped demo's best episode and the uniformly
random policy's mean score, else left raw (and out of the aggregates).
Aggregates over seeds and games come from rliable:
the IQM with a 95 % stratified-bootstrap interval and the probability of improvement, each over
a `(runs, games)` matrix (`statistics.score_matrix`).

Error bars: Table 1 alignment ± sample std over all runs, score IQM with its 95 % CI;
Fig. 2 the standard error over seeds of S_R divided by |S_A|; Fig. 3 ± sample std over seeds of
the binned curves; Fig. 4 ± sample std over seeds; Fig. 5 ± standard error over seeds of each
seed's relative performance averaged over games; Fig. 6 the IQM's 95 % CI.

The layers: `results` reads the sweep, `reference` normalises, `statistics` aggregates,
`training_curves` bins the curves, `drawing` draws, `writing` writes the files, `sections` holds
what the experiments' sections share. Importing this module is cheap: rliable, matplotlib,
TensorBoard and the envs load when a report is written.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import UsageError, one_line
from routine_gym.experiments import budget_comparison
from routine_gym.experiments.folder_lock import lock_holder
from routine_gym.experiments.reference import (
    REFERENCE_EPISODES,
    REFERENCE_SEED,
    Reference,
    reference_scores,
)
from routine_gym.experiments.registry import EXPERIMENTS
from routine_gym.experiments.results import RunRecord, load_runs
from routine_gym.experiments.specs import BUDGETS
from routine_gym.experiments.writing import Writer, num, table

__all__ = ["report_files", "write_report"]

#: Missing runs named in `report.md` before "and N more".
MAX_MISSING_LISTED = 12


def _status_lines(runs: list[RunRecord]) -> list[str]:
    unique = list({r.key: r for r in runs}.values())
    diverged = [r for r in unique if not r.finished and r.diverged is not None]
    missing = [r for r in unique if not r.finished and r.diverged is None]
    line = f"{len(unique) - len(missing) - len(diverged)} of {len(unique)} runs finished"
    if diverged:  # grid points' answers (docs/fair-protocol.md), not runs still to do
        line += f", {len(diverged)} diverged"
    if missing:
        listed = ", ".join(r.describe() for r in missing[:MAX_MISSING_LISTED])
        more = len(missing) - MAX_MISSING_LISTED
        line += f"; missing: {listed}" + (f" and {more} more" if more > 0 else "")
    return [line + ".", ""]


def _normalisation_lines(references: Mapping[str, Reference], demo_set: str = "first",
                         episodes: int = REFERENCE_EPISODES) -> list[str]:
    rows = []
    for env_id, ref in sorted(references.items()):
        kind = {"human": "human-normalised (published table)",
                "demo": "demo-normalised", "raw": "raw"}[ref.kind]
        rows.append((env_id, kind, num(ref.random) if ref.random is not None else "–",
                     num(ref.top) if ref.top is not None else "–", ref.note or ""))
    return ["## Normalisation", "",
            "Normalised score per game: `(score − random)/(reference − random)`. Atari games "
            "(a key in `routine_gym.metrics.HUMAN_RANDOM_SCORES`) are human-normalised "
            "(reference: the human score); other games are demo-normalised (reference: the "
            f"best episode of the shipped demo{_set_note(demo_set)}; random: the uniformly "
            f"random policy's mean over {episodes} episodes from seed {REFERENCE_SEED}); a game "
            "with "
            "neither keeps its raw score and is left out of the aggregates. Cached in "
            "`reference_scores.json`.", "",
            *table(("env", "normalisation", "random", "reference", "note"), rows)]


def _demo_lines(out: Path) -> list[str]:
    """The demos the sweep's runs mined, as its manifests recorded them (sweeps written before
    2026-12-06 recorded none: nothing)."""
    import json

    used: dict[str, dict] = {}
    for name in EXPERIMENTS:
        path = out / f"{name}.json"
        try:
            demos = json.loads(path.read_text()).get("demos") if path.exists() else None
        except (OSError, ValueError):
            demos = None
        if isinstance(demos, dict):
            used.update({k: v for k, v in demos.items() if isinstance(v, dict)})
    if not used:
        return []
    rows = [(env_id, f"`demos/{d.get('file')}`", d.get("demo_set", "–"),
             num(d["score"], 1) if isinstance(d.get("score"), int | float) else "–",
             str(d.get("sha256", ""))[:12]) for env_id, d in sorted(used.items())]
    return ["", "## Demos", "",
            "The shipped demo each game's routines were mined from (`routine_gym.demo."
            "DEMO_SETS`; `routine-gym show-demos` lists both sets):", "",
            *table(("env", "file", "demo set", "score", "SHA-256 (first 12)"), rows)]


def _set_note(demo_set: str) -> str:
    """Which demos a report's references are (nothing for the first protocol's, whose reports
    said nothing of it)."""
    if demo_set == "first":
        return ""
    return (f" of the `{demo_set}` demo set (`routine_gym.demo.DEMO_SETS`; MinAtar: the "
            "10M-step experts' demos of `demos/README.md`)")


def report_files() -> tuple[str, ...]:
    """Every file a report may write into `OUT/report/`; those this report did not write (an
    experiment whose data is gone) are removed, so the folder holds exactly this report."""
    stems = [stem for experiment in EXPERIMENTS.values() for stem in experiment.files]
    return (*(f"{stem}.{ext}" for stem in (*stems, *budget_comparison.FILES)
              for ext in ("png", "csv")),
            "report.md", "reference_scores.json")


def write_report(out: str | Path, *, reps: int = 2000, seed: int = 0,
                 beside: str | Path | None = None, folder: str | Path | None = None,
                 progress: Callable[[str], None] | None = None) -> list[Path]:
    """Aggregate the sweep in `out` and write `out/report/` (see the module docstring).

    The report only reads the sweep folder, so it may be written while a sweep runs there (it
    takes no lock): it shows the runs finished so far, and `report.md` says a sweep was
    running. The files of an earlier report that this one does not write (an experiment whose
    manifest is gone, a figure with no finished run now) are removed.

    Args:
        out: the folder `routine-gym experiment run --out` wrote.
        reps: bootstrap resamples of each confidence interval.
        seed: seed of the resampling (the same seed, the same intervals).
        beside: another sweep folder whose rl experiment ran at another budget: the report
            also compares the two budgets (`budget_comparison`).
        folder: where the report goes (`report --out`); default `out/report`.
        progress: called with one line before each step that takes time (reading the
            sweep, the reference scores, each experiment, the budgets side by side), so a
            report of a large sweep is not a minute of silence.

    Returns:
        The paths written: each experiment's PNG and CSV, `reference_scores.json`, and
        `report.md` (last).

    Raises:
        UsageError: one line naming the file: `out` does not exist, is a file or holds no
            manifest of the six experiments; a manifest, `result.json` or the random-policy
            cache that is not valid JSON or not of the sweep's shape; `out/report` that is a
            file or cannot be written; with `beside`: either folder without an rl experiment
            of A2C or RAPL-A2C runs, `beside` missing or not a sweep folder, both folders at
            the same steps.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: a file, not a sweep folder (the --out of `routine-gym "
                         "experiment run`)")
    if not out.is_dir():
        raise UsageError(f"{out}: no such sweep folder (write one with `routine-gym "
                         "experiment run --out`)")
    folder = out / "report" if folder is None else Path(folder)
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{folder}: a file, where the report's folder goes; move it away")
    sides = budget_comparison.load_sides(out, beside) if beside is not None else None
    try:
        written = _write_report(out, folder, reps, seed, sides, progress or (lambda line: None))
        for name in report_files():
            stale = folder / name
            if stale not in written and (stale.is_file() or stale.is_symlink()):
                stale.unlink()
    except OSError as exc:  # a read-only folder, a full disk
        raise UsageError(f"{folder}: cannot write the report there "
                         f"({exc.strerror or one_line(exc)})") from None
    return written


def _sweep_note(out: Path) -> list[str]:
    holder = lock_holder(out)
    if holder is None:
        return []
    return [f"Written while a sweep was running in this folder ({holder}): runs still in "
            "flight count as missing.", ""]


def _write_report(out: Path, folder: Path, reps: int, seed: int,
                  sides: tuple[budget_comparison.Side, budget_comparison.Side] | None,
                  progress: Callable[[str], None]) -> list[Path]:
    progress(f"reading the runs of {out}")
    results: dict[str, Mapping[str, Any] | None] = {}
    manifests = {name: load_runs(out, name, results) for name in EXPERIMENTS}
    if all(m is None for m in manifests.values()):
        raise UsageError(f"{out}: not a sweep folder: none of "
                         f"{', '.join(n + '.json' for n in EXPERIMENTS)} is there")
    envs = {r.env_id for name, experiment in EXPERIMENTS.items()
            if experiment.normalised and manifests[name]
            for r in manifests[name].runs if r.role == "main" and r.finished}
    progress(f"reference scores of {len(envs)} game(s) (the random policy's is played once "
             "per game, then cached in reference_scores.json)")
    budget_names = {m.budget for m in manifests.values() if m is not None}
    sizes = BUDGETS.get(min(budget_names)) if len(budget_names) == 1 else None
    demo_set = sizes.demo_set if sizes is not None else "first"
    episodes = sizes.reference_episodes if sizes is not None else REFERENCE_EPISODES
    references = reference_scores(envs, folder / "reference_scores.json", demo_set, episodes)
    w = Writer(folder, references, reps, seed)
    w.written.append(folder / "reference_scores.json")

    budgets = {name: m.budget for name, m in manifests.items() if m is not None}
    finished = [r["finished"] for r in results.values() if r and r.get("finished")]
    budget = (next(iter(budgets.values())) if len(set(budgets.values())) == 1
              else ", ".join(f"{n}: {b}" for n, b in budgets.items()))
    lines = [f"# routine-gym report: `{out}`", "",
             f"Budget: **{budget}**. Latest finished run: "
             f"{max(finished) if finished else 'none'}.", "",
             *_sweep_note(out),
             "Scores are each run's final evaluation (mean return over its evaluation "
             "episodes); aggregates are rliable's IQM with 95 % stratified-bootstrap CIs "
             f"({reps} resamples, seed {seed}) and its probability of improvement.", ""]
    for name, experiment in EXPERIMENTS.items():
        lines += [f"## {experiment.figure} — {experiment.title} (`{name}`)", ""]
        manifest = manifests[name]
        if manifest is None:
            lines += [f"not run (no `{name}.json` in the sweep folder).", ""]
            continue
        lines += _status_lines(manifest.runs)
        for gap in manifest.left_out:
            setting = ", ".join(f"{k} = {v}" for k, v in (gap.get("variant") or {}).items())
            lines += [f"Left out: {gap.get('env_id')}"
                      f"{f' at {setting}' if setting else ''}: {gap.get('why', '')}.", ""]
        main = [r for r in manifest.runs if r.role == "main"]
        if not any(r.finished for r in main):
            lines += ["No finished run: no figure.", ""]
            continue
        lines += [f"Figure: `{experiment.file}.png`, data: `{experiment.file}.csv`.", ""]
        progress(f"{experiment.figure} ({name}): {sum(r.finished for r in main)} finished "
                 "run(s), bootstrap CIs and figure")
        lines += experiment.section(w, main)
    if sides is not None:
        progress("the rl experiment at both budgets (--beside)")
        lines += budget_comparison.section(w, *sides, out)
    lines += _normalisation_lines(references, demo_set, episodes)
    lines += _demo_lines(out)
    atomic_write_text(folder / "report.md", "\n".join(lines).rstrip() + "\n")
    w.written.append(folder / "report.md")
    return w.written
