"""Running one run, and the backends that run a sweep's runs (SPEC §8).

`execute_run` runs (or resumes) one run's script to its end in its folder and writes its
`result.json` (with its `provenance`: the wall time of all its attempts and their machines);
both backends call it. `local` is a pool of `--jobs` threads each waiting on one
run's process on this machine; `ray` is one Ray task per run asking for its CPUs (and a GPU with
`--cuda`), in a cluster it joins (`--address`) or a local instance it starts and stops. A run's
process dies with the sweep that started it, and SIGTERM stops a sweep as Ctrl-C does
(`install_signal_handlers`).

`experiment run --track` gives every run's script `--track --wandb-project-name P
[--wandb-entity E]` (`tracking_flags`): the run's config as the sweep submits it carries them
under `tracking`, beside its flags and never among them, so a run's key, its `config.json` and
its result are the same with or without tracking, and a sweep may be resumed either way.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from routine_gym.atomic import atomic_write_text
from routine_gym.errors import DIVERGED_EXIT, UsageError, one_line
from routine_gym.experiments import read_json_object, utc_now
from routine_gym.experiments.provenance import NOTE_EVERY, Attempts
from routine_gym.experiments.results import DIVERGED_FILE, result_problem
from routine_gym.experiments.run_counters import counter_record
from routine_gym.experiments.training_curves import (
    CURVE_BINS,
    RETURN_TAG,
    curve_bins,
    read_scalars,
)

__all__ = ["LocalBackend", "RayBackend", "command", "curve_and_counters", "execute_run",
           "install_signal_handlers", "file_tail", "script_path", "tracking_flags"]

REPO = Path(__file__).resolve().parents[2]

def script_path(script: str) -> Path:
    """`algos/{script}.py` of this checkout, or of the installed package."""
    for folder in (REPO / "algos", Path(__file__).resolve().parents[1] / "algos"):
        path = folder / f"{script}.py"
        if path.is_file():
            return path
    raise UsageError(f"cannot find the script {script}.py (looked in {REPO / 'algos'})")


def _resolve(value: Any, runs: Path, key: str) -> list[str]:
    """A flag value as command-line words, with `@self/`, `@run:KEY/` and `@demos/` made
    paths."""
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
    if text.startswith("@demos/"):  # a shipped demo (`RunSpec.pinned`)
        from routine_gym.demo import DEMOS_DIR

        return [str(Path(DEMOS_DIR) / text[len("@demos/"):])]
    return [text]


def tracking_flags(tracking: dict[str, Any] | None, resume: bool = False) -> list[str]:
    """A script's W&B flags for the sweep's tracking (`{"project": P, "entity": E or None}`):
    none for an untracked new run; `--no-track` for an untracked resume, whose checkpoint may
    have been made by a tracked sweep (the sweep's command line decides, not the checkpoint)."""
    if tracking is None:
        return ["--no-track"] if resume else []
    words = ["--track", "--wandb-project-name", str(tracking["project"])]
    if tracking.get("entity") is not None:
        words += ["--wandb-entity", str(tracking["entity"])]
    return words


def command(config: dict[str, Any], runs: Path, cuda: bool = False,
            python: str | None = None) -> list[str]:
    """The command line of a run: resume from its newest checkpoint, or start it; with the
    sweep's W&B flags when `config` has `tracking` (`tracking_flags`)."""
    key = config["key"]
    folder = runs / key
    python = python or sys.executable
    script = str(script_path(config["script"]))
    tracking = config.get("tracking")
    checkpoints = sorted(folder.glob("*/checkpoint.pt"), key=lambda p: p.stat().st_mtime)
    if checkpoints:
        return [python, script, "--resume", str(checkpoints[-1].parent),
                *tracking_flags(tracking, resume=True)]
    words = [python, script]
    flags = {**config["flags"], **config.get("pinned", {})}
    if config.get("derived"):  # decided now, from the finished runs it needs
        from routine_gym.experiments.derived import derived_flags

        flags.update(derived_flags(config["derived"], runs))
    for flag, value in flags.items():
        if isinstance(value, bool):  # the scripts' booleans are --flag / --no-flag
            words.append(f"--{flag}" if value else f"--no-{flag}")
        else:
            words += [f"--{flag}", *_resolve(value, runs, key)]
    words += ["--run-dir", str(folder), "--torch-threads", "1", *tracking_flags(tracking)]
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


def file_tail(path: Path, size: int) -> bytes | None:
    """The last `size` bytes of a file, None when it cannot be read."""
    try:
        with open(path, "rb") as fh:
            fh.seek(max(0, fh.seek(0, os.SEEK_END) - size))
            return fh.read()
    except OSError:
        return None


def _last_line(path: Path) -> str:
    tail = file_tail(path, 4096)
    if tail is None:
        return "(no log)"
    lines = [ln.strip() for ln in tail.decode(errors="replace").splitlines() if ln.strip()]
    return lines[-1] if lines else "(no output)"


def curve_and_counters(run_dir: Path, config: dict[str, Any]
                        ) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """The run's training episodes binned as the report bins them
    (`training_curves.curve_bins`), so a snapshot of `result.json`s draws Fig. 3 without the
    TensorBoard logs (None without a budget), and what the run counted (`counter_record`;
    None for a script that counts nothing). A run whose budget counts decisions
    (`--budget-unit decisions`) is binned up to the primitive steps it ran."""
    scalars = read_scalars(run_dir)  # an event file is read whole, whichever tags are kept
    total_steps = int(config.get("steps") or 0)
    if config["flags"].get("budget-unit") == "decisions" and "counters/decisions" in scalars:
        total_steps = int(scalars["counters/decisions"][0][-1])
    if total_steps <= 0:
        return None, counter_record(scalars)
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0))
    sums, counts = curve_bins(*scalars.get(RETURN_TAG, empty), total_steps)
    curve = {"total_steps": total_steps, "bins": CURVE_BINS,
             "sums": [round(float(v), 6) for v in sums], "counts": counts.tolist()}
    return curve, counter_record(scalars, total_steps)


