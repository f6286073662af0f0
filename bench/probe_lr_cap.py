"""Probe: is the fair tuning grid's top learning rate a cap?

    python bench/probe_lr_cap.py bench/results/experiments/fair --out /tmp/lr-cap --jobs 2 \\
        --report bench/results/lr_cap_probe.md

The fair protocol's grid (`specs.TUNE_GRIDS`) is each family's default learning rate times a
few factors, annealed and constant. If a rate above its top were better, the tuned methods
would sit below their best, and the comparison with RAPL would rest on a cap that may favour
either arm. This probe trains each method of `METHODS` once more per tune run at the top point
of its schedule (the highest constant rate, the highest annealed one), with the learning rate
doubled again and every other flag of that tune run (its schedule, tuning seed, budget, demo,
evaluation), and tabulates, per method and game, the mean final score over the tuning seeds of
the grid's best point, its top points and the two probes: where a probe's is the highest, the
grid capped that method there. Both schedules, because the methods differ in which they
choose at the top (at `fair`, A2C mostly annealed, the RAPL arms constant): a probe of one
schedule alone would find one side's cap and miss the other's. With the grid's first form (½,
1, 2 times the default; its top chosen in 27 of 30 cells at `fair`) the probe ran at 4 times
(`bench/results/lr_cap_probe.md`), which then joined the grid; run again, at 8 times
(`bench/results/lr_cap_probe_8x.md`), which joined it too. Those two probes doubled the
constant top only; at 16 times, both schedules, it won 4 of 20 cells
(`bench/results/lr_cap_probe_16x.md`), and the grid stopped growing (docs/fair-protocol.md).

Runs go into `OUT/runs/KEY-x2/` (KEY the tune run's key), each as a sweep runs it
(`backends.execute_run`: its log, checkpoints, `result.json`); run it again to resume (finished
runs are read, killed ones resume from their checkpoints). A run that diverges (its loss or
weights stop being numbers, `routine_gym.plumbing.divergence`) is an answer here, not a fault:
its probe point shows "diverged" and beats nothing. The probe is not part of the
protocol: no sweep reads its runs.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from common import base_machine_info, children_die_with_me, fail

REPO = Path(__file__).resolve().parent.parent
#: The methods probed: both families' baseline and RAPL as published.
METHODS = ("A2C", "RAPL-A2C", "PPO", "RAPL-PPO")
#: How much the probe raises the grid's top learning rate.
FACTOR = 2.0


def read_json(path: Path) -> dict:
    """The JSON object in `path`; a one-line error naming the file if it is not one."""
    from routine_gym.experiments import UsageError, read_json_object

    try:
        return read_json_object(path)
    except UsageError as exc:
        fail(str(exc))
        raise  # unreachable: fail exits


def tune_runs(sweep: Path) -> list[dict]:
    """The tune experiment's runs of `METHODS` in `sweep` that finished (a `result.json`),
    each with its `config` and `score` (mean final evaluation return)."""
    manifest = sweep / "tune.json"
    if not manifest.is_file():
        fail(f"{sweep} has no tune.json: give a sweep folder of the tune experiment")
    found = []
    for run in read_json(manifest)["runs"]:
        result = sweep / "runs" / run["key"] / "result.json"
        if run["method"] in METHODS and result.is_file():
            config = read_json(sweep / "runs" / run["key"] / "config.json")
            found.append({**run, "config": config,
                          "score": float(read_json(result)["eval"]["mean_return"])})
    if not found:
        fail(f"{sweep} has no finished tune run of {', '.join(METHODS)}")
    return found


def top_points(runs: list[dict]) -> dict[tuple[str, bool], float]:
    """Each method's highest learning rate among its tune runs of each schedule, keyed
    `(method, anneal)`: the grid's top, constant and annealed."""
    top: dict[tuple[str, bool], float] = {}
    for run in runs:
        cell = (run["method"], bool(run["variant"]["anneal_lr"]))
        top[cell] = max(top.get(cell, 0.0), float(run["variant"]["learning_rate"]))
    return top


def probe_configs(runs: list[dict]) -> list[dict]:
    """A config per tune run at its method's top point of its schedule: the same flags (the
    schedule too), the learning rate times `FACTOR`, under the key `KEY-x2`."""
    top = top_points(runs)
    configs = []
    for run in runs:
        anneal = bool(run["variant"]["anneal_lr"])
        lr = top[(run["method"], anneal)]
        if float(run["variant"]["learning_rate"]) == lr:
            config = json.loads(json.dumps(run["config"]))
            config["flags"]["learning-rate"] = FACTOR * lr
            config["key"] = f"{run['key']}-x{FACTOR:g}"
            config.pop("derived", None)
            configs.append({"config": config, "method": run["method"], "env_id": run["env_id"],
                            "seed": run["config"]["flags"]["seed"], "anneal": anneal})
    # The A2C family first, each method's constant probes before its annealed ones.
    return sorted(configs, key=lambda c: (METHODS.index(c["method"]), c["anneal"]))


def _diverged(folder: Path) -> bool:
    """Whether the probe run in `folder` diverged before (its `diverged.json`)."""
    from routine_gym.errors import UsageError
    from routine_gym.experiments.results import divergence

    try:
        return divergence(folder) is not None
    except UsageError as exc:  # a damaged record: one line, as for any bad file
        fail(str(exc))


