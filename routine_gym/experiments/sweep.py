"""Run an experiment's runs: skip the finished, resume the killed, locally or on Ray (SPEC §8).

Folder layout of `--out OUT`:

    OUT/{experiment}.json            the manifest: budget, version, every run with its labels
                                     and the settings left out (`left_out`, with why)
    OUT/runs/{key}/config.json       the run's script, flags, needed runs and agent steps
    OUT/runs/{key}/log.txt           the script's output (appended by every attempt)
    OUT/runs/{key}/result.json       written when the run finished: its eval.json(s), its
                                     training curve binned for Fig. 3, what it counted and
                                     its provenance (wall time, machine: `provenance`)
    OUT/runs/{key}/attempts.json     each process of the run so far: start, seconds, machine
    OUT/runs/{key}/{script's run}/   the script's own folder: TensorBoard log, checkpoint.pt,
                                     eval.json (and `demo.npz` beside it for an expert)

    OUT/.lock                        held (`flock`) by the sweep writing the folder; it
                                     names that sweep: pid, host, start, command

A run is finished when its `result.json` parses and has the shape the report reads
(`results.result_problem`); a corrupt one (truncated, empty, not JSON, the wrong shape) is moved
aside to `result.json.corrupt-{time}`, with a note on the progress stream, and the run runs
again. A run with a `checkpoint.pt` resumes from it (`--resume`), so the same command continues
a sweep after a crash, a kill or a lost session, losing at most one checkpoint interval per run.
A run that fails is reported with the last line of its log and does not stop the others (the
runs that need it are not started). A run whose script reports a divergence (exit code 3,
`routine_gym.plumbing.divergence`) gets `OUT/runs/{key}/diverged.json` (its one line, when, its
provenance). A point of a tuning grid (a run of `tune`, or one a `tuned` rule reads) that
diverged is an answer, not a failure: it is not trained again, its point loses the choice
(`derived`) and the runs it decides start; any other divergence fails as any failure does.

One sweep writes a folder at a time: it holds the folder's lock throughout (`folder_lock`).

OUT is made absolute once, so every path on a run's command line is absolute: a run's process
works in its own folder, and a relative `--out` would otherwise name a folder inside it.

Backends (`backends`): `local`, a pool of `--jobs` processes on this machine, and `ray`, one Ray
task per run asking for its CPUs (and a GPU with `--cuda`); `--address HOST:PORT` joins an
existing cluster, whose nodes must see OUT at the same path (a shared filesystem), and without
it a local Ray instance of `--jobs` CPUs is started and stopped.

Tracking (`tracking={"project": P, "entity": E}`, the CLI's `--track`): every run's script also
logs to Weights & Biases (`backends.tracking_flags`); the flags are not a run's, so its key
is the same with or without them. W&B's files go to each run's folder (`OUT/runs/{key}/wandb/`,
the run's working folder) unless `WANDB_DIR` says otherwise.
"""

from __future__ import annotations

import json
import os
import re
import socket
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import UsageError, one_line
from routine_gym.experiments import os_problem, read_json_object, utc_now
from routine_gym.experiments.backends import LocalBackend, RayBackend, file_tail
from routine_gym.experiments.derived import grid_keys
from routine_gym.experiments.folder_lock import sweep_lock
from routine_gym.experiments.registry import EXPERIMENTS, available, build, games, left_out
from routine_gym.experiments.results import divergence, result_problem
from routine_gym.experiments.specs import BUDGETS, Entry, RunSpec
from routine_gym.plumbing.arguments import MAX_TORCH_THREADS, usable_cpus

__all__ = ["CONNECT_TIMEOUT", "SweepSummary", "check_options", "check_ray_address", "plan",
           "run_experiment"]

#: A run's progress line: `step N/TOTAL`, or `decision N/TOTAL` with a budget in decisions.
_STEP_LINE = re.compile(rb"(?:step|decision)\s+([\d,]+)/")


# -- the sweep ----------------------------------------------------------------------------------

@dataclass
class SweepSummary:
    """How a sweep went: keys done before it started, finished now, failed (with why), and the
    grid points that diverged (with their one line; before or now), which are answers."""

    skipped: list[str] = field(default_factory=list)
    finished: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    diverged: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failed


