"""Reading a sweep folder: each experiment's manifest `OUT/{experiment}.json` and each run's
`OUT/runs/{key}/result.json`, checked, as `RunRecord`s.

A run's result is checked for the shape the report reads (`result_problem`); the sweep uses the
same check to decide whether a run finished. Every error is one line naming the file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from routine_gym.errors import UsageError
from routine_gym.experiments import json_kind, read_json_object

__all__ = ["DIVERGED_FILE", "RESULT_HINT", "Manifest", "RunRecord", "divergence", "is_number",
           "load_result", "load_runs", "result_problem"]


@dataclass(frozen=True)
class RunRecord:
    """One entry of an experiment's manifest and, when the run finished, its `result.json`."""

    key: str
    method: str
    env_id: str
    seed: int
    variant: Mapping[str, Any]
    role: str
    steps: int
    folder: Path
    result: Mapping[str, Any] | None = None
    #: The one line of a run that diverged (its `diverged.json`) and has no result.
    diverged: str | None = None

    @property
    def finished(self) -> bool:
        return self.result is not None

    @property
    def score(self) -> float:
        """The final evaluation's mean return (unseen easy levels for CoinRun)."""
        return float(self.result["eval"]["mean_return"])

    def describe(self) -> str:
        variant = "".join(f", {k}={v}" for k, v in self.variant.items())
        return f"`{self.key}` ({self.method}, {self.env_id}, seed {self.seed}{variant})"


#: What a run key looks like (12 hex digits today); anything else in a manifest is refused, so a
#: key never names a path outside `OUT/runs/`.
_KEY = re.compile(r"[A-Za-z0-9_-]{1,64}")
#: The hint of an error about a run's `result.json`.
RESULT_HINT = ("run the sweep's `routine-gym experiment run` command again: it moves a corrupt "
               "result.json aside and reruns the run")


#: A run's record that it diverged (`OUT/runs/KEY/diverged.json`, written by `execute_run` when
#: its script exits with `routine_gym.plumbing.divergence.EXIT_CODE`): the key, the script's
#: one-line report, when, and the provenance of its attempts.
DIVERGED_FILE = "diverged.json"


def divergence(folder: str | Path) -> str | None:
    """The one-line report of a run that diverged (its folder's `diverged.json`) and has not
    finished since (no `result.json`), or None.

    Raises:
        UsageError: the file is not a JSON object with a string `error`.
    """
    folder = Path(folder)
    path = folder / DIVERGED_FILE
    if (folder / "result.json").exists() or not path.exists():
        return None
    record = read_json_object(path, "delete it: the sweep then trains the run again")
    if not isinstance(record.get("error"), str):
        raise UsageError(f"{path}: `error` is {record.get('error')!r}, not the run's report; "
                         "delete it: the sweep then trains the run again")
    return record["error"]


def is_number(value: Any) -> bool:
    """Whether a JSON value is a number (an int or a float, not a boolean)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _eval_problem(evaluation: Any, where: str) -> str | None:
    if not isinstance(evaluation, dict):
        return f"`{where}` is {json_kind(evaluation)}, not an object"
    score = evaluation.get("mean_return")
    if "mean_return" not in evaluation:
        return f"`{where}` has no `mean_return`"
    if not is_number(score) or not math.isfinite(score):
        return f"`{where}.mean_return` is {score!r}, not a finite number"
    alignment = evaluation.get("mean_alignment")
    if "mean_alignment" in evaluation and alignment is not None and (
            not is_number(alignment) or math.isinf(alignment)):
        return f"`{where}.mean_alignment` is {alignment!r}, not a number"
    return None


def _curve_problem(curve: Any) -> str | None:
    if curve is None:
        return None
    if not isinstance(curve, dict):
        return f"`curve` is {json_kind(curve)}, not an object"
    bins, total = curve.get("bins"), curve.get("total_steps")
    if not isinstance(bins, int) or isinstance(bins, bool) or bins < 1:
        return f"`curve.bins` is {bins!r}, not a number of bins"
    if not isinstance(total, int) or isinstance(total, bool) or total < 1:
        return f"`curve.total_steps` is {total!r}, not a number of steps"
    sums, counts = curve.get("sums"), curve.get("counts")
    if not isinstance(sums, list) or len(sums) != bins or not all(
            is_number(v) and math.isfinite(v) for v in sums):
        return f"`curve.sums` is not a list of {bins} finite numbers"
    if not isinstance(counts, list) or len(counts) != bins or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in counts):
        return f"`curve.counts` is not a list of {bins} counts"
    return None


def result_problem(result: Any, key: str | None = None) -> str | None:
    """What is wrong with a run's result (a parsed `result.json`), or None when it has the shape
    the report reads: an object with `eval` (an evaluation with a finite `mean_return`), and
    optionally `evals` (more evaluations by name), `curve` (the binned training curve),
    `run_dir` (a folder name), `finished` (a date) and `key` (`key`, when given)."""
    if not isinstance(result, dict):
        return f"holds {json_kind(result)}, not a JSON object"
    if key is not None and "key" in result and result["key"] != key:
        return f"is the result of run {result['key']!r}, not of run {key}"
    if "eval" not in result:
        return "has no `eval` (the run's final evaluation)"
    problem = _eval_problem(result["eval"], "eval")
    if problem:
        return problem
    evals = result.get("evals")
    if evals is not None:
        if not isinstance(evals, dict):
            return f"`evals` is {json_kind(evals)}, not an object"
        for name, evaluation in evals.items():
            if problem := _eval_problem(evaluation, f"evals.{name}"):
                return problem
    run_dir = result.get("run_dir")
    if run_dir is not None and (not isinstance(run_dir, str) or not run_dir
                                or run_dir in (".", "..") or "/" in run_dir or "\\" in run_dir):
        return f"`run_dir` is {run_dir!r}, not a folder name"
    finished = result.get("finished")
    if finished is not None and not isinstance(finished, str):
        return f"`finished` is {finished!r}, not a date"
    return _curve_problem(result.get("curve"))


def load_result(path: str | Path, key: str | None = None) -> dict[str, Any]:
    """A run's `result.json`, checked (`result_problem`).

    Raises:
        UsageError: one line naming the file and what is wrong with it (not JSON, empty,
            truncated, the wrong shape).
    """
    result = read_json_object(path, RESULT_HINT)
    problem = result_problem(result, key)
    if problem:
        raise UsageError(f"{path}: {problem}; {RESULT_HINT}")
    return result


class Manifest(NamedTuple):
    """An experiment's manifest, `OUT/{experiment}.json`, with its runs."""

    budget: str
    description: str
    runs: list[RunRecord]
    left_out: list[dict[str, Any]] = []  # settings without runs, each with its why


