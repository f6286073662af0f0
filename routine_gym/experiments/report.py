"""The report of a sweep (`routine-gym experiment report OUT`, SPEC §8): the paper's Table 1 and
Figures 2–6 from the runs `routine-gym experiment run` left in `OUT`.

`write_report(OUT)` reads the manifests `OUT/{experiment}.json` and each run's
`OUT/runs/{key}/result.json` (and, for the curves, its TensorBoard log) and writes into
`OUT/report/`:

- per experiment a figure and the CSV behind it: `table1_imitation`, `fig2_rl`, `fig3_curves`,
  `fig4_coinrun`, `fig5_scalability`, `fig6_ablation` (`.png` and `.csv`);
- `report.md`: the sweep's budget, the date of its latest finished run, which runs are
  missing, and a table per experiment with the paper's numbers where it gives them;
- `reference_scores.json`: the scores each game is normalised with (a cache: the random
  policy's score is played once).

A run's score is its final evaluation's mean return (`eval.mean_return` of `result.json`).
Scores are normalised per game (`Reference`): human-normalised with the published table where
the env's profile has a key in it (Atari), else demo-normalised `(score − random)/(demo −
random)` with the shipped demo's best episode and the uniformly random policy's mean score,
else left raw (and out of the aggregates). Aggregates over seeds and games come from rliable:
the IQM with a 95 % stratified-bootstrap interval and the probability of improvement, each over
a `(runs, games)` matrix (`score_matrix`).

Error bars: Table 1 alignment ± sample std over all runs, score IQM with its 95 % CI;
Fig. 2 the standard error over seeds of S_R divided by |S_A|; Fig. 3 ± sample std over seeds of
the binned curves; Fig. 4 ± sample std over seeds; Fig. 5 ± standard error over seeds of each
seed's relative performance averaged over games; Fig. 6 the IQM's 95 % CI.

Importing this module is cheap: rliable, matplotlib, TensorBoard and the envs load when a
report is written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from routine_gym.atomic import atomic_write_bytes, atomic_write_text
from routine_gym.errors import UsageError, one_line
from routine_gym.experiments import json_kind, read_json_object

__all__ = [
    "ABLATION_COLOURS",
    "ABLATION_VARIANTS",
    "COLOURS",
    "CURVE_BINS",
    "EXPERIMENT_NAMES",
    "FILES",
    "Manifest",
    "PAPER_TABLE1",
    "Reference",
    "Run",
    "bin_curve",
    "curve_bins",
    "curve_values",
    "demo_score",
    "iqm_intervals",
    "load_result",
    "load_runs",
    "probability_of_improvement",
    "random_policy_scores",
    "read_episodic_returns",
    "reference_scores",
    "result_problem",
    "score_matrix",
    "write_report",
]

#: The six experiments, in the order of the report.
EXPERIMENT_NAMES = ("imitation", "rl", "curves", "coinrun", "scalability", "ablation")
#: The file stem of each experiment's figure and CSV in `OUT/report/`.
FILES = {"imitation": "table1_imitation", "rl": "fig2_rl", "curves": "fig3_curves",
         "coinrun": "fig4_coinrun", "scalability": "fig5_scalability",
         "ablation": "fig6_ablation"}
_HEADINGS = {"imitation": "Table 1", "rl": "Fig. 2", "curves": "Fig. 3", "coinrun": "Fig. 4",
             "scalability": "Fig. 5", "ablation": "Fig. 6"}

#: One colour per method, the same in every figure (matplotlib's tab10).
COLOURS = {
    "A2C": "#7f7f7f",
    "RAPL-A2C": "#d62728",
    "MacroAction": "#1f77b4",
    "OptionCritic": "#2ca02c",
    "CompILE": "#9467bd",
    "BC": "#8c564b",
    "GAIL": "#e377c2",
    "SQIL": "#17becf",
    "RAPL-SQIL": "#ff7f0e",
}
#: The discovery ablations of Fig. 6 in the paper's order, and one colour each (Full is the
#: full RAPL-A2C, in its colour; the others are colours no method has, so a variant is never
#: read as a baseline; ID, the same discovery on a weaker demo, is a light shade of Full's).
ABLATION_VARIANTS = ("Full", "RR", "PbE", "RF", "ID", "RP")
ABLATION_COLOURS = {"Full": COLOURS["RAPL-A2C"], "RR": "#bcbd22", "PbE": "#393b79",
                    "RF": "#8c6d31", "ID": "#ff9896", "RP": "#7b4173"}
_OTHER_COLOUR = "#333333"

#: The paper's Table 1 (Atari): method → (alignment, human-normalised score).
PAPER_TABLE1 = {"BC": (0.18, 0.183), "GAIL": (0.16, 0.264), "SQIL": (0.28, 0.294),
                "RAPL-SQIL": (0.34, 0.361)}
_METHOD_ORDER = {
    "imitation": ("BC", "GAIL", "SQIL", "RAPL-SQIL"),
    "rl": ("A2C", "RAPL-A2C"),
    "curves": ("A2C", "MacroAction", "OptionCritic", "CompILE", "RAPL-A2C"),
    "coinrun": ("A2C", "RAPL-A2C"),
    "scalability": ("RAPL-A2C", "MacroAction"),
}

#: Step bins of a training curve (Fig. 3) from 0 to the run's budget.
CURVE_BINS = 50
RETURN_TAG = "charts/episodic_return"
#: Episodes and first seed of the random policy behind a demo-normalised score.
REFERENCE_EPISODES = 10
REFERENCE_SEED = 0
_COINRUN_LEVELS = (("train", "train levels"), ("easy", "unseen easy"), ("hard", "hard"))
_MAX_MISSING_LISTED = 12


# -- the sweep's runs ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
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


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _eval_problem(evaluation: Any, where: str) -> str | None:
    if not isinstance(evaluation, dict):
        return f"`{where}` is {json_kind(evaluation)}, not an object"
    score = evaluation.get("mean_return")
    if "mean_return" not in evaluation:
        return f"`{where}` has no `mean_return`"
    if not _number(score) or not math.isfinite(score):
        return f"`{where}.mean_return` is {score!r}, not a finite number"
    alignment = evaluation.get("mean_alignment")
    if "mean_alignment" in evaluation and alignment is not None and (
            not _number(alignment) or math.isinf(alignment)):
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
            _number(v) and math.isfinite(v) for v in sums):
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
    runs: list[Run]
    left_out: list[dict[str, Any]] = []  # settings without runs, each with its why


def _manifest_run(entry: Any, out: Path, results: dict[str, Mapping[str, Any] | None],
                  path: Path) -> Run:
    """A manifest's run entry as a `Run` (with its result); UsageError naming `path`."""
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
    return Run(key=key, method=entry["method"], env_id=entry["env_id"], seed=entry["seed"],
               variant=dict(variant), role=entry.get("role", "main"),
               steps=entry.get("steps", 0), folder=out / "runs" / key, result=results[key])


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


# -- normalisation ------------------------------------------------------------------------------


