"""Run an experiment's runs: skip the finished, resume the killed, locally or on Ray (SPEC §8).

Folder layout of `--out OUT`:

    OUT/{experiment}.json            the manifest: budget, version, every run with its labels
                                     and the settings left out (`left_out`, with why)
    OUT/runs/{key}/config.json       the run's script, flags, needed runs and agent steps
    OUT/runs/{key}/log.txt           the script's output (appended by every attempt)
    OUT/runs/{key}/result.json       written when the run finished: its eval.json(s) and
                                     its training curve binned for Fig. 3
    OUT/runs/{key}/{script's run}/   the script's own folder: TensorBoard log, checkpoint.pt,
                                     eval.json (and `demo.npz` beside it for an expert)

A run is finished when `result.json` exists; a run with a `checkpoint.pt` resumes from it
(`--resume`), so the same command continues a sweep after a crash, a kill or a lost session,
losing at most one checkpoint interval per run. A run that fails is reported with the last line
of its log and does not stop the others (the runs that need it are not started).

Backends: `local`, a pool of `--jobs` processes on this machine, and `ray`, one Ray task per run
asking for its CPUs (and a GPU with `--cuda`); `--address HOST:PORT` joins an existing cluster,
whose nodes must see OUT at the same path (a shared filesystem), and without it a local Ray
instance of `--jobs` CPUs is started and stopped.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import UsageError
from routine_gym.experiments.specs import (
    BUDGETS,
    EXPERIMENTS,
    Entry,
    RunSpec,
    build,
    left_out,
)

__all__ = ["SweepSummary", "execute_run", "run_experiment", "script_path"]

REPO = Path(__file__).resolve().parents[2]
_STEP_LINE = re.compile(rb"step\s+([\d,]+)/")


def script_path(script: str) -> Path:
    """`algos/{script}.py` of this checkout, or of the installed package."""
    for folder in (REPO / "algos", Path(__file__).resolve().parents[1] / "algos"):
        path = folder / f"{script}.py"
        if path.is_file():
            return path
    raise UsageError(f"cannot find the script {script}.py (looked in {REPO / 'algos'})")


def _now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _resolve(value: Any, runs: Path, key: str) -> list[str]:
    """A flag value as command-line words, with `@self/` and `@run:KEY/` made paths."""
    if isinstance(value, list | tuple):
        return [w for v in value for w in _resolve(v, runs, key)]
    if isinstance(value, bool):
        return ["True" if value else "False"]
    text = str(value)
    if text.startswith("@self/"):
        return [str(runs / key / text[len("@self/"):])]
    if text.startswith("@run:"):
        other, _, rest = text[len("@run:"):].partition("/")
        return [str(runs / other / rest)]
    return [text]


def command(config: dict[str, Any], runs: Path, cuda: bool = False,
            python: str | None = None) -> list[str]:
    """The command line of a run: resume from its newest checkpoint, or start it."""
    key = config["key"]
    folder = runs / key
    python = python or sys.executable
    script = str(script_path(config["script"]))
    checkpoints = sorted(folder.glob("*/checkpoint.pt"), key=lambda p: p.stat().st_mtime)
    if checkpoints:
        return [python, script, "--resume", str(checkpoints[-1].parent)]
    words = [python, script]
    for flag, value in config["flags"].items():
        words += [f"--{flag}", *_resolve(value, runs, key)]
    words += ["--run-dir", str(folder), "--torch-threads", "1"]
    if cuda:
        words.append("--cuda")
    return words


def _die_with_parent() -> None:
    """In the child: be killed when the process that started it dies (Linux), so a killed
    sweep leaves no orphan run writing into its folder."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    os.setpgrp()


_CHILDREN: set[subprocess.Popen] = set()
_CHILDREN_LOCK = threading.Lock()


