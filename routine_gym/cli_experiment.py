"""The `routine-gym experiment` commands: `list` (the experiments and their sizes at each
budget), `run` (a sweep of an experiment's runs, local or on Ray) and `report` (the sweep's
figures, CSVs and `report.md`). The command line itself is `routine_gym.cli`'s."""

from __future__ import annotations

import argparse
import sys
import threading
import time

from routine_gym.errors import UsageError

__all__ = ["cmd_experiment_list", "cmd_experiment_report", "cmd_experiment_run"]


def cmd_experiment_list(args: argparse.Namespace) -> int:
    from routine_gym.experiments.registry import EXPERIMENTS, available, count_runs
    from routine_gym.experiments.specs import BUDGETS

    print(f"{'experiment':12s} {'figure':8s} " + "  ".join(f"{b:>22s}" for b in BUDGETS))
    for name, experiment in EXPERIMENTS.items():
        cells = []
        for budget in BUDGETS:
            if not available(name, budget):  # the budget holds other experiments only
                cells.append("–")
                continue
            runs, steps = count_runs(name, budget)
            cells.append(f"{runs:>5d} runs {_steps(steps):>11s}")
        print(f"{name:12s} {experiment.figure:8s} " + "  ".join(f"{c:>22s}" for c in cells))
        print(f"{'':12s} {experiment.title}")
    print()
    for budget in BUDGETS.values():
        print(f"{budget.name:6s} {budget.description}")
    return 0


def _steps(steps: int) -> str:
    for unit, size in (("G", 10**9), ("M", 10**6), ("k", 10**3)):
        if steps >= size:
            return f"{steps / size:.1f}{unit} steps"
    return f"{steps} steps"


def cmd_experiment_run(args: argparse.Namespace) -> int:
    import shlex

    from routine_gym.experiments.backends import install_signal_handlers
    from routine_gym.experiments.folder_lock import sweep_lock
    from routine_gym.experiments.registry import EXPERIMENTS, available
    from routine_gym.experiments.sweep import check_options, plan, run_experiment

    # Every option is checked before the folder is touched; then the folder is held (one sweep
    # at a time) across all the experiments of `all`.
    tracking = None
    if args.track:
        tracking = {"project": args.wandb_project_name or "routine-gym",
                    "entity": args.wandb_entity}
    elif args.wandb_project_name is not None or args.wandb_entity is not None:
        flag = "--wandb-project-name" if args.wandb_project_name is not None else "--wandb-entity"
        raise UsageError(f"{flag} names where --track logs: it needs --track")
    check_options(args.backend, args.jobs, args.cpus_per_run, args.address,
                  track=args.track)
    if tracking is not None:  # before any run: a bad project would fail every one of them
        from routine_gym.plumbing.tracking import check_tracking

        check_tracking(tracking["project"], tracking["entity"])
    chosen = plan(args.name, args.budget, args.seeds, args.envs)
    install_signal_handlers()
    failed = 0
    with sweep_lock(args.out, command=shlex.join(["routine-gym", *sys.argv[1:]])):
        for name in EXPERIMENTS:
            if args.name == "all" and not available(name, args.budget):
                print(f"[{name}] skipped: no runs at the {args.budget} budget")
            elif args.name == "all" and name not in dict(chosen):
                print(f"[{name}] skipped: none of --envs is one of its games")
        for name, envs in chosen:
            summary = run_experiment(name, args.budget, args.out, jobs=args.jobs,
                                     backend=args.backend, address=args.address,
                                     seeds=args.seeds, envs=envs, cuda=args.cuda,
                                     cpus_per_run=args.cpus_per_run, tracking=tracking)
            for key, why in summary.diverged.items():
                print(f"[{name}] run {key}, a grid point, diverged ({why}): it is not trained "
                      "again, and its point loses the choice")
            for key, why in summary.failed.items():
                print(f"[{name}] run {key} failed: {why} (log: {args.out}/runs/{key}/log.txt)")
            failed += len(summary.failed)
    if failed:
        print(f"{failed} run(s) failed; the others finished. Run the same command to retry them.")
        return 1
    return 0


def cmd_experiment_report(args: argparse.Namespace) -> int:
    from routine_gym.atomic import check_folder
    from routine_gym.experiments.report import write_report

    if args.report_dir is not None:
        check_folder(args.report_dir, "--out")  # minari:ID, xyz:, '', a file: before reading

    start = time.monotonic()
    pending: list[threading.Timer] = []

    def say(line: str, at: float | None = None) -> None:
        # stderr: stdout stays the list of files written, for a script to read.
        at = time.monotonic() - start if at is None else at
        print(f"report [{at:5.1f} s] {line}", file=sys.stderr, flush=True)

    def progress(line: str) -> None:
        # A step's line shows once the step has taken a second: a quick report, or one stopped
        # by a mistake (a bad file is found while reading), prints only its one-line error.
        for timer in pending:
            timer.cancel()
        pending[:] = [threading.Timer(1.0, say, (line, time.monotonic() - start))]
        pending[0].daemon = True
        pending[0].start()

    try:
        written = write_report(args.out, beside=args.beside, folder=args.report_dir,
                               progress=progress)
    finally:
        for timer in pending:
            timer.cancel()
    for path in written:
        print(path)
    say(f"{len(written)} file(s) written in {written[-1].parent}")
    return 0
