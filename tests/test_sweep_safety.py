"""`routine-gym experiment run/report` against the mistakes of issue 24, with real files, flags
and processes: a relative `--out`, two sweeps on one folder (and a killed one's lock file),
corrupt and wrongly shaped JSON files, an unwritable `--out`, nonsense options. Only one test
trains (two smoke runs); the others stop before any run starts, or use a backend that runs
nothing."""

from __future__ import annotations

import functools
import io
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from one_line import assert_one_line_error

from routine_gym.errors import UsageError
from routine_gym.experiments import (
    backends,
    folder_lock,
    read_json_object,
    reference,
    registry,
    report,
    results,
    specs,
    sweep,
)
from routine_gym.experiments.specs import RunSpec

#: The sweep's errors are the CLI's: one line starting `routine-gym: error: `.
_one_line_error = functools.partial(assert_one_line_error, prefix="routine-gym: error: ")

CLI = [sys.executable, "-m", "routine_gym.cli"]
BREAKOUT = "MinAtar/Breakout-v1"
HOST = socket.gethostname()
#: What a corrupt file can hold: (label, bytes).
BAD_JSON = [
    ("empty", b""),
    ("truncated", b'{"key": "x", "eval": {"mean_return": 1'),
    ("not JSON", b"hello"),
    ("not UTF-8", b"\xff\xfe\x00"),
    ("a list", b"[1, 2]"),
    ("a string", b'"text"'),
    ("a number", b"3"),
    ("null", b"null"),
    ("deeply nested", b"[" * 100_000 + b"]" * 100_000),
]
BAD_JSON_IDS = [label for label, _ in BAD_JSON]


def _cli(args: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, "experiment", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=timeout)


def _one_line(exc: pytest.ExceptionInfo, *parts: str) -> str:
    text = str(exc.value)
    assert "\n" not in text
    for part in parts:
        assert part in text, (part, text)
    return text


# -- 1 and 2: a relative --out, two sweeps at once, a killed sweep's lock -------------------------

def _lock_info(path: Path) -> dict:
    try:
        return json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        return {}


@pytest.mark.slow
def test_a_relative_out_trains_in_place_and_one_sweep_holds_the_folder_at_a_time(tmp_path):
    """The README's `--out sweeps/...` from another folder: the runs train into
    `sweeps/smoke/runs/KEY/` (not into `runs/KEY/sweeps/smoke/...`) and finish; a second
    sweep on the folder is refused at once naming the first; the lock file a SIGKILLed sweep
    leaves behind blocks nobody; a sweep after the last one ended runs."""
    cmd = [*CLI, "experiment", "run", "rl", "--budget", "smoke", "--out", "sweeps/smoke",
           "--jobs", "2"]
    out = tmp_path / "sweeps" / "smoke"
    lock = out / ".lock"
    first = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        while _lock_info(lock).get("pid") != first.pid and time.time() < deadline:
            assert first.poll() is None, "the first sweep ended before it held the folder"
            time.sleep(0.1)
        # Paused as soon as it holds the folder, it starts no run meanwhile (a run it started
        # already trains on, in a process group of its own, and dies with it below).
        first.send_signal(signal.SIGSTOP)
        info = _lock_info(lock)
        assert info["pid"] == first.pid and info["host"] == HOST
        assert "experiment run rl --budget smoke --out sweeps/smoke" in info["command"]

        start = time.time()
        second = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
        assert time.time() - start < 30  # refused at once, not after training anything
        _one_line_error(second, f"{out} is in use by another sweep (pid {first.pid} on {HOST}, "
                                f"started {info['started']}")
        assert first.poll() is None
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait(timeout=60)
    assert _lock_info(lock).get("pid") == first.pid  # the killed sweep's file is still there

    third = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert third.returncode == 0, third.stdout + third.stderr
    assert f"into {out}\n" in third.stdout  # the folder made absolute once
    keys = {r["key"] for r in json.loads((out / "rl.json").read_text())["runs"]}
    assert len(keys) == 5  # A2C, RAPL-A2C, PPO, RAPL-PPO, MacroAction-PPO
    for key in keys:
        folder = out / "runs" / key
        result = json.loads((folder / "result.json").read_text())
        assert (folder / result["run_dir"] / "eval.json").is_file()
        assert not (folder / "sweeps").exists()  # nothing trained into a nested copy
        assert "no eval.json" not in (folder / "log.txt").read_text()
    assert lock.read_text() == ""  # released: it names no holder
    assert folder_lock.lock_holder(out) is None

    fourth = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert fourth.returncode == 0, fourth.stderr
    assert "5 finished before, 0 to run" in fourth.stdout


