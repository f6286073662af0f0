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

    OUT/.lock                        held (`flock`) by the sweep writing the folder; it
                                     names that sweep: pid, host, start, command

A run is finished when its `result.json` parses and has the shape the report reads
(`report.result_problem`); a corrupt one (truncated, empty, not JSON, the wrong shape) is moved
aside to `result.json.corrupt-{time}`, with a note on the progress stream, and the run runs
again. A run with a `checkpoint.pt` resumes from it (`--resume`), so the same command continues
a sweep after a crash, a kill or a lost session, losing at most one checkpoint interval per run.
A run that fails is reported with the last line of its log and does not stop the others (the
runs that need it are not started).

One sweep writes a folder at a time: it holds an exclusive `flock` on `OUT/.lock` from before
it writes anything to its end, and a second sweep on the folder is refused at once, naming the
holder. The kernel drops the lock when the holder's process dies, however it dies (a SIGKILL
too), so the file a killed sweep leaves behind never blocks the next one. `report` takes no
lock: it only reads, so it may run while a sweep runs (it shows the runs finished so far).

OUT is made absolute once, so every path on a run's command line is absolute: a run's process
works in its own folder, and a relative `--out` would otherwise name a folder inside it.

Backends: `local`, a pool of `--jobs` processes on this machine, and `ray`, one Ray task per run
asking for its CPUs (and a GPU with `--cuda`); `--address HOST:PORT` joins an existing cluster,
whose nodes must see OUT at the same path (a shared filesystem), and without it a local Ray
instance of `--jobs` CPUs is started and stopped.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import json
import os
import re
import shlex
import signal
import socket
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
from routine_gym.errors import UsageError, one_line
from routine_gym.experiments import read_json_object
from routine_gym.experiments.specs import (
    BUDGETS,
    EXPERIMENTS,
    Entry,
    RunSpec,
    build,
    games,
    left_out,
)

__all__ = ["SweepSummary", "check_options", "execute_run", "lock_holder", "plan",
           "run_experiment", "script_path", "sweep_folder", "sweep_lock"]

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
    # Absolute: the run's process works in its own folder (a Ray task on whichever node).
    runs = Path(os.path.abspath(runs_dir))
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
    from routine_gym.experiments.report import result_problem

    run_dir = evals[-1].parent
    try:
        extra = {p.stem[len("eval-"):]: read_json_object(p)
                 for p in sorted(run_dir.glob("eval-*.json"))}
        result = {"key": config["key"], "run_dir": run_dir.name,
                  "eval": read_json_object(evals[-1]), "evals": extra,
                  "curve": _curve(run_dir, int(config.get("steps") or 0)),
                  "seconds": time.time() - start, "finished": _now()}
    except UsageError as exc:
        return {"key": config["key"], "error": one_line(exc)}
    problem = result_problem(result, config["key"])
    if problem:  # never a result.json that the next sweep would call corrupt
        return {"key": config["key"], "error": f"its evaluation in {run_dir}: {problem}"}
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


def _manifest_row(row: Any) -> bool:
    """Whether a manifest's run entry has the fields (and types) the sweep sorts them by."""
    return (isinstance(row, dict)
            and all(isinstance(row.get(f), str) for f in ("key", "role", "env_id", "method"))
            and isinstance(row.get("seed"), int) and isinstance(row.get("variant"), dict))


def _write_manifest(out: Path, name: str, budget: str, entries: Sequence[Entry]) -> None:
    path = out / f"{name}.json"
    experiment = EXPERIMENTS[name]
    if path.exists():
        old = read_json_object(path, "delete it and run again: the sweep writes it anew")
        if old.get("budget") != budget or old.get("version") != experiment.version:
            raise UsageError(
                f"{out} already holds experiment {name} at budget {old.get('budget')} "
                f"(version {old.get('version')}); use another --out for budget {budget}")
        # Runs listed before (other --seeds/--envs) stay listed.
        rows = old.get("runs", [])
        if not isinstance(rows, list) or not all(_manifest_row(r) for r in rows):
            raise UsageError(f"{path}: `runs` is not a list of run entries (objects with a "
                             "key, role, env_id, method, variant and seed); delete it and run "
                             "again: the sweep writes it anew")
        keep = {json.dumps(r, sort_keys=True) for r in rows}
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