def _manifest_row(row: Any) -> bool:
    """Whether a manifest's run entry has the fields (and types) the sweep sorts them by."""
    return (isinstance(row, dict)
            and all(isinstance(row.get(f), str) for f in ("key", "role", "env_id", "method"))
            and isinstance(row.get("seed"), int) and isinstance(row.get("variant"), dict))


def _place(row: dict[str, Any]) -> str:
    """What a manifest's run stands for: its role, method, game, seed and variant."""
    return json.dumps([row["role"], row["method"], row["env_id"], row["seed"], row["variant"]],
                      sort_keys=True)


def _write_manifest(out: Path, name: str, budget: str, entries: Sequence[Entry]) -> None:
    path = out / f"{name}.json"
    experiment = EXPERIMENTS[name]
    if path.exists():
        old = read_json_object(path, "delete it and run again: the sweep writes it anew")
        if old.get("budget") != budget or old.get("version") != experiment.version:
            raise UsageError(
                f"{out} already holds experiment {name} at budget {old.get('budget')} "
                f"(version {old.get('version')}); use another --out for budget {budget}")
        # Runs listed before (other --seeds/--envs) stay listed, but for those whose place
        # (method, game, seed, variant) a run of other flags now takes: the experiment changed
        # that run's flags (RAPL-PPO's --prim-epochs), so the old run is no longer its run.
        rows = old.get("runs", [])
        if not isinstance(rows, list) or not all(_manifest_row(r) for r in rows):
            raise UsageError(f"{path}: `runs` is not a list of run entries (objects with a "
                             "key, role, env_id, method, variant and seed); delete it and run "
                             "again: the sweep writes it anew")
        taken = {_place(e.manifest()) for e in entries}
        keep = {json.dumps(r, sort_keys=True) for r in rows if _place(r) not in taken}
    else:
        keep = set()
    rows = keep | {json.dumps(e.manifest(), sort_keys=True) for e in entries}
    manifest = {"experiment": name, "version": experiment.version, "budget": budget,
                "title": experiment.title, "figure": experiment.figure,
                "description": BUDGETS[budget].description, "updated": utc_now(),
                "left_out": left_out(name, budget),
                "demos": demos_used(budget, {e.env_id for e in entries}),
                "runs": sorted((json.loads(r) for r in rows),
                               key=lambda r: (r["role"] != "expert", r["env_id"], r["method"],
                                              json.dumps(r["variant"]), r["seed"]))}
    atomic_write_text(path, json.dumps(manifest, indent=2) + "\n")


def demos_used(budget: str, env_ids: set[str]) -> dict[str, dict[str, Any]]:
    """The shipped demo each game of a sweep mines at `budget` (its demo set's file): the path
    under `demos/`, the demo set, its score and its SHA-256 (a game whose demo an expert of the
    sweep records has none here)."""
    import hashlib

    from routine_gym.demo import DEMOS_DIR, Demo, shipped_demo_path

    demo_set = BUDGETS[budget].demo_set
    used = {}
    for env_id in sorted(env_ids):
        path = shipped_demo_path(env_id, demo_set)
        if path is None:
            continue
        used[env_id] = {"file": os.path.relpath(path, DEMOS_DIR), "demo_set": demo_set,
                        "score": Demo.load(path).score,
                        "sha256": hashlib.sha256(Path(path).read_bytes()).hexdigest()}
    return used


def _steps_done(runs: Path, key: str) -> int:
    """The last `step N/` (or `decision N/`) a run printed (0 before its first progress
    line)."""
    found = _STEP_LINE.findall(file_tail(runs / key / "log.txt", 8192) or b"")
    return int(found[-1].replace(b",", b"")) if found else 0


def _duration(seconds: float) -> str:
    seconds = int(seconds)
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    return f"{seconds // 60}m{seconds % 60:02d}s"