def _hold(folder: Path) -> subprocess.Popen:
    """Another process holding the sweep folder (as a running sweep does)."""
    code = ("import sys, time\n"
            "from routine_gym.experiments.folder_lock import sweep_lock\n"
            "with sweep_lock(sys.argv[1], command='a sweep in a test'):\n"
            "    print('held', flush=True)\n"
            "    time.sleep(600)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder)], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


class _Backend:
    """A backend that runs nothing: it records the keys submitted and reports them finished,
    writing a valid `result.json` as `execute_run` would."""

    def __init__(self, submitted: list[str]) -> None:
        self.submitted = submitted

    def submit(self, config, runs, cuda):
        self.submitted.append(config["key"])
        result = {"key": config["key"], "run_dir": "r", "eval": {"mean_return": 1.0},
                  "evals": {}, "curve": None, "seconds": 0.0, "finished": "2026-01-01T00:00:00Z"}
        (Path(runs) / config["key"] / "result.json").write_text(json.dumps(result))
        return config["key"]

    def wait(self, handles, timeout):
        return [(h, {"key": h}) for h in handles]

    def close(self):
        pass


def _runs(n: int) -> list[specs.Entry]:
    return [specs.Entry(RunSpec("rapl_a2c", (("env-id", BREAKOUT), ("seed", seed)), 10),
                        "A2C", BREAKOUT, seed) for seed in range(1, n + 1)]


@pytest.fixture
def fake_runs(monkeypatch) -> tuple[list[specs.Entry], list[str]]:
    """The sweep's experiment is `_runs(3)` and its backend `_Backend`: (entries, submitted)."""
    entries, submitted = _runs(3), []
    monkeypatch.setattr(sweep, "build", lambda *a, **k: entries)
    monkeypatch.setattr(sweep, "LocalBackend", lambda jobs: _Backend(submitted))
    return entries, submitted


def test_a_held_folder_refuses_a_sweep_before_it_writes_and_frees_when_its_holder_dies(
        tmp_path, fake_runs):
    _, submitted = fake_runs
    holder = _hold(tmp_path)
    try:
        with pytest.raises(UsageError) as exc:
            sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO())
        _one_line(exc, f"{tmp_path} is in use by another sweep (pid {holder.pid} on {HOST}, "
                       "started ", ": a sweep in a test)")
        assert not (tmp_path / "rl.json").exists() and not submitted
        assert folder_lock.lock_holder(tmp_path).startswith(f"pid {holder.pid} on {HOST}")
    finally:
        holder.kill()
        holder.wait()
    # Killed: its file still names it, but the kernel dropped its lock.
    assert json.loads((tmp_path / ".lock").read_text())["pid"] == holder.pid
    assert folder_lock.lock_holder(tmp_path) is None  # its pid is gone
    assert sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO()).ok
    assert len(submitted) == 3
    # Re-entrant in one process (`experiment run all` holds it across experiments).
    with folder_lock.sweep_lock(tmp_path) as held:
        assert held == tmp_path
        assert sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO()).ok
        assert folder_lock.lock_holder(tmp_path).startswith(f"pid {os.getpid()} on {HOST}")
    assert (tmp_path / ".lock").read_text() == ""


# -- 3: corrupt results count as not finished (sweep) and name their file (report) ----------------