# -- the sweep folder and its lock ---------------------------------------------------------------

LOCK_FILE = ".lock"
#: Seconds the reachability check of `--address` waits for the Ray head.
CONNECT_TIMEOUT = 3.0


def _os_problem(exc: OSError) -> str:
    return exc.strerror or one_line(exc)


def sweep_folder(out: str | os.PathLike) -> Path:
    """`out` as an absolute path (symbolic links kept: Ray nodes see a shared folder under the
    same name), made with its `runs/` folder when missing.

    Raises:
        UsageError: one line: `out` is empty, a file, under a file, or cannot be made.
    """
    text = os.fspath(out)
    if not str(text).strip():
        raise UsageError("--out needs a folder, actual value: ''")
    path = Path(os.path.abspath(text))
    for place in (path / "runs", *(path / "runs").parents):
        if place.exists() or place.is_symlink():
            if not place.is_dir():
                what = "--out" if place == path else f"--out {text}:"
                raise UsageError(f"{what} {place} is a file, not a folder")
            break
    try:
        (path / "runs").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out {text}: cannot make the folder {exc.filename or path} "
                         f"({_os_problem(exc)})") from None
    return path


_HELD: dict[str, list[Any]] = {}  # real path of a sweep folder → [fd, depth]
_HELD_GUARD = threading.Lock()


def _describe_holder(info: dict[str, Any]) -> str:
    text = (f"pid {info.get('pid', '?')} on {info.get('host', '?')}, "
            f"started {info.get('started', '?')}")
    if info.get("command"):
        text += f": {info['command']}"
    return text


def _read_holder(fd: int) -> dict[str, Any]:
    try:
        info = json.loads(os.pread(fd, 65536, 0).decode("utf-8", errors="replace") or "{}")
    except (OSError, ValueError, RecursionError):
        return {}
    return info if isinstance(info, dict) else {}


@contextlib.contextmanager
def sweep_lock(out: str | os.PathLike, command: str | None = None) -> Any:
    """Own the sweep folder `out` (made when missing) while the block runs: an exclusive
    `flock` on `out/.lock`, which names the holder (pid, host, start, command). Re-entrant in
    one process (`experiment run all` holds it across its experiments). Yields `out` as an
    absolute path.

    Raises:
        UsageError: another process holds the folder (one line naming it), or `out` cannot be
            made or written (`sweep_folder`).
    """
    path = sweep_folder(out)
    real = os.path.realpath(path)
    with _HELD_GUARD:
        held = _HELD.get(real)
        if held is not None:
            held[1] += 1
    if held is not None:
        try:
            yield path
        finally:
            with _HELD_GUARD:
                held[1] -= 1
        return
    lock = path / LOCK_FILE
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError as exc:
        raise UsageError(f"--out {os.fspath(out)}: cannot write there: {lock}: "
                         f"{_os_problem(exc)}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            info = _read_holder(fd)
            holder = _describe_holder(info) if info else "its pid is not written yet"
            raise UsageError(f"{path} is in use by another sweep ({holder}); one sweep writes "
                             "a folder at a time: wait for it to end, or stop it") from None
        except OSError as exc:
            raise UsageError(f"{lock}: cannot lock it ({_os_problem(exc)}); the sweep folder "
                             "needs a filesystem with file locks") from None
        info = {"pid": os.getpid(), "host": socket.gethostname(), "started": _now(),
                "command": command or shlex.join(sys.argv)}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        with _HELD_GUARD:
            _HELD[real] = [fd, 1]
        try:
            yield path
        finally:
            with _HELD_GUARD:
                del _HELD[real]
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)  # released: the file names no holder
    finally:
        os.close(fd)  # drops the lock (the kernel drops it too if this process dies)