def _tail(path: Path, size: int) -> bytes | None:
    """The last `size` bytes of a file, None when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            fh.seek(max(0, fh.seek(0, os.SEEK_END) - size))
            return fh.read()
    except OSError:
        return None


def _last_line(path: Path) -> str:
    tail = _tail(path, 4096)
    if tail is None:
        return "(no log)"
    lines = [ln.strip() for ln in tail.decode(errors="replace").splitlines() if ln.strip()]
    return lines[-1] if lines else "(no output)"


def _curve(run_dir: Path, total_steps: int) -> dict[str, Any] | None:
    """The run's training episodes binned as the report bins them (`report.curve_bins`), so a
    snapshot of `result.json`s draws Fig. 3 without the TensorBoard logs; None without a
    budget."""
    from routine_gym.experiments.report import CURVE_BINS, curve_bins, read_episodic_returns

    if total_steps <= 0:
        return None
    steps, returns = read_episodic_returns(run_dir)
    sums, counts = curve_bins(steps, returns, total_steps)
    return {"total_steps": total_steps, "bins": CURVE_BINS,
            "sums": [round(float(v), 6) for v in sums], "counts": counts.tolist()}


def execute_run(config: dict[str, Any], runs_dir: str, cuda: bool = False) -> dict[str, Any]:
    """Run (or resume) one run to the end and write its `result.json`; returns the result, or
    `{"key", "error"}` with the last line of its log. Used by both backends (a Ray task runs it
    on whichever node it lands)."""
    runs = Path(runs_dir)
    folder = runs / config["key"]
    log = folder / "log.txt"
    words = command(config, runs, cuda=cuda)
    start = time.time()
    with open(log, "ab") as out:
        out.write(f"# {_now()} {shlex.join(words)}\n".encode())
        out.flush()
        proc = subprocess.Popen(words, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, cwd=str(folder),
                                preexec_fn=_die_with_parent)
        with _CHILDREN_LOCK:
            _CHILDREN.add(proc)
        try:
            code = proc.wait()
        finally:
            with _CHILDREN_LOCK:
                _CHILDREN.discard(proc)
    evals = sorted(folder.glob("*/eval.json"), key=lambda p: p.stat().st_mtime)
    if code != 0 or not evals:
        why = f"exit code {code}" if code != 0 else "no eval.json"
        return {"key": config["key"], "error": f"{why}: {_last_line(log)}"}
    run_dir = evals[-1].parent
    extra = {p.stem[len("eval-"):]: json.loads(p.read_text()) for p in run_dir.glob("eval-*.json")}
    result = {"key": config["key"], "run_dir": run_dir.name,
              "eval": json.loads(evals[-1].read_text()), "evals": extra,
              "curve": _curve(run_dir, int(config.get("steps") or 0)),
              "seconds": time.time() - start, "finished": _now()}
    atomic_write_text(folder / "result.json", json.dumps(result, indent=2) + "\n")
    return result


def _kill_children() -> None:
    with _CHILDREN_LOCK:
        for proc in list(_CHILDREN):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)


# -- backends -----------------------------------------------------------------------------------

class _LocalBackend:
    """A pool of `jobs` threads, each waiting on one run's process."""

    def __init__(self, jobs: int) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(max_workers=jobs)

    def submit(self, config: dict, runs: Path, cuda: bool) -> Any:
        return self.pool.submit(execute_run, config, str(runs), cuda)

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, dict]]:
        from concurrent.futures import FIRST_COMPLETED, wait

        done, _ = wait(handles, timeout=timeout, return_when=FIRST_COMPLETED)
        return [(h, _outcome(h.result)) for h in done]

    def close(self) -> None:
        _kill_children()
        self.pool.shutdown(wait=True, cancel_futures=True)


