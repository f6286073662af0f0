"""How long does `routine-gym experiment report` take, with rliable's per-resample functions and
with the report's own (`statistics.iqm`, `statistics.improvement`), and are the two reports the
same?

A report's intervals are stratified bootstraps (rliable's `get_interval_estimates`, 2,000
resamples): each resample's IQM or P(X > Y) is one call. rliable's `aggregate_iqm` and
`probability_of_improvement` reach them through scipy's `trim_mean` and `mannwhitneyu`, whose
argument checking (and the p-value `mannwhitneyu` computes and rliable drops) costs far more
than the arithmetic. The report now computes both itself, with the same operations, so the
numbers are the same bit for bit. This benchmark writes the report of a sweep folder twice in
one process, first with rliable's functions put back, then as the report is, times each, and
compares every file the two wrote (the PNGs too). Usage:

    python bench/bench_report.py bench/results/experiments/fair --out bench/results/report_speed.md
"""

from __future__ import annotations

import argparse
import filecmp
import tempfile
import time
from pathlib import Path

from common import base_machine_info, children_die_with_me, fail, load_average


def timed_report(sweep: Path, folder: Path, reps: int) -> float:
    from routine_gym.experiments.report import write_report

    start = time.perf_counter()
    write_report(sweep, reps=reps, folder=folder)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweep", type=Path, help="a sweep folder (a committed snapshot)")
    parser.add_argument("--reps", type=int, default=2000, help="bootstrap resamples (2000)")
    parser.add_argument("--out", type=Path, default=None, help="the markdown report")
    args = parser.parse_args()
    if args.reps < 1:
        fail(f"--reps must be at least 1, not {args.reps}")
    if not args.sweep.is_dir():
        fail(f"{args.sweep}: no such sweep folder")

    import matplotlib.pyplot  # noqa: F401  (imported before either is timed)
    import scipy.stats  # noqa: F401
    from rliable import library  # noqa: F401
    from rliable import metrics as rmetrics

    from routine_gym.errors import UsageError
    from routine_gym.experiments import statistics

    ours = statistics.iqm, statistics.improvement
    load = load_average()
    with tempfile.TemporaryDirectory() as tmp:
        first, second = Path(tmp) / "rliable", Path(tmp) / "ours"
        try:
            statistics.iqm = lambda x: float(rmetrics.aggregate_iqm(x))
            statistics.improvement = lambda x, y: float(
                rmetrics.probability_of_improvement(x, y))
            try:
                slow = timed_report(args.sweep, first, args.reps)
            finally:
                statistics.iqm, statistics.improvement = ours
            fast = timed_report(args.sweep, second, args.reps)
        except UsageError as exc:
            fail(str(exc))
        names = sorted(p.name for p in first.iterdir())
        if names != sorted(p.name for p in second.iterdir()):
            fail("the two reports wrote different files")
        differ = [n for n in names if n != "report.md"
                  and not filecmp.cmp(first / n, second / n, shallow=False)]
        same_md = ((first / "report.md").read_text().replace(str(first), "REPORT")
                   == (second / "report.md").read_text().replace(str(second), "REPORT"))
    info = base_machine_info()
    text = "\n".join([
        "# The report's bootstraps: rliable's per-resample functions against the report's", "",
        f"`python bench/bench_report.py {args.sweep} --reps {args.reps}` ({info['date']}, "
        f"{info['cpu']}, load before: {load}). The whole `experiment report` of the sweep, "
        "written twice in one process: with rliable's `aggregate_iqm` and "
        "`probability_of_improvement` as each resample's statistic, then with "
        "`statistics.iqm` and `statistics.improvement` (what the report uses).", "",
        "| per-resample statistic | report written in | |",
        "|---|---:|---|",
        f"| rliable's (scipy `trim_mean`, `mannwhitneyu`) | {slow:.1f} s | |",
        f"| the report's own | {fast:.1f} s | {slow / fast:.1f}× faster |", "",
        f"Files compared: {len(names)}; differing: {', '.join(differ) or 'none'}; "
        f"report.md the same (the folder's name aside): {'yes' if same_md else 'NO'}.", ""])
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text)
    if differ or not same_md:
        raise SystemExit(1)


if __name__ == "__main__":
    children_die_with_me()
    main()