def lock_holder(out: str | os.PathLike) -> str | None:
    """Who holds the sweep folder `out` (`_describe_holder`), or None when no sweep appears to:
    read from `out/.lock` without locking it (a sweep killed without releasing it leaves its
    holder written there; its pid is checked on this host)."""
    lock = Path(out) / LOCK_FILE
    try:
        fd = os.open(lock, os.O_RDONLY | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        info = _read_holder(fd)
    finally:
        os.close(fd)
    if not info:
        return None
    pid = info.get("pid")
    if info.get("host") == socket.gethostname() and isinstance(pid, int):
        if pid == os.getpid():
            return _describe_holder(info)
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None  # a killed sweep's file
        except OSError:
            pass
    return _describe_holder(info)


# -- checks before a sweep touches anything --------------------------------------------------------

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
        raise UsageError(f"--address {address}: cannot connect ({_os_problem(exc)}); is the "
                         "Ray head running there (`ray start --head`)?") from None


def check_options(backend: str = "local", jobs: int = 1, cpus_per_run: int = 1,
                  address: str | None = None) -> None:
    """Refuse bad sweep options before anything is written (see `run_experiment`)."""
    if backend not in ("local", "ray"):
        raise UsageError(f"--backend needs to be local or ray, actual value: {backend}")
    if jobs < 1:
        raise UsageError(f"--jobs needs to be ≥ 1, actual value: {jobs}")
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


def plan(name: str, budget: str, seeds: Sequence[int] | None = None,
         envs: Sequence[str] | None = None) -> list[tuple[str, list[str] | None]]:
    """The experiments `experiment run NAME` runs, each with the `--envs` it has: NAME alone,
    or, for `all`, every experiment that has one of `envs` (all of them without `--envs`).

    Raises:
        UsageError: an unknown experiment or budget; a seed outside the budget; a game that
            is not one of the experiment's (for `all`: of any experiment's).
    """
    names = list(EXPERIMENTS) if name == "all" else [name]
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
                   poll: float = 1.0) -> SweepSummary:
    """Run experiment `name` at `budget` into `out` (see the module docstring), holding the
    folder's lock (`sweep_lock`) throughout.

    Raises:
        UsageError: an unknown experiment, budget, seed, env (one the experiment does not
            have) or backend; `--jobs` or `--cpus-per-run` below 1; a Ray address that does not
            answer; `out` holding the experiment at another budget, being a file, under a
            file, or not writable; another sweep holding `out`; a manifest or `config.json`
            of the wrong shape (naming the file); Ray missing.
    """
    stream = stream if stream is not None else sys.stdout
    check_options(backend, jobs, cpus_per_run, address)
    entries = build(name, budget, seeds, envs)
    with sweep_lock(out) as folder:
        try:
            return _sweep(name, budget, folder, entries, jobs=jobs, backend=backend,
                          address=address, whole=bool(seeds or envs), cuda=cuda,
                          cpus_per_run=cpus_per_run, stream=stream, poll=poll)
        except OSError as exc:  # a full disk, a folder made read-only meanwhile
            raise UsageError(f"cannot write the sweep folder {folder}: "
                             f"{exc.filename or ''}{': ' if exc.filename else ''}"
                             f"{_os_problem(exc)}") from None


def _finished(runs: Path, key: str, progress: _Progress, name: str) -> bool:
    """Whether run `key` finished: a `result.json` of the right shape. A corrupt one is moved
    aside (`result.json.corrupt-{time}`, named on the progress stream): the run runs again."""
    from routine_gym.experiments.report import result_problem

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
           stream: Any, poll: float) -> SweepSummary:
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
    done = {k for k in specs if _finished(runs, k, progress, name)}
    summary.skipped = sorted(done)
    todo = [k for k in specs if k not in done]
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