#: A result.json of the wrong shape, and the words of its problem.
BAD_RESULTS = [
    ("no eval", {"evals": {}}, "has no `eval`"),
    ("eval not an object", {"eval": [1]}, "`eval` is a list, not an object"),
    ("no mean_return", {"eval": {"episodes": 1}}, "`eval` has no `mean_return`"),
    ("mean_return a string", {"eval": {"mean_return": "7"}}, "`eval.mean_return` is '7'"),
    ("mean_return NaN", {"eval": {"mean_return": float("nan")}}, "not a finite number"),
    ("mean_return inf", {"eval": {"mean_return": float("inf")}}, "not a finite number"),
    ("evals a list", {"eval": {"mean_return": 1}, "evals": []}, "`evals` is a list"),
    ("level eval without score", {"eval": {"mean_return": 1}, "evals": {"hard": {}}},
     "`evals.hard` has no `mean_return`"),
    ("run_dir a path", {"eval": {"mean_return": 1}, "run_dir": "../../x"}, "not a folder name"),
    ("curve a string", {"eval": {"mean_return": 1}, "curve": "x"}, "`curve` is a string"),
    ("curve short", {"eval": {"mean_return": 1},
                     "curve": {"bins": 3, "total_steps": 9, "sums": [1], "counts": [1]}},
     "`curve.sums` is not a list of 3 finite numbers"),
    ("finished a number", {"eval": {"mean_return": 1}, "finished": 3}, "`finished` is 3"),
    ("another run's", {"key": "ffffffffffff", "eval": {"mean_return": 1}},
     "is the result of run 'ffffffffffff'"),
]


def _shape(result: dict) -> bytes:
    return json.dumps(result).encode()


def test_corrupt_results_are_moved_aside_and_their_runs_run_again(tmp_path, fake_runs):
    entries, submitted = fake_runs
    keys = [e.run.key for e in entries]
    stream = io.StringIO()
    assert sweep.run_experiment("rl", "smoke", tmp_path, stream=stream).ok
    assert submitted == keys
    good = (tmp_path / "runs" / keys[0] / "result.json").read_bytes()
    # Every way a result can be broken: the file's bytes, or a JSON object of a wrong shape.
    corruptions = [raw for _, raw in BAD_JSON] + [_shape(bad) for _, bad, _ in BAD_RESULTS]
    for raw in corruptions:
        submitted.clear()
        (tmp_path / "runs" / keys[1] / "result.json").write_bytes(raw)
        stream = io.StringIO()
        summary = sweep.run_experiment("rl", "smoke", tmp_path, stream=stream)
        assert summary.ok and submitted == [keys[1]], raw[:60]  # only the corrupt one reruns
        path = tmp_path / "runs" / keys[1] / "result.json"
        note = next(line for line in stream.getvalue().splitlines() if "corrupt" in line)
        assert note.startswith(f"[rl] {path} is corrupt (") and "moved aside to" in note
        assert f"run {keys[1]} runs again" in note
        aside = sorted(path.parent.glob("result.json.corrupt-*"))
        assert aside and aside[-1].read_bytes() == raw and aside[-1].name in note
        assert json.loads(path.read_text())["eval"] == {"mean_return": 1.0}  # the rerun's
        for old in aside:
            old.unlink()
    assert (tmp_path / "runs" / keys[0] / "result.json").read_bytes() == good


def test_execute_run_never_writes_a_result_the_next_sweep_calls_corrupt(tmp_path):
    """A script whose eval.json is broken fails the run, naming the file, and leaves no
    result.json (the run is not counted finished)."""
    script = ("import pathlib, sys\n"
              "d = pathlib.Path(sys.argv[sys.argv.index('--run-dir') + 1]) / 'run'\n"
              "d.mkdir(parents=True, exist_ok=True)\n"
              "(d / 'eval.json').write_text(sys.argv[sys.argv.index('--payload') + 1])\n")
    (tmp_path / "fake.py").write_text(script)
    for payload, why in (("[1]", "holds a list, not a JSON object"),
                         ('{"mean_return": "x"}', "`eval.mean_return` is 'x'")):
        config = {"key": "aaaaaaaaaaaa", "script": "fake", "flags": {"payload": payload},
                  "steps": 0}
        runs = tmp_path / "runs"
        (runs / "aaaaaaaaaaaa").mkdir(parents=True, exist_ok=True)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(backends, "script_path", lambda name: tmp_path / f"{name}.py")
            outcome = backends.execute_run(config, str(runs))
        assert why in outcome["error"], outcome
        assert not (runs / "aaaaaaaaaaaa" / "result.json").exists()