class Reference(NamedTuple):
    """How a game's scores are normalised: `kind` is `"human"` (the published table, under
    `key`), `"demo"` (`(score − random)/(demo − random)`) or `"raw"` (not normalised)."""

    kind: str
    random: float | None = None
    top: float | None = None  # the human score or the demo's
    key: str | None = None
    note: str = ""

    def normalise(self, score: float) -> float:
        if self.kind == "human":
            from routine_gym.metrics import human_normalized_score

            return float(human_normalized_score(score, self.key))
        if self.kind == "demo":
            return (float(score) - self.random) / (self.top - self.random)
        return float(score)


def random_policy_scores(env_id: str, episodes: int, seed: int) -> dict[str, Any]:
    """The uniformly random policy's scores (`routine_gym.evaluation.random_policy_scores`)."""
    from routine_gym.evaluation import random_policy_scores as play

    return play(env_id, episodes, seed)


def demo_score(env_id: str) -> float | None:
    """The score of the best episode of `env_id`'s shipped demo, or None without one."""
    from routine_gym.demo import Demo, shipped_demo_path

    path = shipped_demo_path(env_id)
    if path is None:
        return None
    demo = Demo.load(path)
    return float(demo.scores[demo.best_episode])


def _human_key(env_id: str) -> str | None:
    from routine_gym.envs import profile_for
    from routine_gym.metrics import atari_game_name

    key = profile_for(env_id).score_key(env_id)
    if key is None:
        return None
    try:
        atari_game_name(key)
    except ValueError:
        return None  # an Atari game outside the published table
    return key


def _read_cache(cache: Path) -> dict[str, Any]:
    """The random-policy cache `reference_scores.json`, checked: UsageError naming it."""
    hint = "delete it: the next report plays the random policy again"
    stored = read_json_object(cache, hint)
    envs = stored.get("envs", {})
    if not isinstance(envs, dict):
        raise UsageError(f"{cache}: `envs` is {json_kind(envs)}, not an object; {hint}")
    for env_id, entry in envs.items():
        if not isinstance(entry, dict):
            raise UsageError(f"{cache}: `envs.{env_id}` is {json_kind(entry)}, not an object; "
                             f"{hint}")
        random = entry.get("random")
        if random is not None and (not _number(random) or not math.isfinite(random)):
            raise UsageError(f"{cache}: `envs.{env_id}.random` is {random!r}, not a finite "
                             f"number; {hint}")
    return stored


def reference_scores(env_ids: Iterable[str], cache: str | Path) -> dict[str, Reference]:
    """Each env's `Reference`, written to `cache` (JSON); a random-policy score already there
    (same episodes and seed) is reused rather than played again."""
    from routine_gym.metrics import HUMAN_RANDOM_SCORES, atari_game_name

    cache = Path(cache)
    cached: dict[str, Any] = {}
    if cache.exists():
        stored = _read_cache(cache)
        if (stored.get("episodes"), stored.get("seed")) == (REFERENCE_EPISODES, REFERENCE_SEED):
            cached = stored.get("envs", {})
    references: dict[str, Reference] = {}
    for env_id in sorted(set(env_ids)):
        key = _human_key(env_id)
        if key is not None:
            random, human = HUMAN_RANDOM_SCORES[atari_game_name(key)]
            references[env_id] = Reference("human", random, human, key)
            continue
        demo = demo_score(env_id)
        if demo is None:
            references[env_id] = Reference("raw", note="no shipped demo and no published table")
            continue
        random = cached.get(env_id, {}).get("random")
        if random is None:
            random = random_policy_scores(env_id, REFERENCE_EPISODES, REFERENCE_SEED)["mean"]
        random = float(random)
        if math.isclose(demo, random):
            references[env_id] = Reference("raw", random, demo,
                                           note="the demo scores as the random policy")
        else:
            references[env_id] = Reference("demo", random, demo)
    envs = {env_id: {"normalisation": ref.kind, "random": ref.random, "reference": ref.top,
                     "score_key": ref.key, "note": ref.note}
            for env_id, ref in references.items()}
    atomic_write_text(cache, json.dumps({"episodes": REFERENCE_EPISODES, "seed": REFERENCE_SEED,
                                         "envs": {**cached, **envs}}, indent=2) + "\n")
    return references


# -- aggregates (rliable) ------------------------------------------------------------------------


def score_matrix(runs: Sequence[Run], games: Sequence[str],
                 value: Callable[[Run], float]) -> np.ndarray | None:
    """The `(runs, games)` matrix rliable aggregates: column `g` holds `value(run)` of the
    finished runs of game `g` by increasing seed, cut to the fewest runs any game has (a
    rectangle); None when a game has none."""
    columns = []
    for game in games:
        done = sorted((r for r in runs if r.env_id == game and r.finished), key=lambda r: r.seed)
        columns.append([value(r) for r in done])
    if not columns or min(len(c) for c in columns) == 0:
        return None
    n = min(len(c) for c in columns)
    return np.array([c[:n] for c in columns], dtype=np.float64).T


@contextmanager
def _bootstrap_rng(seed: int) -> Iterator[np.random.RandomState]:
    # rliable 1.2's stratified bootstraps draw their indices from NumPy's global RNG
    # (np.random.choice) whatever random_state says, so the global RNG is seeded too, and
    # put back afterwards, to make the intervals reproducible.
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(seed)  # noqa: NPY002
    try:
        with warnings.catch_warnings():
            # arch warns about the RandomState rliable hands it.
            warnings.filterwarnings("ignore", message="random_state is deprecated",
                                    category=FutureWarning)
            yield np.random.RandomState(seed)
    finally:
        np.random.set_state(state)  # noqa: NPY002