class _RayBackend:
    """One Ray task per run, asking for `cpus` CPUs (and a GPU with `--cuda`)."""

    def __init__(self, jobs: int, address: str | None, cpus: int, cuda: bool) -> None:
        try:
            import ray
        except ImportError:
            raise UsageError("--backend ray needs Ray: pip install 'routine-gym[ray]'") from None
        self.ray = ray
        self.started = not ray.is_initialized()
        if self.started:
            os.environ.setdefault("RAY_AUTH_MODE", "disabled")
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                      "configure_logging": False}
            try:
                if address:
                    ray.init(address=address, **kwargs)
                else:
                    ray.init(num_cpus=jobs * cpus, num_gpus=1 if cuda else 0, **kwargs)
            except Exception as err:  # noqa: BLE001 - Ray raises many kinds; one line here
                where = f"the Ray cluster at {address}" if address else "a local Ray instance"
                raise UsageError(f"cannot start or join {where}: "
                                 f"{str(err).strip().splitlines()[0]}") from None
        if self.started and _HANDLING_SIGTERM and (
                threading.current_thread() is threading.main_thread()):
            signal.signal(signal.SIGTERM, _sigterm)  # Ray's own handler would just exit
        self.task = ray.remote(num_cpus=cpus, num_gpus=1 if cuda else 0,
                               max_retries=0)(execute_run)

    def submit(self, config: dict, runs: Path, cuda: bool) -> Any:
        return self.task.remote(config, str(runs), cuda)

    def wait(self, handles: Sequence[Any], timeout: float) -> list[tuple[Any, dict]]:
        done, _ = self.ray.wait(list(handles), num_returns=1, timeout=timeout)
        return [(h, _outcome(lambda h=h: self.ray.get(h))) for h in done]

    def close(self) -> None:
        if self.started:
            self.ray.shutdown()


def _outcome(get: Callable[[], dict]) -> dict:
    try:
        return get()
    except Exception as err:  # noqa: BLE001 - a run's crash is reported, not raised
        return {"error": f"{type(err).__name__}: {str(err).strip().splitlines()[-1:]}"}


# -- the sweep ----------------------------------------------------------------------------------

@dataclass
class SweepSummary:
    """How a sweep went: keys done before it started, finished now, failed (with why)."""

    skipped: list[str] = field(default_factory=list)
    finished: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.failed


def _write_manifest(out: Path, name: str, budget: str, entries: Sequence[Entry]) -> None:
    path = out / f"{name}.json"
    experiment = EXPERIMENTS[name]
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("budget") != budget or old.get("version") != experiment.version:
            raise UsageError(
                f"{out} already holds experiment {name} at budget {old.get('budget')} "
                f"(version {old.get('version')}); use another --out for budget {budget}")
        # Runs listed before (other --seeds/--envs) stay listed.
        keep = {json.dumps(r, sort_keys=True) for r in old.get("runs", [])}
    else:
        keep = set()
    rows = keep | {json.dumps(e.manifest(), sort_keys=True) for e in entries}
    manifest = {"experiment": name, "version": experiment.version, "budget": budget,
                "title": experiment.title, "figure": experiment.figure,
                "description": BUDGETS[budget].description, "updated": _now(),
                "left_out": left_out(name, budget),
                "runs": sorted((json.loads(r) for r in rows),
                               key=lambda r: (r["role"] != "expert", r["env_id"], r["method"],
                                              json.dumps(r["variant"]), r["seed"]))}
    atomic_write_text(path, json.dumps(manifest, indent=2) + "\n")