# -- the report: files it reads, folders it writes ------------------------------------------------

def _sweep_folder(out: Path, scores: dict[tuple[str, int], float], experiment: str = "rl",
                  env_id: str = BREAKOUT) -> dict[tuple[str, int], str]:
    """A sweep folder as `experiment run` leaves it: (method, seed) → key."""
    keys, rows = {}, []
    for (method, seed), score in scores.items():
        key = f"{experiment[:2]}{len(keys):010x}"
        keys[method, seed] = key
        rows.append({"key": key, "script": "rapl_a2c", "method": method, "env_id": env_id,
                     "seed": seed, "variant": {}, "role": "main", "steps": 100})
        folder = out / "runs" / key
        folder.mkdir(parents=True)
        (folder / "result.json").write_text(json.dumps(
            {"key": key, "run_dir": "r", "eval": {"mean_return": score}, "evals": {},
             "finished": "2026-01-01T00:00:00Z"}))
    (out / f"{experiment}.json").write_text(json.dumps(
        {"experiment": experiment, "version": 1, "budget": "smoke", "runs": rows}))
    return keys


@pytest.fixture
def references(monkeypatch):
    """Breakout is demo-normalised with demo 10 and random 0; nothing is played."""
    monkeypatch.setattr(reference, "demo_score", {BREAKOUT: 10.0}.get)
    monkeypatch.setattr(reference, "random_policy_scores", lambda *a: {"mean": 0.0})


RL = {("A2C", 1): 4.0, ("A2C", 2): 6.0, ("RAPL-A2C", 1): 6.0, ("RAPL-A2C", 2): 8.0}


@pytest.mark.parametrize(("label", "raw"), BAD_JSON, ids=BAD_JSON_IDS)
def test_report_names_a_corrupt_result_json(tmp_path, label, raw):
    keys = _sweep_folder(tmp_path, RL)
    path = tmp_path / "runs" / keys["RAPL-A2C", 2] / "result.json"
    path.write_bytes(raw)
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{path}: ", "experiment run")


@pytest.mark.parametrize(("label", "bad", "why"), BAD_RESULTS,
                         ids=[label for label, _, _ in BAD_RESULTS])
def test_report_names_a_result_json_of_the_wrong_shape(tmp_path, label, bad, why):
    keys = _sweep_folder(tmp_path, RL)
    path = tmp_path / "runs" / keys["A2C", 1] / "result.json"
    path.write_bytes(_shape(bad))
    with pytest.raises(UsageError) as exc:
        results.load_runs(tmp_path, "rl")
    _one_line(exc, f"{path}: ", why)


@pytest.mark.parametrize(("label", "raw"), BAD_JSON, ids=BAD_JSON_IDS)
def test_a_manifest_of_the_wrong_shape_is_one_line_for_run_and_report(tmp_path, label, raw,
                                                                      fake_runs):
    _, submitted = fake_runs
    (tmp_path / "rl.json").write_bytes(raw)
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{tmp_path / 'rl.json'}: ")
    with pytest.raises(UsageError) as exc:
        sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO())
    _one_line(exc, f"{tmp_path / 'rl.json'}: ")
    assert not submitted