def _manifest_run(entry: Any, out: Path, results: dict[str, Mapping[str, Any] | None],
                  path: Path) -> RunRecord:
    """A manifest's run entry as a `RunRecord` (with its result); UsageError naming `path`."""
    if not isinstance(entry, dict):
        raise UsageError(f"{path}: a run entry is {json_kind(entry)}, not an object "
                         f"({entry!r:.80})")
    missing = [f for f in ("key", "method", "env_id", "seed") if f not in entry]
    if missing:
        raise UsageError(f"{path}: a run entry lacks {missing[0]!r} ({entry!r:.120})")
    key = entry["key"]
    if not isinstance(key, str) or not _KEY.fullmatch(key):
        raise UsageError(f"{path}: a run entry's key is {key!r}, not a run key")
    for name in ("method", "env_id", "role"):
        if name in entry and not isinstance(entry[name], str):
            raise UsageError(f"{path}: run {key}: `{name}` is {entry[name]!r}, not a string")
    for name in ("seed", "steps"):
        value = entry.get(name, 0)
        if not isinstance(value, int) or isinstance(value, bool):
            raise UsageError(f"{path}: run {key}: `{name}` is {value!r}, not a whole number")
    variant = entry.get("variant") or {}
    if not isinstance(variant, dict):
        raise UsageError(f"{path}: run {key}: `variant` is {json_kind(variant)}, not an object")
    if key not in results:
        result_path = out / "runs" / key / "result.json"
        results[key] = load_result(result_path, key) if result_path.exists() else None
    diverged = None if results[key] is not None else divergence(out / "runs" / key)
    return RunRecord(key=key, method=entry["method"], env_id=entry["env_id"], seed=entry["seed"],
               variant=dict(variant), role=entry.get("role", "main"),
               steps=entry.get("steps", 0), folder=out / "runs" / key, result=results[key],
               diverged=diverged)


def load_runs(out: str | Path, experiment: str,
              results: dict[str, Mapping[str, Any] | None] | None = None) -> Manifest | None:
    """The manifest `OUT/{experiment}.json` with its runs, or None when it is absent.

    Each run carries its `result.json` when it has one; `results` caches them by key across
    experiments (several experiments share runs).

    Raises:
        UsageError: naming the file, for a manifest or result that is not valid JSON or not of
            the shape the sweep writes (`result_problem`), or a manifest entry without its
            fields.
    """
    out = Path(out)
    path = out / f"{experiment}.json"
    if not path.exists():
        return None
    manifest = read_json_object(path)
    results = {} if results is None else results
    entries = manifest.get("runs", [])
    if not isinstance(entries, list):
        raise UsageError(f"{path}: `runs` is {json_kind(entries)}, not a list")
    runs = [_manifest_run(entry, out, results, path) for entry in entries]
    gaps = manifest.get("left_out") or []
    if not isinstance(gaps, list) or not all(
            isinstance(g, dict) and isinstance(g.get("variant") or {}, dict) for g in gaps):
        raise UsageError(f"{path}: `left_out` is not a list of settings (objects with an "
                         "env_id, a variant and why)")
    return Manifest(str(manifest.get("budget", "?")), str(manifest.get("description", "")), runs,
                    list(gaps))