def iqm_intervals(score_dict: Mapping[str, np.ndarray], reps: int = 2000,
                  seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """`{name: (IQM, lo, hi)}`: rliable's IQM of each `(runs, games)` matrix and its 95 %
    stratified-bootstrap percentile interval (`reps` resamples of the runs within each game).
    Each matrix is resampled from the same seed, so its interval does not depend on the
    others."""
    from rliable import library as rly
    from rliable import metrics as rmetrics

    intervals = {}
    for name, scores in score_dict.items():
        with _bootstrap_rng(seed) as random_state:
            points, cis = rly.get_interval_estimates(
                {name: scores}, lambda x: np.array([rmetrics.aggregate_iqm(x)]), reps=reps,
                random_state=random_state)
        intervals[name] = (float(points[name][0]), float(cis[name][0, 0]),
                           float(cis[name][1, 0]))
    return intervals


def performance_profiles(score_dict: Mapping[str, np.ndarray], taus: np.ndarray,
                         reps: int = 2000, seed: int = 0
                         ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """`{name: (profile, lo, hi)}`: rliable's score distribution, the fraction of runs (of every
    game) scoring above each threshold in `taus`, with its 95 % stratified-bootstrap band."""
    from rliable import library as rly

    with _bootstrap_rng(seed):
        profiles, cis = rly.create_performance_profile(dict(score_dict), taus, reps=reps)
    return {name: (np.asarray(profiles[name], dtype=np.float64),
                   np.asarray(cis[name][0], dtype=np.float64),
                   np.asarray(cis[name][1], dtype=np.float64)) for name in score_dict}


def probability_of_improvement(x: np.ndarray, y: np.ndarray, reps: int = 2000,
                               seed: int = 0) -> tuple[float, float, float]:
    """`(P(X > Y), lo, hi)`: rliable's probability that a run of X beats a run of Y on a game,
    averaged over games (ties count a half), with its 95 % stratified-bootstrap interval;
    `x` and `y` are `(runs, games)` matrices over the same games."""
    from rliable import library as rly
    from rliable import metrics as rmetrics

    with _bootstrap_rng(seed) as random_state:
        points, cis = rly.get_interval_estimates(
            {"X,Y": (x, y)},
            lambda a, b: np.array([rmetrics.probability_of_improvement(a, b)]), reps=reps,
            random_state=random_state)
    return float(points["X,Y"][0]), float(cis["X,Y"][0, 0]), float(cis["X,Y"][1, 0])


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value; NaN for none)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return math.nan, math.nan
    std = float(arr.std(ddof=1)) if arr.size > 1 else 0.0
    return float(arr.mean()), std


def _standard_error(values: Sequence[float]) -> float:
    arr = np.asarray(values, dtype=np.float64)
    return float(arr.std(ddof=1) / math.sqrt(arr.size)) if arr.size > 1 else 0.0


# -- training curves -----------------------------------------------------------------------------


def _event_file_order(path: Path) -> tuple[int, str]:
    # events.out.tfevents.{unix time}.{host}...: a resumed run's file is the later one.
    parts = path.name.split(".")
    stamp = int(parts[3]) if len(parts) > 3 and parts[3].isdigit() else 0
    return stamp, path.name


def read_episodic_returns(folder: str | Path, tag: str = RETURN_TAG
                          ) -> tuple[np.ndarray, np.ndarray]:
    """`(steps, returns)` of the training episodes a run logged to TensorBoard under `tag`,
    read from every event file in `folder`. A resumed run logs into a new file from its
    checkpoint on; what an older file logged at or after the newer file's first step was
    lost with the killed process and is dropped."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    points: list[tuple[int, float]] = []
    for path in sorted(Path(folder).glob("events.out.tfevents.*"), key=_event_file_order):
        events = EventAccumulator(str(path), size_guidance={"scalars": 0})
        events.Reload()
        if tag not in events.Tags()["scalars"]:
            continue
        new = [(e.step, e.value) for e in events.Scalars(tag)]
        if new:
            first = min(step for step, _ in new)
            points = [p for p in points if p[0] < first] + new
    points.sort(key=lambda p: p[0])
    return (np.array([p[0] for p in points], dtype=np.int64),
            np.array([p[1] for p in points], dtype=np.float64))


def curve_bins(steps: Sequence[int] | np.ndarray, returns: Sequence[float] | np.ndarray,
               total_steps: int, bins: int = CURVE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """`(sums, counts)`: the summed return and the number of the episodes that ended in each of
    `bins` equal step bins from 0 to `total_steps` (bin `b` is `(b·w, (b+1)·w]`,
    `w = total_steps / bins`; episodes past `total_steps` count in the last bin). What a sweep
    keeps of a run's training curve (`result.json`'s `curve`), so the report needs no
    TensorBoard log.

    Example:
        >>> sums, counts = curve_bins([3, 4, 9], [5.0, 7.0, 2.0], total_steps=10, bins=5)
        >>> sums.tolist(), counts.tolist()
        ([0.0, 12.0, 0.0, 0.0, 2.0], [0, 2, 0, 0, 1])
    """
    if bins < 1 or total_steps <= 0:
        raise ValueError(f"bins and total_steps need to be ≥ 1, actual values: {bins}, "
                         f"{total_steps}")
    edges = np.linspace(0.0, float(total_steps), bins + 1)
    steps = np.asarray(steps, dtype=np.float64)
    returns = np.asarray(returns, dtype=np.float64)
    index = np.clip(np.searchsorted(edges[1:], steps, side="left"), 0, bins - 1)
    return (np.bincount(index, weights=returns, minlength=bins),
            np.bincount(index, minlength=bins))


def curve_values(sums: Sequence[float] | np.ndarray, counts: Sequence[int] | np.ndarray
                 ) -> np.ndarray:
    """Each bin's mean return from `curve_bins`' sums and counts; an empty bin carries the
    previous value forward, and bins before the first episode are NaN."""
    values = np.full(len(sums), np.nan)
    last = np.nan
    for b, (total, count) in enumerate(zip(sums, counts, strict=True)):
        if count:
            last = total / count
        values[b] = last
    return values


def bin_curve(steps: Sequence[int] | np.ndarray, returns: Sequence[float] | np.ndarray,
              total_steps: int, bins: int = CURVE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """A training curve on a common grid: `bins` equal step bins from 0 to `total_steps`.

    The value at `x` (a bin's right edge) is the mean return of the episodes that ended in
    `(x − w, x]`, `w = total_steps / bins`; an empty bin carries the previous value forward,
    and bins before the first episode are NaN. Episodes past `total_steps` count in the last
    bin.

    Example:
        >>> x, y = bin_curve([3, 4, 9], [5.0, 7.0, 2.0], total_steps=10, bins=5)
        >>> x.tolist(), y.tolist()
        ([2.0, 4.0, 6.0, 8.0, 10.0], [nan, 6.0, 6.0, 6.0, 2.0])
    """
    sums, counts = curve_bins(steps, returns, total_steps, bins)
    return np.linspace(0.0, float(total_steps), bins + 1)[1:], curve_values(sums, counts)


def _run_curve(run: Run, total: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A run's binned curve `(x, values)` on the grid `(0, total]`: from its `result.json` when
    the sweep kept it there on this grid, else from its TensorBoard log (a manifest without
    steps: the grid ends at its last episode); None when it logged no episode."""
    kept = run.result.get("curve")
    if kept and kept.get("bins") == CURVE_BINS and kept.get("total_steps") == total:
        if not any(kept["counts"]):
            return None
        x = np.linspace(0.0, float(total), CURVE_BINS + 1)[1:]
        return x, curve_values(kept["sums"], kept["counts"])
    steps, returns = read_episodic_returns(_curve_folder(run))
    if steps.size == 0:
        return None
    return bin_curve(steps, returns, total or max(int(steps.max()), 1))


# -- writing -------------------------------------------------------------------------------------


def _cell(value: Any) -> Any:
    if isinstance(value, float | np.floating):
        return "" if not math.isfinite(value) else repr(float(value))
    return value


@dataclass
class _Writer:
    """Writes the report's files atomically and remembers them."""

    folder: Path
    references: Mapping[str, Reference]
    reps: int
    seed: int
    written: list[Path] = field(default_factory=list)

    def csv(self, name: str, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> None:
        buffer = io.StringIO()
        writer = csv.writer(buffer, lineterminator="\n")
        writer.writerow(header)
        writer.writerows([_cell(v) for v in row] for row in rows)
        path = self.folder / f"{name}.csv"
        atomic_write_text(path, buffer.getvalue())
        self.written.append(path)

    def png(self, fig: Any, name: str) -> None:
        path = self.folder / f"{name}.png"
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=120)
        atomic_write_bytes(path, buffer.getvalue())
        self.written.append(path)


def _figure(width: float, height: float) -> Any:
    # A figure on the Agg canvas directly: no pyplot, no global backend, no window.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _colour(name: str) -> str:
    return COLOURS.get(name, ABLATION_COLOURS.get(name, _OTHER_COLOUR))


_VERSION = re.compile(r"-v\d+$")


def _game_labels(env_ids: Iterable[str]) -> dict[str, str]:
    """Short names for the axes: `MinAtar/Breakout-v1` → `Breakout`, with the suite kept
    where two suites share a game."""
    env_ids = list(dict.fromkeys(env_ids))
    full = {e: _VERSION.sub("", e.rpartition(":")[2]) for e in env_ids}
    short = {e: name.rpartition("/")[2] for e, name in full.items()}
    clash = {s for s in short.values() if list(short.values()).count(s) > 1}
    return {e: full[e] if short[e] in clash else short[e] for e in env_ids}


def _ordered(names: Iterable[str], order: Sequence[str]) -> list[str]:
    names = set(names)
    return [n for n in order if n in names] + sorted(names - set(order))


def _table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines + [""]


def _num(x: float, digits: int = 2) -> str:
    """`x` with `digits` decimals; – for none (None, NaN), n/a for an infinity (a division by
    a score of 0 or nearly)."""
    if x is None or math.isnan(x):
        return "–"
    return "n/a" if math.isinf(x) else f"{x:.{digits}f}"


def _pct(x: float, digits: int = 1) -> str:
    text = _num(None if x is None else 100 * x, digits)
    return text if text in ("–", "n/a") else f"{text} %"


def _interval(estimate: tuple[float, float, float] | None, percent: bool = True) -> str:
    if estimate is None:
        return "–"
    point, lo, hi = estimate
    if not all(math.isfinite(v) for v in (point, lo, hi)):
        return "n/a"
    if percent:
        return f"{100 * point:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]"
    return f"{point:.2f} [{lo:.2f}, {hi:.2f}]"


# -- shared by the experiments -------------------------------------------------------------------


def _per_env_means(runs: Sequence[Run], envs: Sequence[str]) -> list[str]:
    """A table's per-game cells: the mean over seeds of the runs' final scores, or – for none."""
    cells = []
    for e in envs:
        scores = [r.score for r in runs if r.env_id == e]
        cells.append(_num(float(np.mean(scores)), 1) if scores else "–")
    return cells


def _groups(runs: Iterable[Run], label: Callable[[Run], str | None]) -> dict[str, list[Run]]:
    """The finished main runs by label (a label of None leaves the run out)."""
    groups: dict[str, list[Run]] = {}
    for run in runs:
        if run.role == "main" and run.finished and (name := label(run)) is not None:
            groups.setdefault(name, []).append(run)
    return groups


class _Aggregate(NamedTuple):
    games: list[str]  # the normalised games every group has finished runs of
    matrices: dict[str, np.ndarray]  # group → (runs, games) normalised scores
    iqm: dict[str, tuple[float, float, float]]
    percent: bool  # normalised (shown in %) or, with no normalisable game, raw
    left_out: list[str]  # games left out: raw, or some group has no run of them


def _aggregate(w: _Writer, groups: Mapping[str, list[Run]]) -> _Aggregate:
    """IQMs over the games that every group has finished and that have a normalisation."""
    games = sorted({r.env_id for runs in groups.values() for r in runs})
    common = [g for g in games if all(any(r.env_id == g for r in runs)
                                      for runs in groups.values())]
    normalised = [g for g in common if w.references.get(g, Reference("raw")).kind != "raw"]
    percent = bool(normalised)
    used = normalised if percent else common

    def value(run: Run) -> float:
        return w.references.get(run.env_id, Reference("raw")).normalise(run.score)

    matrices = {}
    for name, runs in groups.items():
        matrix = score_matrix(runs, used, value) if used else None
        if matrix is not None:
            matrices[name] = matrix
    iqm = iqm_intervals(matrices, reps=w.reps, seed=w.seed)
    return _Aggregate(used, matrices, iqm, percent, [g for g in games if g not in used])


def _aggregate_lines(w: _Writer, agg: _Aggregate, what: str = "final score") -> list[str]:
    if not agg.games:
        return ["No game has finished runs of every method: no aggregate.", ""]
    kinds: dict[str, list[str]] = {}
    for g in agg.games:
        kinds.setdefault(w.references.get(g, Reference("raw")).kind, []).append(g)
    names = {"human": "human-normalised", "demo": "demo-normalised", "raw": "raw"}
    unit = "; ".join(f"{names[k]} on {', '.join(gs)}" for k, gs in sorted(kinds.items()))
    unit = f"normalised ({unit}; see Normalisation)" if agg.percent else (
        f"raw ({unit}: no game here has a normalisation)")
    lines = [f"IQM of the {what}, {unit}, over {len(agg.games)} game(s) × the seeds every "
             f"game has, with 95 % stratified-bootstrap CIs (rliable):", ""]
    if agg.left_out:
        lines += [f"Left out of the aggregates: {', '.join(agg.left_out)} (raw scores, or not "
                  "every method finished there).", ""]
    return lines


def _poi_lines(w: _Writer, agg: _Aggregate, winner: str, others: Sequence[str]) -> list[str]:
    rows = []
    for other in others:
        if winner in agg.matrices and other in agg.matrices:
            rows.append((f"{winner} > {other}", _interval(probability_of_improvement(
                agg.matrices[winner], agg.matrices[other], reps=w.reps, seed=w.seed),
                percent=False)))
    if not rows:
        return []
    return ["Probability of improvement P(X > Y) (rliable; a run of X beats a run of Y on a "
            "game, averaged over games), with 95 % CIs:", "",
            *_table(("X > Y", "P(X > Y) [95 % CI]"), rows)]


def _norm_axis_label(w: _Writer, agg: _Aggregate) -> str:
    if not agg.percent:
        return "raw score, IQM"
    kinds = sorted({w.references[g].kind for g in agg.games})
    return f"{'/'.join(kinds)}-normalised score, IQM (%)"


def _iqm_bars(ax: Any, names: Sequence[str], agg: _Aggregate, colours: Sequence[str]) -> None:
    scale = 100.0 if agg.percent else 1.0
    x = np.arange(len(names))
    points = np.array([agg.iqm.get(n, (np.nan,) * 3) for n in names], dtype=np.float64)
    heights = points[:, 0] * scale
    yerr = np.abs(np.vstack([points[:, 0] - points[:, 1], points[:, 2] - points[:, 0]])) * scale
    ax.bar(x, np.nan_to_num(heights), yerr=yerr, color=colours, capsize=5,
           error_kw={"elinewidth": 1.2})
    ax.set_xticks(x, names)
    ax.axhline(0.0, color="black", linewidth=0.8)


# -- Table 1: imitation --------------------------------------------------------------------------


def _imitation(w: _Writer, runs: list[Run]) -> list[str]:
    groups = _groups(runs, lambda r: r.method)
    methods = _ordered(groups, _METHOD_ORDER["imitation"])
    agg = _aggregate(w, groups)
    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    alignment = {m: _mean_std([a for r in groups[m]
                               if _number(a := r.result["eval"].get("mean_alignment"))
                               and math.isfinite(a)]) for m in methods}

    rows = []
    for m in methods:
        point, lo, hi = agg.iqm.get(m, (math.nan,) * 3)
        rows.append((m, len(groups[m]), *alignment[m], point, lo, hi,
                     "normalised" if agg.percent else "raw"))
    w.csv(FILES["imitation"], ("method", "runs", "alignment_mean", "alignment_std",
                               "score_iqm", "score_ci_lo", "score_ci_hi", "score"), rows)

    fig = _figure(10, 4.2)
    left, right = fig.subplots(1, 2)
    x = np.arange(len(methods))
    colours = [_colour(m) for m in methods]
    means = np.array([alignment[m][0] for m in methods])
    stds = np.array([alignment[m][1] for m in methods])
    left.bar(x, np.nan_to_num(means), yerr=stds, color=colours, capsize=5)
    left.set_xticks(x, methods)
    left.set_ylabel("alignment score")
    left.set_title("Alignment with the demo (mean ± std over runs)")
    _iqm_bars(right, methods, agg, colours)
    right.set_ylabel(_norm_axis_label(w, agg))
    right.set_title("Score (IQM, 95 % bootstrap CI)")
    paper = [(i, PAPER_TABLE1[m]) for i, m in enumerate(methods) if m in PAPER_TABLE1]
    if paper:
        marker = {"marker": "D", "facecolors": "none", "edgecolors": "black", "zorder": 3,
                  "label": "paper (Atari)"}
        left.scatter([i for i, _ in paper], [p[0] for _, p in paper], **marker)
        right.scatter([i for i, _ in paper], [100 * p[1] for _, p in paper], **marker)
        left.legend(loc="upper left")
    fig.suptitle("Table 1 — Imitation: BC, GAIL, SQIL, RAPL-SQIL")
    w.png(fig, FILES["imitation"])

    labels = _game_labels(envs)
    header = ("method", "alignment (mean ± std)", "score IQM [95 % CI]",
              *[f"{labels[e]} return" for e in envs], "paper alignment", "paper HNS (Atari)")
    table = []
    for m in methods:
        per_env = _per_env_means(groups[m], envs)
        paper_align, paper_hns = PAPER_TABLE1.get(m, (None, None))
        a_mean, a_std = alignment[m]
        table.append((m, f"{_num(a_mean, 3)} ± {_num(a_std, 3)}" if math.isfinite(a_mean) else "–",
                      _interval(agg.iqm.get(m), agg.percent), *per_env,
                      _num(paper_align) if paper_align is not None else "–",
                      _pct(paper_hns) if paper_hns is not None else "–"))
    lines = ["Alignment: each run's mean alignment of its evaluation episodes with the demo, "
             "mean ± sample std over all runs (every env and seed). Per-env returns: mean "
             "over seeds of the final evaluation's mean return (raw).", "",
             *_aggregate_lines(w, agg), *_table(header, table)]
    return lines + _poi_lines(w, agg, "RAPL-SQIL", [m for m in methods if m != "RAPL-SQIL"])


# -- Fig. 2: relative performance per game ----------------------------------------------------


def _relative(rapl: Sequence[float], a2c: Sequence[float]) -> tuple[float, float]:
    """(S_R − S_A)/|S_A| and its error bar, the standard error of S_R over seeds / |S_A|."""
    from routine_gym.metrics import relative_performance

    s_a = float(np.mean(a2c))
    try:
        value = relative_performance(float(np.mean(rapl)), s_a)
    except ValueError:
        return math.nan, math.nan
    error = _standard_error(rapl) / abs(s_a)
    if not (math.isfinite(value) and math.isfinite(error)):  # S_A too close to 0
        return math.nan, math.nan
    return value, error


def _rl(w: _Writer, runs: list[Run]) -> list[str]:
    groups = _groups(runs, lambda r: r.method)
    a2c, rapl = groups.get("A2C", []), groups.get("RAPL-A2C", [])
    games = sorted({r.env_id for r in a2c} & {r.env_id for r in rapl})
    rows = []
    for g in games:
        s_a = [r.score for r in a2c if r.env_id == g]
        s_r = [r.score for r in rapl if r.env_id == g]
        rel, err = _relative(s_r, s_a)
        rows.append((g, len(s_a), len(s_r), float(np.mean(s_a)), float(np.mean(s_r)),
                     100 * rel, 100 * err))
    rows.sort(key=lambda row: -row[5] if math.isfinite(row[5]) else math.inf)
    w.csv(FILES["rl"], ("env_id", "runs_a2c", "runs_rapl", "S_A", "S_R",
                        "relative_performance_pct", "error_pct"), rows)
    better = sum(1 for row in rows if row[4] >= row[3])
    undefined = [row[0] for row in rows if not math.isfinite(row[5])]

    labels = _game_labels(games)
    fig = _figure(max(7.0, 0.45 * len(rows) + 2.5), 4.5)
    ax = fig.subplots()
    x = np.arange(len(rows))
    ax.bar(x, [np.nan_to_num(row[5]) for row in rows], yerr=[row[6] for row in rows],
           color=COLOURS["RAPL-A2C"], capsize=4)
    ax.axhline(0.0, color="black", linewidth=0.8)
    ax.set_xticks(x, [labels[row[0]] for row in rows], rotation=45 if len(rows) > 6 else 0,
                  ha="right" if len(rows) > 6 else "center")
    ax.set_ylabel("relative performance (S_R − S_A)/|S_A| (%)")
    ax.set_xlabel("game (error bar: standard error of S_R over seeds / |S_A|)")
    ax.set_title(f"Fig. 2 — RAPL-A2C over A2C: same or better on {better} of {len(rows)} "
                 "games")
    w.png(fig, FILES["rl"])

    agg = _aggregate(w, {m: groups[m] for m in ("A2C", "RAPL-A2C") if m in groups})
    table = [(g, n_a, n_r, _num(s_a), _num(s_r), _pct(rel / 100), _pct(err / 100))
             for g, n_a, n_r, s_a, s_r, rel, err in rows]
    lines = ["S = mean over seeds of the final evaluation's mean return (raw). Relative "
             "performance (S_R − S_A)/|S_A| of RAPL-A2C (R) over A2C (A); ± is the standard "
             "error of S_R over seeds divided by |S_A| (A2C's own spread is not in it).", "",
             *_table(("game", "A2C runs", "RAPL runs", "S_A", "S_R", "relative", "±"), table),
             f"**RAPL-A2C same or better than A2C (S_R ≥ S_A) on {better} of {len(rows)} "
             "games** (paper: same or better on 25 of 33 Atari games).", "",
             *([f"The relative performance is undefined (n/a) where S_A is 0 or too close to 0 "
                f"({', '.join(undefined)}): no bar there.", ""] if undefined else []),
             *_aggregate_lines(w, agg),
             *_table(("method", "IQM [95 % CI]"),
                     [(m, _interval(agg.iqm.get(m), agg.percent)) for m in agg.iqm])]
    return lines + _poi_lines(w, agg, "RAPL-A2C", ["A2C"])


# -- Fig. 3: training curves ---------------------------------------------------------------------


def _curve_folder(run: Run) -> Path:
    run_dir = run.result.get("run_dir")
    if run_dir and (run.folder / run_dir).is_dir():
        return run.folder / run_dir
    found = sorted(run.folder.glob("*/events.out.tfevents.*"))
    return found[0].parent if found else run.folder / (run_dir or "")


def _curves(w: _Writer, runs: list[Run]) -> list[str]:
    groups = _groups(runs, lambda r: r.method)
    methods = _ordered(groups, _METHOD_ORDER["curves"])
    games = sorted({r.env_id for rs in groups.values() for r in rs})
    curves: dict[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
    no_log = []
    for g in games:
        for m in methods:
            group = [r for r in groups[m] if r.env_id == g]
            if not group:
                continue
            # One grid per game and method: the budget of its runs (the manifest's steps).
            total = max(r.steps for r in group)
            binned = []
            for run in group:
                curve = _run_curve(run, total)
                if curve is None:
                    no_log.append(run.describe())
                    continue
                x, values = curve
                binned.append(values)
            if binned:
                values = np.vstack(binned)
                count = np.sum(np.isfinite(values), axis=0)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN leading bins
                    mean = np.nanmean(values, axis=0)
                    std = np.where(count > 1, np.nanstd(values, axis=0, ddof=1), 0.0)
                curves[g, m] = (x, mean, np.where(count > 0, std, np.nan), count)
    w.csv(FILES["curves"], ("env_id", "method", "step", "mean_return", "std_return", "runs"),
          [(g, m, float(x[i]), mean[i], std[i], int(count[i]))
           for (g, m), (x, mean, std, count) in curves.items() for i in range(len(x))])

    plotted = [g for g in games if any((g, m) in curves for m in methods)]
    labels = _game_labels(games)
    cols = min(3, max(1, len(plotted)))
    rows_n = max(1, math.ceil(len(plotted) / cols))
    width = max(6.5, 4.4 * cols)
    fig = _figure(width, 3.3 * rows_n + 0.9)
    axes = np.atleast_1d(fig.subplots(rows_n, cols, squeeze=False)).ravel()
    for ax, g in zip(axes, plotted, strict=False):
        for m in methods:
            if (g, m) not in curves:
                continue
            x, mean, std, _ = curves[g, m]
            ax.plot(x, mean, color=_colour(m), label=m, linewidth=1.6)
            ax.fill_between(x, mean - std, mean + std, color=_colour(m), alpha=0.18,
                            linewidth=0)
        ax.set_title(labels[g])
        ax.set_xlabel("agent steps")
        ax.set_ylabel("episodic return")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    for ax in axes[len(plotted):]:
        ax.set_visible(False)
    fig.legend(handles=[_legend_line(m) for m in methods], loc="outside lower center",
               ncols=min(len(methods), 5 if width >= 9 else 3))
    fig.suptitle("Fig. 3 — Training curves (mean ± std over seeds)")
    w.png(fig, FILES["curves"])

    agg = _aggregate(w, groups)
    profile_lines = _profiles(w, agg, methods)
    lines = [f"Curves: each run's training episodes (`{RETURN_TAG}`) averaged in "
             f"{CURVE_BINS} equal step bins from 0 to its budget (an empty bin carries the "
             "last value forward), then mean ± sample std over seeds.", ""]
    if no_log:
        lines += [f"No TensorBoard returns in: {', '.join(no_log)}.", ""]
    lines += [*_aggregate_lines(w, agg),
              *_table(("method", "IQM [95 % CI]"),
                      [(m, _interval(agg.iqm.get(m), agg.percent)) for m in methods
                       if m in agg.iqm])]
    lines += _poi_lines(w, agg, "RAPL-A2C", [m for m in methods if m != "RAPL-A2C"])
    return lines + profile_lines


PROFILE_FILE = "fig3_profiles"


def _profiles(w: _Writer, agg: _Aggregate, methods: Sequence[str]) -> list[str]:
    """rliable's performance profiles of the final scores (`fig3_profiles.png/.csv`)."""
    names = [m for m in methods if m in agg.matrices]
    if not names:
        return []
    scale = 100.0 if agg.percent else 1.0
    top = max(float(np.max(agg.matrices[m])) for m in names)
    bottom = min(0.0, min(float(np.min(agg.matrices[m])) for m in names))
    taus = np.linspace(bottom, max(top, bottom + 1e-6) * 1.05, 41)
    profiles = performance_profiles({m: agg.matrices[m] for m in names}, taus, w.reps, w.seed)
    w.csv(PROFILE_FILE, ("method", "tau", "fraction_above", "ci_lo", "ci_hi"),
          [(m, float(t) * scale, p[i], lo[i], hi[i]) for m, (p, lo, hi) in profiles.items()
           for i, t in enumerate(taus)])
    fig = _figure(6.5, 4.2)
    ax = fig.subplots()
    for m, (p, lo, hi) in profiles.items():
        ax.plot(taus * scale, p, color=_colour(m), label=m, linewidth=1.8)
        ax.fill_between(taus * scale, lo, hi, color=_colour(m), alpha=0.15, linewidth=0)
    unit = _norm_axis_label(w, agg).replace(", IQM", "").replace(" (%)", ", %")
    ax.set_xlabel(f"threshold τ: {unit}")
    ax.set_ylabel("fraction of runs with score > τ")
    ax.set_ylim(-0.02, 1.02)
    ax.legend(loc="best", framealpha=0.9)
    fig.suptitle("Fig. 3 (profiles) — score distributions over all runs and games")
    w.png(fig, PROFILE_FILE)
    return ["", f"Performance profiles (rliable, `{PROFILE_FILE}.png`): the fraction of runs "
            "of every game whose final score is above τ, with 95 % stratified-bootstrap "
            "bands, on the games of the aggregate above."]


def _legend_line(method: str) -> Any:
    from matplotlib.lines import Line2D

    return Line2D([], [], color=_colour(method), linewidth=2, label=method)


# -- Fig. 4: CoinRun -----------------------------------------------------------------------------


def _level_score(run: Run, levels: str) -> float | None:
    if levels == "easy":
        return run.score
    evaluation = (run.result.get("evals") or {}).get(levels)
    return None if evaluation is None else float(evaluation["mean_return"])


def _coinrun(w: _Writer, runs: list[Run]) -> list[str]:
    groups = _groups(runs, lambda r: r.method)
    methods = _ordered(groups, _METHOD_ORDER["coinrun"])
    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    stats = {}
    for e in envs:
        for m in methods:
            for levels, _ in _COINRUN_LEVELS:
                scores = [s for r in groups[m] if r.env_id == e
                          and (s := _level_score(r, levels)) is not None]
                if scores:
                    stats[e, m, levels] = (*_mean_std(scores), len(scores))
    w.csv(FILES["coinrun"], ("env_id", "method", "levels", "mean_return", "std_return", "runs"),
          [(e, m, levels, *values) for (e, m, levels), values in stats.items()])

    fig = _figure(max(5.5, 4.5 * len(envs)), 4.2)
    axes = np.atleast_1d(fig.subplots(1, max(1, len(envs)), squeeze=False)).ravel()
    width = 0.8 / max(1, len(methods))
    for ax, e in zip(axes, envs, strict=False):
        x = np.arange(len(_COINRUN_LEVELS))
        for i, m in enumerate(methods):
            values = [stats.get((e, m, levels), (math.nan, math.nan, 0))
                      for levels, _ in _COINRUN_LEVELS]
            ax.bar(x + (i - (len(methods) - 1) / 2) * width, [np.nan_to_num(v[0]) for v in values],
                   width, yerr=[v[1] for v in values], color=_colour(m), label=m, capsize=4)
        ax.set_xticks(x, [name for _, name in _COINRUN_LEVELS])
        ax.set_ylabel("return (mean ± std over seeds)")
        ax.set_title(_game_labels(envs)[e])
        ax.legend()
    fig.suptitle("Fig. 4 — CoinRun: training levels, unseen easy and hard levels")
    w.png(fig, FILES["coinrun"])

    table = []
    for e in envs:
        for m in methods:
            cells = []
            for levels, _ in _COINRUN_LEVELS:
                mean, std, n = stats.get((e, m, levels), (math.nan, math.nan, 0))
                cells.append(f"{_num(mean)} ± {_num(std)} (n={n})" if n else "–")
            table.append((e, m, *cells))
    return ["Raw returns (CoinRun scores 10 for a finished level), mean ± sample std over "
            "seeds: `train` is the 100 training levels, `unseen easy` the final evaluation, "
            "`hard` unseen hard levels.", "",
            *_table(("env", "method", *[name for _, name in _COINRUN_LEVELS]), table)]


# -- Fig. 5: scalability -------------------------------------------------------------------------


def _scalability(w: _Writer, runs: list[Run]) -> list[str]:
    from routine_gym.metrics import relative_performance

    a2c = _groups(runs, lambda r: r.method if r.method == "A2C" and not r.variant else None)
    baseline = {}
    for g in sorted({r.env_id for r in a2c.get("A2C", [])}):
        s_a = float(np.mean([r.score for r in a2c["A2C"] if r.env_id == g]))
        if s_a != 0.0:
            baseline[g] = s_a

    def label(run: Run) -> str | None:
        k, length = run.variant.get("K"), run.variant.get("min_length", 2)
        if run.method == "A2C" or not all(isinstance(v, int) and not isinstance(v, bool)
                                          for v in (k, length)):
            return None  # not a scalability setting (or not one of whole numbers)
        return json.dumps([run.method, k, length])

    points = []
    for name, group in _groups(runs, label).items():
        method, k, length = json.loads(name)
        per_seed: dict[int, list[float]] = {}
        for r in group:
            if r.env_id in baseline:
                per_seed.setdefault(r.seed, []).append(
                    relative_performance(r.score, baseline[r.env_id]))
        if per_seed:
            seed_means = [float(np.mean(v)) for v in per_seed.values()]
            games = len({r.env_id for r in group if r.env_id in baseline})
            points.append((method, k, length, games, len(seed_means),
                           100 * float(np.mean(seed_means)), 100 * _standard_error(seed_means)))
    order = _METHOD_ORDER["scalability"]
    points.sort(key=lambda p: (order.index(p[0]) if p[0] in order else len(order), p[1], p[2]))
    panels = [("K", [p for p in points if p[2] == 2], 1,
               "K (number of routines), minimum length 2"),
              ("min_length", [p for p in points if p[1] == 3], 2,
               "minimum routine length, K = 3")]
    w.csv(FILES["scalability"], ("panel", "method", "K", "min_length", "games", "seeds",
                                 "relative_mean_pct", "relative_se_pct"),
          [(panel, *p) for panel, chosen, _, _ in panels for p in chosen])

    fig = _figure(10, 4.2)
    for ax, (_, chosen, axis, xlabel) in zip(fig.subplots(1, 2), panels, strict=True):
        ax.axhline(0.0, color=COLOURS["A2C"], linestyle="--", linewidth=1, label="A2C")
        values = sorted({p[axis] for p in chosen})
        for m in _ordered({p[0] for p in chosen}, order):
            line = sorted((p for p in chosen if p[0] == m), key=lambda p: p[axis])
            ax.errorbar([p[axis] for p in line], [p[5] for p in line],
                        yerr=[p[6] for p in line], color=_colour(m), marker="o", capsize=4,
                        linewidth=1.6, label=m)
        if values:
            ax.set_xticks(values)
        else:
            why = "no finished A2C reference" if not baseline else "no finished run here"
            ax.text(0.5, 0.5, why, transform=ax.transAxes, ha="center", va="center")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative performance over A2C (%)\nmean ± s.e. over seeds")
        ax.legend()
    fig.suptitle("Fig. 5 — Scalability: more routines (K) and longer routines")
    w.png(fig, FILES["scalability"])

    lines = ["Relative performance over A2C: for each seed, (S − S_A)/|S_A| averaged over the "
             "games, with S the run's final mean return and S_A A2C's mean over seeds on that "
             "game; then mean ± standard error over seeds. Games where A2C scored 0 are left "
             "out.", ""]
    if not baseline:
        lines += ["No finished A2C run (or A2C scored 0 everywhere): no reference.", ""]
    return lines + _table(("method", "K", "min length", "games", "seeds", "relative ± s.e."),
                          [(m, k, n, g, s, f"{_num(mean, 1)} % ± {_num(se, 1)}"
                            if math.isfinite(mean) else "n/a")
                           for m, k, n, g, s, mean, se in points])


# -- Fig. 6: discovery ablations -----------------------------------------------------------------


def _ablation(w: _Writer, runs: list[Run]) -> list[str]:
    def label(run: Run) -> str | None:
        if run.method == "A2C" and not run.variant:
            return "A2C"
        if run.method == "RAPL-A2C" and "discovery" in run.variant:
            return str(run.variant["discovery"])
        return None

    groups = _groups(runs, label)
    names = _ordered(groups, (*ABLATION_VARIANTS, "A2C"))
    agg = _aggregate(w, groups)
    w.csv(FILES["ablation"], ("variant", "runs", "score_iqm", "score_ci_lo", "score_ci_hi",
                              "score"),
          [(n, len(groups[n]), *agg.iqm.get(n, (math.nan,) * 3),
            "normalised" if agg.percent else "raw") for n in names])

    fig = _figure(max(5.5, 1.0 * len(names) + 2), 4.2)
    ax = fig.subplots()
    _iqm_bars(ax, names, agg, [_colour(n) for n in names])
    ax.set_xticks(np.arange(len(names)), [n if n != "A2C" else "A2C\n(reference)"
                                          for n in names])
    ax.set_ylabel(_norm_axis_label(w, agg))
    ax.set_xlabel("routine discovery (RAPL-A2C)")
    ax.set_title("Fig. 6 — Discovery ablations (IQM, 95 % bootstrap CI)")
    w.png(fig, FILES["ablation"])

    envs = sorted({r.env_id for rs in groups.values() for r in rs})
    labels = _game_labels(envs)
    table = []
    for n in names:
        per_env = _per_env_means(groups[n], envs)
        table.append((n, _interval(agg.iqm.get(n), agg.percent), *per_env))
    return ["Variants of RAPL-A2C's routine discovery (Full: the paper's; RR, PbE, RF, RP: "
            "other proposers; ID: the demo of an expert trained a tenth as long), and A2C "
            "for reference. Per-game columns: mean over seeds of the final mean return "
            "(raw).", "", *_aggregate_lines(w, agg),
            *_table(("variant", "IQM [95 % CI]", *[labels[e] for e in envs]), table)]


_SECTIONS = {"imitation": _imitation, "rl": _rl, "curves": _curves, "coinrun": _coinrun,
             "scalability": _scalability, "ablation": _ablation}
#: Experiments whose aggregates normalise scores (CoinRun is raw; scalability is relative).
_NORMALISED = ("imitation", "rl", "curves", "ablation")


# -- the report ----------------------------------------------------------------------------------


def _title(name: str) -> str:
    from routine_gym.experiments.specs import EXPERIMENTS

    spec = EXPERIMENTS.get(name)
    return spec.title if spec is not None else name


def _status_lines(runs: list[Run]) -> list[str]:
    unique = list({r.key: r for r in runs}.values())
    missing = [r for r in unique if not r.finished]
    line = f"{len(unique) - len(missing)} of {len(unique)} runs finished"
    if missing:
        listed = ", ".join(r.describe() for r in missing[:_MAX_MISSING_LISTED])
        more = len(missing) - _MAX_MISSING_LISTED
        line += f"; missing: {listed}" + (f" and {more} more" if more > 0 else "")
    return [line + ".", ""]


def _normalisation_lines(references: Mapping[str, Reference]) -> list[str]:
    rows = []
    for env_id, ref in sorted(references.items()):
        kind = {"human": "human-normalised (published table)",
                "demo": "demo-normalised", "raw": "raw"}[ref.kind]
        rows.append((env_id, kind, _num(ref.random) if ref.random is not None else "–",
                     _num(ref.top) if ref.top is not None else "–", ref.note or ""))
    return ["## Normalisation", "",
            "Normalised score per game: `(score − random)/(reference − random)`. Atari games "
            "(a key in `routine_gym.metrics.HUMAN_RANDOM_SCORES`) are human-normalised "
            "(reference: the human score); other games are demo-normalised (reference: the "
            "best episode of the shipped demo; random: the uniformly random policy's mean "
            f"over {REFERENCE_EPISODES} episodes from seed {REFERENCE_SEED}); a game with "
            "neither keeps its raw score and is left out of the aggregates. Cached in "
            "`reference_scores.json`.", "",
            *_table(("env", "normalisation", "random", "reference", "note"), rows)]


#: Every file a report may write into `OUT/report/`; those this report did not write (an
#: experiment whose data is gone) are removed, so the folder holds exactly this report.
REPORT_FILES = (*(f"{stem}.{ext}" for stem in (*FILES.values(), PROFILE_FILE)
                  for ext in ("png", "csv")), "report.md", "reference_scores.json")


def write_report(out: str | Path, *, reps: int = 2000, seed: int = 0) -> list[Path]:
    """Aggregate the sweep in `out` and write `out/report/` (see the module docstring).

    The report only reads the sweep folder, so it may be written while a sweep runs there (it
    takes no lock): it shows the runs finished so far, and `report.md` says a sweep was
    running. The files of an earlier report that this one does not write (an experiment whose
    manifest is gone, a figure with no finished run now) are removed.

    Args:
        out: the folder `routine-gym experiment run --out` wrote.
        reps: bootstrap resamples of each confidence interval.
        seed: seed of the resampling (the same seed, the same intervals).

    Returns:
        The paths written: each experiment's PNG and CSV, `reference_scores.json`, and
        `report.md` (last).

    Raises:
        UsageError: one line naming the file: `out` does not exist, is a file or holds no
            manifest of the six experiments; a manifest, `result.json` or the random-policy
            cache that is not valid JSON or not of the sweep's shape; `out/report` that is a
            file or cannot be written.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"{out}: a file, not a sweep folder (the --out of `routine-gym "
                         "experiment run`)")
    if not out.is_dir():
        raise UsageError(f"{out}: no such sweep folder (write one with `routine-gym "
                         "experiment run --out`)")
    folder = out / "report"
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{folder}: a file, where the report's folder goes; move it away")
    try:
        written = _write_report(out, folder, reps, seed)
        for name in REPORT_FILES:
            stale = folder / name
            if stale not in written and (stale.is_file() or stale.is_symlink()):
                stale.unlink()
    except OSError as exc:  # a read-only folder, a full disk
        raise UsageError(f"{folder}: cannot write the report there "
                         f"({exc.strerror or one_line(exc)})") from None
    return written


def _sweep_note(out: Path) -> list[str]:
    from routine_gym.experiments.sweep import lock_holder

    holder = lock_holder(out)
    if holder is None:
        return []
    return [f"Written while a sweep was running in this folder ({holder}): runs still in "
            "flight count as missing.", ""]


def _write_report(out: Path, folder: Path, reps: int, seed: int) -> list[Path]:
    results: dict[str, Mapping[str, Any] | None] = {}
    manifests = {name: load_runs(out, name, results) for name in EXPERIMENT_NAMES}
    if all(m is None for m in manifests.values()):
        raise UsageError(f"{out}: not a sweep folder: none of "
                         f"{', '.join(n + '.json' for n in EXPERIMENT_NAMES)} is there")
    envs = {r.env_id for name in _NORMALISED if manifests[name]
            for r in manifests[name].runs if r.role == "main" and r.finished}
    references = reference_scores(envs, folder / "reference_scores.json")
    w = _Writer(folder, references, reps, seed)
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
    for name in EXPERIMENT_NAMES:
        lines += [f"## {_HEADINGS[name]} — {_title(name)} (`{name}`)", ""]
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
        lines += [f"Figure: `{FILES[name]}.png`, data: `{FILES[name]}.csv`.", ""]
        lines += _SECTIONS[name](w, main)
    lines += _normalisation_lines(references)
    atomic_write_text(folder / "report.md", "\n".join(lines).rstrip() + "\n")
    w.written.append(folder / "report.md")
    return w.written