@pytest.mark.parametrize(("manifest", "why"), [
    ({"runs": {"a": 1}}, "`runs` is an object, not a list"),
    ({"runs": [3]}, "a run entry is a number, not an object"),
    ({"runs": [{"key": "aaaaaaaaaaaa", "method": "A2C", "env_id": BREAKOUT}]},
     "a run entry lacks 'seed'"),
    ({"runs": [{"key": "../../etc", "method": "A2C", "env_id": BREAKOUT, "seed": 1}]},
     "a run entry's key is '../../etc', not a run key"),
    ({"runs": [{"key": "aaaaaaaaaaaa", "method": "A2C", "env_id": BREAKOUT, "seed": "one"}]},
     "`seed` is 'one', not a whole number"),
    ({"runs": [{"key": "aaaaaaaaaaaa", "method": "A2C", "env_id": BREAKOUT, "seed": 1,
                "variant": [1]}]}, "`variant` is a list, not an object"),
    ({"runs": [], "left_out": [{"env_id": BREAKOUT, "variant": "K"}]}, "`left_out` is not"),
])
def test_report_names_a_manifest_entry_of_the_wrong_shape(tmp_path, manifest, why):
    (tmp_path / "rl.json").write_text(json.dumps(manifest))
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{tmp_path / 'rl.json'}: ", why)


@pytest.mark.parametrize(("label", "raw"), [
    *BAD_JSON, ("envs a list", b'{"episodes": 10, "seed": 0, "envs": []}'),
    ("random a string", b'{"episodes": 10, "seed": 0, "envs": {"MinAtar/Breakout-v1": '
                        b'{"random": "zero"}}}'),
], ids=[*BAD_JSON_IDS, "envs a list", "random a string"])
def test_report_names_a_random_policy_cache_of_the_wrong_shape(tmp_path, label, raw,
                                                                references):
    _sweep_folder(tmp_path, RL)
    cache = tmp_path / "report" / "reference_scores.json"
    cache.parent.mkdir()
    cache.write_bytes(raw)
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{cache}: ", "delete it")


@pytest.mark.parametrize(("label", "raw"), BAD_JSON, ids=BAD_JSON_IDS)
def test_sweep_names_a_config_json_of_the_wrong_shape(tmp_path, label, raw, fake_runs):
    entries, submitted = fake_runs
    path = tmp_path / "runs" / entries[0].run.key / "config.json"
    path.parent.mkdir(parents=True)
    path.write_bytes(raw)
    with pytest.raises(UsageError) as exc:
        sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO())
    _one_line(exc, f"{path}: ", "delete it")
    assert not submitted
    path.write_text(json.dumps({"key": "ffffffffffff"}))  # another run's
    with pytest.raises(UsageError, match="holds the config of run 'ffffffffffff'"):
        sweep.run_experiment("rl", "smoke", tmp_path, stream=io.StringIO())


def test_read_json_object_names_the_file_and_the_problem(tmp_path):
    path = tmp_path / "x.json"
    expected = {"empty": "empty, not a JSON object", "truncated": "not valid JSON (",
                "not JSON": "not valid JSON (", "not UTF-8": "not a JSON file (not UTF-8 text)",
                "a list": "holds a list, not a JSON object",
                "a string": "holds a string, not a JSON object",
                "a number": "holds a number, not a JSON object",
                "null": "holds null, not a JSON object",
                "deeply nested": "JSON nested too deeply to read"}
    for label, raw in BAD_JSON:
        path.write_bytes(raw)
        with pytest.raises(UsageError) as exc:
            read_json_object(path, "do this")
        text = _one_line(exc, f"{path}: {expected[label]}")
        assert text.startswith(f"{path}: {expected[label]}") and text.endswith("; do this")
    with pytest.raises(UsageError, match=f"{tmp_path}: is a folder, not a JSON file"):
        read_json_object(tmp_path)
    with pytest.raises(UsageError, match="nowhere.json: no such file"):
        read_json_object(tmp_path / "nowhere.json")