def run_probes(probes: list[dict], runs_dir: Path, jobs: int) -> dict[str, float]:
    """Run (or resume) every probe not finished; `{key: score}` of all of them, NaN for a run
    that diverged (`execute_run` notes it in the run's `diverged.json`, so a second call does
    not train it again; `diverged.txt` is an older probe's note). Any other failure stops the
    probe with a one-line error."""
    from routine_gym.experiments.backends import execute_run

    scores, todo = {}, []
    for probe in probes:
        folder = runs_dir / probe["config"]["key"]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "config.json").write_text(json.dumps(probe["config"], indent=2) + "\n")
        if (folder / "result.json").is_file():
            scores[probe["config"]["key"]] = float(
                read_json(folder / "result.json")["eval"]["mean_return"])
        elif (folder / "diverged.txt").is_file() or _diverged(folder):
            scores[probe["config"]["key"]] = math.nan
        else:
            todo.append(probe)
    print(f"[probe] {len(probes)} runs, {len(probes) - len(todo)} finished before, "
          f"{len(todo)} to run, {jobs} at a time, into {runs_dir}", flush=True)
    start = time.time()
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(execute_run, p["config"], str(runs_dir)): p for p in todo}
        for done, future in enumerate(as_completed(futures), start=1):
            probe, result = futures[future], future.result()
            key = probe["config"]["key"]
            if result.get("diverged"):
                scores[key] = math.nan
            elif "error" in result:
                fail(f"run {key} ({probe['method']} on {probe['env_id']}) "
                     f"failed: {result['error']}")
            else:
                scores[key] = float(result["eval"]["mean_return"])
            print(f"[probe] {done}/{len(todo)} {probe['method']} {probe['env_id']} seed "
                  f"{probe['seed']}: "
                  + ("diverged" if math.isnan(scores[key]) else f"{scores[key]:.2f}")
                  + f" ({(time.time() - start) / 60:.0f} min)", flush=True)
    return scores


def game(env_id: str) -> str:
    """`MinAtar/Freeway-v1` as `Freeway`."""
    return env_id.split("/")[-1].rsplit("-v", 1)[0]


def point_name(lr: float, anneal: bool) -> str:
    """A grid point as the report shows it: `0.0014 constant`."""
    return f"{lr:g} {'annealed' if anneal else 'constant'}"


def table(runs: list[dict], probes: list[dict], scores: dict[str, float]) -> tuple[list[str], int]:
    """The report's rows, per method and game: the grid's best point and its mean final score
    over the tuning seeds, the top point's of each schedule, the probe's of each (their rate
    doubled), and whether a probe's is the highest of all; and in how many cells one is."""
    cells: dict[tuple[str, str], dict[str, list[float]]] = {}
    for run in runs:
        name = point_name(float(run["variant"]["learning_rate"]), run["variant"]["anneal_lr"])
        cells.setdefault((run["method"], run["env_id"]), {}).setdefault(name, []).append(
            run["score"])
    probed: dict[tuple[str, str, bool], list[float]] = {}
    for probe in probes:
        probed.setdefault((probe["method"], probe["env_id"], probe["anneal"]), []).append(
            scores[probe["config"]["key"]])
    top = top_points(runs)
    rows, wins = [], 0
    for (method, env_id), cell in sorted(cells.items()):
        means = {name: statistics.fmean(v) for name, v in cell.items()}
        best = max(means, key=means.get)
        row = f"| {method} | {game(env_id)} | {means[best]:.2f} ({best}) |"
        for anneal in (False, True):
            name = point_name(top[(method, anneal)], anneal) if (method, anneal) in top else None
            row += f" {means[name]:.2f} |" if name in means else " – |"
        won = False
        for anneal in (False, True):
            probe = probed.get((method, env_id, anneal))
            doubled = point_name(FACTOR * top.get((method, anneal), 0.0), anneal)
            if not probe:
                row += " – |"
            elif any(math.isnan(score) for score in probe):  # a diverged run: no rival
                row += f" diverged ({doubled}) |"
            else:
                won |= statistics.fmean(probe) > means[best]
                row += f" {statistics.fmean(probe):.2f} ({doubled}) |"
        wins += won
        rows.append(row + f" {'**yes**' if won else 'no'} |")
    header = ["| method | game | the grid's best (its point) | the top constant point | "
              "the top annealed point | the probe, constant | the probe, annealed | "
              "a probe beats the grid |", "|---|---|---:|---:|---:|---:|---:|---|"]
    return header + rows, wins


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sweep", type=Path, help="a sweep folder with the tune experiment")
    parser.add_argument("--out", type=Path, required=True, help="where the probe's runs go")
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time (2)")
    parser.add_argument("--report", type=Path, default=None,
                        help="the markdown report (default: OUT/lr_cap_probe.md)")
    args = parser.parse_args()
    if args.jobs < 1:
        fail(f"--jobs must be at least 1, not {args.jobs}")
    runs = tune_runs(args.sweep)
    probes = probe_configs(runs)
    scores = run_probes(probes, args.out / "runs", args.jobs)
    rows, wins = table(runs, probes, scores)
    info = base_machine_info()
    seeds = sorted({p["seed"] for p in probes})
    text = "\n".join([
        "# Is the fair tuning grid's top learning rate a cap?", "",
        f"`python bench/probe_lr_cap.py {args.sweep} --out OUT --jobs {args.jobs}` "
        f"({info['date']}, {info['cpu']}). Each method's tune runs at the grid's top point of "
        f"each schedule (constant, annealed), run again with the learning rate times {FACTOR:g} "
        f"and every other flag the same (tuning seeds {', '.join(map(str, seeds))}, the sweep's "
        "budget and demos). Mean final score over the tuning seeds: the grid's best point (the "
        "tune experiment's choice), its top points (the ones the probes double) and the "
        "probes.", "",
        *rows, "",
        f"A probe beats every grid point in {wins} of {len(rows) - 2} method-game cells.", ""])
    report = args.report or args.out / "lr_cap_probe.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    report.write_text(text)
    print(text)


if __name__ == "__main__":
    children_die_with_me()
    main()