def _steps_done(runs: Path, key: str) -> int:
    """The last `step N/` a run printed (0 before its first progress line)."""
    found = _STEP_LINE.findall(_tail(runs / key / "log.txt", 8192) or b"")
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

    def show(self, done: set[str], running: set[str], failed: dict, force: bool = False) -> None:
        now = time.time()
        if not force and now - self.last < (2.0 if self.tty else 30.0):
            return
        self.last = now
        steps = self.steps(done, running)
        if self.start_steps is None:
            self.start_steps = steps
        rate = (steps - self.start_steps) / max(now - self.start, 1e-9)
        if steps >= self.total:
            eta = "0m00s"
        else:
            eta = _duration((self.total - steps) / rate) if rate > 0 else "–"
        line = (f"[{self.name}] runs {len(done)}/{len(self.specs)} done, {len(running)} running, "
                f"{len(failed)} failed · agent steps {steps:,}/{self.total:,} · "
                f"{_duration(now - self.start)} elapsed · ETA {eta}")
        if self.tty:
            self.stream.write("\r\033[K" + line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        self.stream.write(("\r\033[K" if self.tty else "") + text + "\n")
        self.stream.flush()


def run_experiment(name: str, budget: str, out: str | Path, *, jobs: int = 1,
                   backend: str = "local", address: str | None = None,
                   seeds: Sequence[int] | None = None, envs: Sequence[str] | None = None,
                   cuda: bool = False, cpus_per_run: int = 1, stream: Any = None,
                   poll: float = 1.0) -> SweepSummary:
    """Run experiment `name` at `budget` into `out` (see the module docstring).

    Raises:
        UsageError: an unknown experiment, budget, seed, env or backend; `out` holding the
            experiment at another budget; Ray missing or unreachable.
    """
    stream = stream if stream is not None else sys.stdout
    if backend not in ("local", "ray"):
        raise UsageError(f"--backend needs to be local or ray, actual value: {backend}")
    if jobs < 1:
        raise UsageError(f"--jobs needs to be ≥ 1, actual value: {jobs}")
    if address and backend != "ray":
        raise UsageError("--address joins a Ray cluster: it needs --backend ray")
    entries = build(name, budget, seeds, envs)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file, not a folder")
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    # The manifest lists the whole experiment, so a report of a sweep run seed by seed (or game
    # by game) counts the runs still to do as missing.
    _write_manifest(out, name, budget, build(name, budget) if seeds or envs else entries)
    specs = {e.run.key: e.run for e in entries}
    for key, spec in specs.items():
        (runs / key).mkdir(exist_ok=True)
        config_path = runs / key / "config.json"
        if not config_path.exists():
            atomic_write_text(config_path, json.dumps(spec.config(), indent=2) + "\n")

    summary = SweepSummary()
    done = {k for k in specs if (runs / k / "result.json").exists()}
    summary.skipped = sorted(done)
    todo = [k for k in specs if k not in done]
    progress = _Progress(name, specs, runs, stream)
    where = (f"local, {jobs} at a time" if backend == "local" else
             f"Ray cluster at {address}" if address else f"local Ray instance of {jobs} CPUs")
    progress.note(f"[{name}] budget {budget}: {len(specs)} runs, {len(done)} finished before, "
                  f"{len(todo)} to run ({where}) into {out}")
    if not todo:
        progress.show(done, set(), {}, force=True)
        return summary

    runner = (_LocalBackend(jobs) if backend == "local"
              else _RayBackend(jobs, address, cpus_per_run, cuda))
    handles: dict[Any, str] = {}
    failed: dict[str, str] = {}
    try:
        while todo or handles:
            for key in list(todo):
                spec = specs[key]
                broken = [n for n in spec.needs if n in failed]
                if broken:
                    todo.remove(key)
                    failed[key] = f"needs run {broken[0]}, which failed"
                    progress.note(f"[{name}] failed {key} ({spec.script}): {failed[key]}")
                    continue
                if backend == "local" and len(handles) >= jobs:
                    break
                if all(n in done for n in spec.needs):
                    todo.remove(key)
                    handles[runner.submit(spec.config(), runs, cuda)] = key
            if not handles:
                for key in todo:  # nothing can start them: their needs are not in the sweep
                    missing = next(n for n in specs[key].needs if n not in done)
                    failed[key] = f"needs run {missing}, which is not part of this sweep"
                break
            for handle, outcome in runner.wait(list(handles), poll):
                key = handles.pop(handle)
                if "error" in outcome:
                    failed[key] = outcome["error"]
                    progress.note(f"[{name}] failed {key} ({specs[key].script}): "
                                  f"{outcome['error']}")
                else:
                    done.add(key)
                    summary.finished.append(key)
            progress.show(done, set(handles.values()), failed)
    except KeyboardInterrupt:
        progress.note(f"[{name}] interrupted: the runs in flight keep their checkpoints; run "
                      "the same command to resume")
        raise
    finally:
        runner.close()
    progress.show(done, set(), failed, force=True)
    if progress.tty:
        stream.write("\n")
    summary.failed = failed
    return summary


def _sigterm(*_: Any) -> None:
    raise KeyboardInterrupt


_HANDLING_SIGTERM = False


def install_signal_handlers() -> None:
    """SIGTERM stops a sweep as Ctrl-C does: the runs' processes are stopped with it (and a
    local Ray instance is shut down)."""
    global _HANDLING_SIGTERM
    _HANDLING_SIGTERM = True
    signal.signal(signal.SIGTERM, _sigterm)