def test_report_never_shows_inf_and_a_rerun_removes_what_it_no_longer_writes(tmp_path,
                                                                              references):
    # A2C scores so close to 0 that (S_R − S_A)/|S_A| overflows: undefined, not `inf %`.
    tiny = {("A2C", 1): 5e-324, ("A2C", 2): 5e-324, ("RAPL-A2C", 1): 6.0, ("RAPL-A2C", 2): 8.0}
    _sweep_folder(tmp_path, tiny)
    _sweep_folder(tmp_path, {("A2C", 1): 3.0, ("RAPL-A2C", 1): 4.0}, "coinrun",
                  "procgen/CoinRun-v0")
    written = report.write_report(tmp_path, reps=20)
    folder = tmp_path / "report"
    assert {p.name for p in folder.iterdir()} == {p.name for p in written}
    assert "fig4_coinrun.png" in {p.name for p in written}
    text = (folder / "report.md").read_text()
    assert not re.search(r"\binf\b", text, re.IGNORECASE)
    assert "undefined (n/a) where S_A is 0 or too close to 0 (MinAtar/Breakout-v1)" in text
    assert "inf" not in (folder / "fig2_rl.csv").read_text()

    # The coinrun experiment is gone: its figure and CSV go too.
    (tmp_path / "coinrun.json").unlink()
    (folder / "unrelated.txt").write_text("kept")
    written = report.write_report(tmp_path, reps=20)
    assert {p.name for p in folder.iterdir()} == {p.name for p in written} | {"unrelated.txt"}
    assert not (folder / "fig4_coinrun.png").exists()
    assert not (folder / "fig4_coinrun.csv").exists()


def test_report_of_a_folder_a_sweep_holds_proceeds_and_says_so(tmp_path, references):
    _sweep_folder(tmp_path, RL)
    holder = _hold(tmp_path)
    try:
        report.write_report(tmp_path, reps=20)
    finally:
        holder.kill()
        holder.wait()
    text = (tmp_path / "report" / "report.md").read_text()
    assert f"Written while a sweep was running in this folder (pid {holder.pid} on {HOST}" in text
    report.write_report(tmp_path, reps=20)  # the holder is dead: no note
    assert "Written while a sweep" not in (tmp_path / "report" / "report.md").read_text()


@pytest.fixture
def read_only(tmp_path) -> Path:
    """A folder nothing can be written in (root writes through file modes: /sys/fs then)."""
    folder = tmp_path / "read-only"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        (folder / "probe").touch()
    except PermissionError:
        yield folder
    else:
        (folder / "probe").unlink()
        if not Path("/sys/fs").is_dir():
            pytest.skip("no folder this user cannot write")
        yield Path("/sys/fs")
    finally:
        folder.chmod(0o755)


def test_report_into_a_file_or_a_read_only_folder_is_one_line(tmp_path, read_only,
                                                              references):
    _sweep_folder(tmp_path, RL)
    (tmp_path / "report").write_text("not a folder")
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{tmp_path / 'report'}: a file, where the report's folder goes")
    (tmp_path / "report").unlink()
    (tmp_path / "report").symlink_to(read_only)
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path, reps=20)
    _one_line(exc, f"{tmp_path / 'report'}: cannot write the report there (")
    with pytest.raises(UsageError) as exc:
        report.write_report(tmp_path / "rl.json")
    _one_line(exc, "rl.json: a file, not a sweep folder")


# -- the command line: --out mistakes and nonsense options, one line each --------------------------

def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize(("argv", "message"), [
    (["--out", "somefile/sweep"], "--out somefile/sweep: {tmp}/somefile is a file, not a folder"),
    (["--out", "somefile"], "--out {tmp}/somefile is a file, not a folder"),
    (["--out", "{ro}/sweep"], "--out {ro}/sweep: cannot make the folder"),
    (["--out", "{ro}"], "--out {ro}: cannot make the folder"),
    (["--out", ""], "--out needs a folder"),
    (["--out", "X", "--cpus-per-run", "-3"], "--cpus-per-run needs to be ≥ 1, actual value: -3"),
    (["--out", "X", "--cpus-per-run", "0"], "--cpus-per-run needs to be ≥ 1, actual value: 0"),
    (["--out", "X", "--backend", "ray", "--address", "127.0.0.1:{port}"],
     "--address 127.0.0.1:{port}: cannot connect (Connection refused); is the Ray head running"),
    (["--out", "X", "--backend", "ray", "--address", "headnode"],
     "--address needs HOST:PORT"),
    (["--out", "X", "--envs", "MinAtar/Pong-v1"],
     "--envs MinAtar/Pong-v1 is not a game of the rl experiment at the smoke budget (its "
     "games: MinAtar/Breakout-v1)"),
    (["--out", "X", "--envs", "MiniQbert-v0"],
     "--envs MiniQbert-v0 is not a game of the rl experiment at the smoke budget"),
    (["--out", "X", "--seeds", "2"], "--seeds 2 is outside the smoke budget's seeds 1..1"),
])
def test_cli_refuses_bad_out_and_options_in_one_line_before_writing(tmp_path, read_only, argv,
                                                                    message):
    (tmp_path / "somefile").write_text("a file")
    fill = {"tmp": tmp_path, "ro": read_only, "port": _closed_port()}
    argv = [a.format(**fill) for a in argv]
    start = time.time()
    proc = _cli(["run", "rl", "--budget", "smoke", *argv], tmp_path)
    _one_line_error(proc, message.format(**fill))
    assert time.time() - start < 30  # an unreachable Ray head does not hang
    assert not (tmp_path / "X").exists()
    assert (tmp_path / "somefile").read_text() == "a file"