def execute_run(config: dict[str, Any], runs_dir: str, cuda: bool = False) -> dict[str, Any]:
    """Run (or resume) one run to the end and write its `result.json`; returns the result, or
    `{"key", "error"}` with the last line of its log. A run whose script reports a divergence
    (exit code `routine_gym.plumbing.divergence.EXIT_CODE`) gets a `diverged.json` beside it
    (`results.divergence` reads it) and returns `{"key", "error", "diverged": True}`. Used by
    both backends (a Ray task runs it on whichever node it lands)."""
    # Absolute: the run's process works in its own folder (a Ray task on whichever node).
    runs = Path(os.path.abspath(runs_dir))
    folder = runs / config["key"]
    log = folder / "log.txt"
    try:
        words = command(config, runs, cuda=cuda)
    except UsageError as exc:  # flags a rule cannot decide (`derived`): one line, no process
        return {"key": config["key"], "error": one_line(exc)}
    start = time.time()
    attempts = Attempts(folder, resumed="--resume" in words)
    with open(log, "ab") as out:
        out.write(f"# {utc_now()} {shlex.join(words)}\n".encode())
        out.flush()
        proc = subprocess.Popen(words, stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, cwd=str(folder),
                                preexec_fn=_die_with_parent)
        with _CHILDREN_LOCK:
            _CHILDREN.add(proc)
        try:
            code = _wait(proc, attempts)
        finally:
            with _CHILDREN_LOCK:
                _CHILDREN.discard(proc)
    if code == DIVERGED_EXIT:
        record = {"key": config["key"], "error": _last_line(log), "finished": utc_now(),
                  "provenance": attempts.record()}
        atomic_write_text(folder / DIVERGED_FILE, json.dumps(record, indent=2) + "\n")
        return {"key": config["key"], "error": f"diverged: {record['error']}", "diverged": True}
    evals = sorted(folder.glob("*/eval.json"), key=lambda p: p.stat().st_mtime)
    if code != 0 or not evals:
        why = f"exit code {code}" if code != 0 else "no eval.json"
        return {"key": config["key"], "error": f"{why}: {_last_line(log)}"}
    run_dir = evals[-1].parent
    try:
        extra = {p.stem[len("eval-"):]: read_json_object(p)
                 for p in sorted(run_dir.glob("eval-*.json"))}
        curve, counters = curve_and_counters(run_dir, config)
        result = {"key": config["key"], "run_dir": run_dir.name,
                  "eval": read_json_object(evals[-1]), "evals": extra, "curve": curve,
                  "seconds": time.time() - start, "finished": utc_now(),
                  "provenance": attempts.record()}
        if counters is not None:
            result["counters"] = counters
    except UsageError as exc:
        return {"key": config["key"], "error": one_line(exc)}
    problem = result_problem(result, config["key"])
    if problem:  # never a result.json that the next sweep would call corrupt
        return {"key": config["key"], "error": f"its evaluation in {run_dir}: {problem}"}
    atomic_write_text(folder / "result.json", json.dumps(result, indent=2) + "\n")
    with contextlib.suppress(FileNotFoundError):  # a divergence before, trained again since
        (folder / DIVERGED_FILE).unlink()
    return result


def _wait(proc: subprocess.Popen, attempts: Attempts) -> int:
    """The exit code of a run's process, noting its wall time every `NOTE_EVERY` seconds."""
    while True:
        try:
            return proc.wait(timeout=NOTE_EVERY)
        except subprocess.TimeoutExpired:
            attempts.note()


def _kill_children() -> None:
    with _CHILDREN_LOCK:
        for proc in list(_CHILDREN):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)


class LocalBackend:
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


class RayBackend:
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
        return {"error": f"{type(err).__name__}: {one_line(err)}"}


def _sigterm(*_: Any) -> None:
    raise KeyboardInterrupt


_HANDLING_SIGTERM = False


def install_signal_handlers() -> None:
    """SIGTERM stops a sweep as Ctrl-C does: the runs' processes are stopped with it (and a
    local Ray instance is shut down)."""
    global _HANDLING_SIGTERM
    _HANDLING_SIGTERM = True
    signal.signal(signal.SIGTERM, _sigterm)