class _Progress:
    """The live line: runs done / running / failed, agent steps, ETA."""

    def __init__(self, name: str, specs: dict[str, RunSpec], runs: Path, stream: Any) -> None:
        self.name, self.specs, self.runs, self.stream = name, specs, runs, stream
        self.total = sum(s.steps for s in specs.values())
        self.start = time.time()
        self.start_steps: int | None = None
        self.last = 0.0
        self.tty = getattr(stream, "isatty", lambda: False)()

    def steps(self, done: set[str], running: set[str]) -> int:
        return (sum(self.specs[k].steps for k in done)
                + sum(min(_steps_done(self.runs, k), self.specs[k].steps) for k in running))

    def show(self, done: set[str], running: set[str], failed: dict, force: bool = False,
             diverged: dict | None = None) -> None:
        now = time.time()
        if not force and now - self.last < (2.0 if self.tty else 30.0):
            return
        self.last = now
        steps = self.steps(done, running)
        # a grid point that diverged will not run its steps
        total = self.total - sum(self.specs[k].steps for k in diverged or ())
        if self.start_steps is None:
            self.start_steps = steps
        rate = (steps - self.start_steps) / max(now - self.start, 1e-9)
        if steps >= total:
            eta = "0m00s"
        else:
            eta = _duration((total - steps) / rate) if rate > 0 else "–"
        line = (f"[{self.name}] runs {len(done)}/{len(self.specs)} done, {len(running)} running, "
                f"{len(failed)} failed"
                + (f", {len(diverged)} diverged (grid points)" if diverged else "")
                + f" · agent steps {steps:,}/{total:,} · "
                f"{_duration(now - self.start)} elapsed · ETA {eta}")
        if self.tty:
            self.stream.write("\r\033[K" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        self.stream.write(("\r\033[K" if self.tty else "") + text + "\n")
        self.stream.flush()


# -- checks before a sweep touches anything --------------------------------------------------------

#: Seconds the reachability check of `--address` waits for the Ray head.
CONNECT_TIMEOUT = 3.0


def check_ray_address(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Refuse a `--address` that is not HOST:PORT or where nothing answers (a TCP connect to
    the head's GCS port, `timeout` seconds), before Ray would wait minutes for it. `auto`
    (Ray's own lookup) is left to Ray.

    Raises:
        UsageError: one line naming the address and what is wrong.
    """
    text = address.strip()
    if text == "auto":
        return
    host, sep, port = text.removeprefix("ray://").rpartition(":")
    host = host.strip("[]")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--address needs HOST:PORT (the Ray head's GCS port, 6379 unless "
                         f"it was started with another), actual value: {address}")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except socket.gaierror as exc:
        raise UsageError(f"--address {address}: unknown host {host} ({exc.strerror})") from None
    except TimeoutError:
        raise UsageError(f"--address {address}: no answer within {timeout:g} s; is the Ray "
                         "head running there and the port open?") from None
    except OSError as exc:
        raise UsageError(f"--address {address}: cannot connect ({os_problem(exc)}); is the "
                         "Ray head running there (`ray start --head`)?") from None


def check_options(backend: str = "local", jobs: int = 1, cpus_per_run: int = 1,
                  address: str | None = None, track: bool = False) -> None:
    """Refuse bad sweep options before anything is written (see `run_experiment`)."""
    if backend not in ("local", "ray"):
        raise UsageError(f"--backend needs to be local or ray, actual value: {backend}")
    if jobs < 1:
        raise UsageError(f"--jobs needs to be ≥ 1, actual value: {jobs}")
    if jobs > MAX_TORCH_THREADS:  # a process per job: 10^6 of them would exhaust the machine
        raise UsageError(f"--jobs needs to be ≤ {MAX_TORCH_THREADS:,} (4 × the {usable_cpus()} "
                         f"CPUs this process may use), actual value: {jobs:,}")
    if cpus_per_run < 1:
        raise UsageError(f"--cpus-per-run needs to be ≥ 1, actual value: {cpus_per_run}")
    if address is not None and backend != "ray":
        raise UsageError("--address joins a Ray cluster: it needs --backend ray")
    if backend == "ray":
        if address is not None:
            check_ray_address(address)
        import importlib.util

        if importlib.util.find_spec("ray") is None:
            raise UsageError("--backend ray needs Ray: pip install 'routine-gym[ray]'")
    if track:
        from routine_gym.plumbing.tracking import import_wandb

        import_wandb()


def plan(name: str, budget: str, seeds: Sequence[int] | None = None,
         envs: Sequence[str] | None = None) -> list[tuple[str, list[str] | None]]:
    """The experiments `experiment run NAME` runs, each with the `--envs` it has: NAME alone,
    or, for `all`, every experiment of the budget that has one of `envs` (all of them without
    `--envs`).

    Raises:
        UsageError: an unknown experiment or budget; an experiment the budget has no runs of; a
            seed outside the budget; a game that is not one of the experiment's (for `all`: of
            any experiment's).
    """
    names = [n for n in EXPERIMENTS if available(n, budget)] if name == "all" else [name]
    if name != "all" or not envs:
        chosen = [(n, list(envs) if envs else None) for n in names]
    else:
        for n in names:
            build(n, budget)  # an unknown budget first
        known = {n: games(n, budget) for n in names}
        every = sorted({g for gs in known.values() for g in gs})
        unknown = [e for e in envs if e not in every]
        if unknown:
            raise UsageError(f"--envs {unknown[0]} is not a game of any experiment at the "
                             f"{budget} budget (their games: {', '.join(every)})")
        chosen = [(n, [e for e in envs if e in known[n]]) for n in names]
        chosen = [(n, e) for n, e in chosen if e]
    for n, subset in chosen:
        build(n, budget, seeds, subset)  # the errors, before anything is written
    return chosen


def run_experiment(name: str, budget: str, out: str | Path, *, jobs: int = 1,
                   backend: str = "local", address: str | None = None,
                   seeds: Sequence[int] | None = None, envs: Sequence[str] | None = None,
                   cuda: bool = False, cpus_per_run: int = 1, stream: Any = None,
                   poll: float = 1.0, tracking: dict[str, Any] | None = None) -> SweepSummary:
    """Run experiment `name` at `budget` into `out` (see the module docstring), holding the
    folder's lock (`sweep_lock`) throughout. `tracking` (`{"project": P, "entity": E or
    None}`) has every run log to W&B too.

    Raises:
        UsageError: an unknown experiment, budget, seed, env (one the experiment does not
            have) or backend; `--jobs` or `--cpus-per-run` below 1; a Ray address that does not
            answer; `out` holding the experiment at another budget, being a file, under a
            file, or not writable; another sweep holding `out`; a manifest or `config.json`
            of the wrong shape (naming the file); Ray missing; wandb missing with `tracking`.
    """
    stream = stream if stream is not None else sys.stdout
    check_options(backend, jobs, cpus_per_run, address, track=tracking is not None)
    entries = build(name, budget, seeds, envs)
    with sweep_lock(out) as folder:
        try:
            return _sweep(name, budget, folder, entries, jobs=jobs, backend=backend,
                          address=address, whole=bool(seeds or envs), cuda=cuda,
                          cpus_per_run=cpus_per_run, stream=stream, poll=poll,
                          tracking=tracking)
        except OSError as exc:  # a full disk, a folder made read-only meanwhile
            raise UsageError(f"cannot write the sweep folder {folder}: "
                             f"{exc.filename or ''}{': ' if exc.filename else ''}"
                             f"{os_problem(exc)}") from None


def _finished(runs: Path, key: str, progress: _Progress, name: str) -> bool:
    """Whether run `key` finished: a `result.json` of the right shape. A corrupt one is moved
    aside (`result.json.corrupt-{time}`, named on the progress stream): the run runs again."""
    path = runs / key / "result.json"
    if not (path.exists() or path.is_symlink()):
        return False
    try:
        why = result_problem(read_json_object(path), key)
    except UsageError as exc:
        why = one_line(exc).removeprefix(f"{path}: ")
    if why is None:
        return True
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    aside = path.with_name(f"result.json.corrupt-{stamp}")
    n = 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"result.json.corrupt-{stamp}-{n}")
    os.replace(path, aside)
    progress.note(f"[{name}] {path} is corrupt ({why}): moved aside to {aside.name}; "
                  f"run {key} runs again")
    return False


def _sweep(name: str, budget: str, out: Path, entries: list[Entry], *, jobs: int,
           backend: str, address: str | None, whole: bool, cuda: bool, cpus_per_run: int,
           stream: Any, poll: float, tracking: dict[str, Any] | None = None) -> SweepSummary:
    runs = out / "runs"
    # The manifest lists the whole experiment, so a report of a sweep run seed by seed (or game
    # by game) counts the runs still to do as missing.
    _write_manifest(out, name, budget, build(name, budget) if whole else entries)
    specs = {e.run.key: e.run for e in entries}
    for key, spec in specs.items():
        folder = runs / key
        if folder.exists() and not folder.is_dir():
            raise UsageError(f"{folder}: a file, where run {key}'s folder goes; move it away")
        folder.mkdir(exist_ok=True)
        config_path = folder / "config.json"
        if config_path.exists() or config_path.is_symlink():
            hint = "delete it and run again: the sweep writes it anew"
            config = read_json_object(config_path, hint)
            if config.get("key") != key:
                raise UsageError(f"{config_path}: holds the config of run "
                                 f"{config.get('key')!r}, not of run {key}; {hint}")
        else:
            atomic_write_text(config_path, json.dumps(spec.config(), indent=2) + "\n")

    summary = SweepSummary()
    progress = _Progress(name, specs, runs, stream)
    # Grid points: a divergence is their answer (the point loses), not a fault. In a grid
    # experiment, its runs at a learning rate of the grid (not an expert it may need).
    grid = ({e.run.key for e in entries if "learning_rate" in e.variant}
            if EXPERIMENTS[name].grid else set())
    for spec in specs.values():
        grid.update(grid_keys(spec.derived))
    done = {k for k in specs if _finished(runs, k, progress, name)}
    diverged = {k: why for k in specs if k in grid and k not in done
                and (why := divergence(runs / k)) is not None}
    summary.skipped = sorted(done)
    summary.diverged = dict(diverged)
    todo = [k for k in specs if k not in done and k not in diverged]
    where = (f"local, {jobs} at a time" if backend == "local" else
             f"Ray cluster at {address}" if address else f"local Ray instance of {jobs} CPUs")
    before = f", {len(diverged)} grid point(s) diverged before" if diverged else ""
    progress.note(f"[{name}] budget {budget}: {len(specs)} runs, {len(done)} finished before"
                  f"{before}, {len(todo)} to run ({where}) into {out}")
    if not todo:
        progress.show(done, set(), {}, force=True, diverged=diverged)
        return summary

    runner = (LocalBackend(jobs) if backend == "local"
              else RayBackend(jobs, address, cpus_per_run, cuda))
    handles: dict[Any, str] = {}
    failed: dict[str, str] = {}
    try:
        while todo or handles:
            for key in list(todo):
                spec = specs[key]
                # a diverged need is an answer only to the `tuned` rule that reads it (its
                # keys looked up only then: this loop runs over every waiting run each poll)
                broken = [n for n in spec.needs if n in failed
                          or (n in diverged and n not in grid_keys(spec.derived))]
                if broken:
                    todo.remove(key)
                    failed[key] = (f"needs run {broken[0]}, which "
                                   + ("failed" if broken[0] in failed else "diverged"))
                    progress.note(f"[{name}] failed {key} ({spec.script}): {failed[key]}")
                    continue
                if backend == "local" and len(handles) >= jobs:
                    break
                if all(n in done or n in diverged for n in spec.needs):
                    todo.remove(key)
                    # The tracking rides beside the run's flags: its key stays the same.
                    config = {**spec.config(), **({"tracking": tracking} if tracking else {})}
                    handles[runner.submit(config, runs, cuda)] = key
            if not handles:
                for key in todo:  # nothing can start them: their needs are not in the sweep
                    missing = next(n for n in specs[key].needs
                                   if n not in done and n not in diverged)
                    failed[key] = f"needs run {missing}, which is not part of this sweep"
                break
            for handle, outcome in runner.wait(list(handles), poll):
                key = handles.pop(handle)
                if outcome.get("diverged") and key in grid:
                    line = outcome["error"].removeprefix("diverged: ")
                    diverged[key] = summary.diverged[key] = line
                    progress.note(f"[{name}] diverged {key} ({specs[key].script}), a grid "
                                  f"point: it loses the choice ({line})")
                elif "error" in outcome:
                    failed[key] = outcome["error"]
                    progress.note(f"[{name}] failed {key} ({specs[key].script}): "
                                  f"{outcome['error']}")
                else:
                    done.add(key)
                    summary.finished.append(key)
            progress.show(done, set(handles.values()), failed, diverged=diverged)
    except KeyboardInterrupt:
        progress.note(f"[{name}] interrupted: the runs in flight keep their checkpoints; run "
                      "the same command to resume")
        raise
    finally:
        runner.close()
    progress.show(done, set(), failed, force=True, diverged=diverged)
    if progress.tty:
        stream.write("\n")
    summary.failed = failed
    return summary