def test_cli_all_runs_the_experiments_that_have_the_games_asked_for(tmp_path):
    assert sweep.plan("all", "smoke", envs=["MinAtar/Freeway-v1"]) == [
        ("ablation", ["MinAtar/Freeway-v1"])]
    assert [n for n, _ in sweep.plan("all", "cpu", envs=["MiniQbert-v0", BREAKOUT])] == [
        "imitation", "rl", "curves", "scalability", "ablation", "diagnosis"]
    assert sweep.plan("all", "cpu", envs=["procgen/CoinRun-v0"]) == [
        ("coinrun", ["procgen/CoinRun-v0"])]
    assert [n for n, e in sweep.plan("all", "cpu")] == [  # no tuning at cpu
        n for n in registry.EXPERIMENTS if n not in ("tune", "equal-frames")]
    proc = _cli(["run", "all", "--budget", "smoke", "--out", "X", "--envs", "Pong"], tmp_path)
    _one_line_error(proc, "--envs Pong is not a game of any experiment at the smoke budget "
                          "(their games: MinAtar/Breakout-v1, MinAtar/Freeway-v1, MiniQbert-v0, "
                          "procgen/CoinRun-v0)")
    assert not (tmp_path / "X").exists()


def test_cli_report_errors_name_the_file(tmp_path):
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "rl.json").write_bytes(b"[" * 100_000 + b"]" * 100_000)
    _one_line_error(_cli(["report", "sweep"], tmp_path),
                    "sweep/rl.json: JSON nested too deeply to read")
    (tmp_path / "sweep" / "rl.json").write_text("null")
    _one_line_error(_cli(["report", "sweep"], tmp_path),
                    "sweep/rl.json: holds null, not a JSON object")
    _one_line_error(_cli(["report", "sweep/rl.json"], tmp_path),
                    "sweep/rl.json: a file, not a sweep folder")


def test_snapshot_keeps_only_sound_results_and_names_a_bad_manifest(tmp_path):
    snapshot = Path(__file__).resolve().parents[1] / "bench" / "snapshot_experiments.py"
    sweep_dir, dest = tmp_path / "sweep", tmp_path / "dest"
    keys = _sweep_folder(sweep_dir, {("A2C", 1): 3.0, ("RAPL-A2C", 1): 4.0}, "coinrun",
                         "procgen/CoinRun-v0")
    corrupt = sweep_dir / "runs" / keys["RAPL-A2C", 1] / "result.json"
    corrupt.write_text('{"eval": {"mean_ret')
    proc = subprocess.run([sys.executable, str(snapshot), str(sweep_dir), str(dest)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "coinrun      1/2 runs finished" in proc.stdout
    assert {p.parent.name for p in dest.glob("runs/*/result.json")} == {keys["A2C", 1]}
    (sweep_dir / "coinrun.json").write_text("[]")
    proc = subprocess.run([sys.executable, str(snapshot), str(sweep_dir), str(dest)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    assert proc.stderr == (f"snapshot_experiments.py: error: {sweep_dir / 'coinrun.json'}: "
                           "holds a list, not a JSON object\n")
