"""PPO, RAPL-PPO and MacroAction-PPO in the rl experiment (issue 29, item 3): their runs at the
budgets that opt in (`rl_ppo`: smoke and cpu), built like the A2C runs, flags `rapl_ppo.py`
takes; every run that was there before keeps its key and config at every budget; `long`'s
45 runs are exactly what the sweep in progress was started with; and a sweep continued from the
committed cpu snapshot runs the PPO runs alone. (The report: `tests/test_report.py`; a smoke
sweep of them: `tests/test_experiments.py`.)"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import shutil
from collections import Counter
from pathlib import Path

import pytest
from script_loader import load_script

from routine_gym.experiments import registry, sweep
from routine_gym.experiments.paper import rl
from routine_gym.experiments.registry import EXPERIMENTS, available, build, count_runs
from routine_gym.experiments.specs import BUDGETS, MINATAR, Builder

REPO = Path(__file__).resolve().parents[1]
SNAPSHOT = REPO / "bench" / "results" / "experiments" / "cpu"
PPO = ("PPO", "RAPL-PPO", "MacroAction-PPO")
MODES = {"PPO": "ppo", "RAPL-PPO": "rapl", "MacroAction-PPO": "macro"}
#: SHA-256 of `_rows(build("rl", "long"))` at 558bf4b, the commit before the PPO runs: the
#: manifest and config of each of the 45 runs the long sweep in progress was started with.
LONG_DIGEST = "91de49ebfa31b633b732ee9c7989440e4bc52bb0fecf249d04624e4c1dd6c4ca"


def _config(entry) -> dict:
    """A run's config as the committed sweeps wrote it: without `pinned`, the first demo set's
    file the command line now names where the default demo changed (its key is unchanged)."""
    return {k: v for k, v in entry.run.config().items() if k != "pinned"}


def _rows(entries) -> list[list[str]]:
    """Each entry's manifest row and run config as JSON, sorted: what a sweep folder holds."""
    return sorted([json.dumps(e.manifest(), sort_keys=True),
                   json.dumps(_config(e), sort_keys=True)] for e in entries)


def test_run_counts_per_budget():
    assert [b for b in BUDGETS if BUDGETS[b].rl_ppo] == ["smoke", "cpu", "fair"]
    # smoke: Breakout, 1 seed × (A2C, RAPL-A2C + 3 PPO); cpu: 6 games × 3 seeds × 5 methods;
    # paper and long: as before (PPO is not there).
    assert count_runs("rl", "smoke") == (5, 5_000)
    assert count_runs("rl", "cpu") == (90, 90 * 10**6)
    assert count_runs("rl", "paper") == (325, 3_250_000_000)
    assert count_runs("rl", "long") == (45, 450_000_000)
    cpu = [e for e in build("rl", "cpu") if e.method in PPO]
    assert len(cpu) == 54 and Counter(e.method for e in cpu) == {m: 18 for m in PPO}
    assert {e.env_id for e in cpu} == {*MINATAR, "MiniQbert-v0"}
    assert {e.seed for e in cpu} == {1, 2, 3} and {e.role for e in cpu} == {"main"}
    assert not any(e.method in PPO for b in ("paper", "long") for e in build("rl", b))


def test_ppo_runs_are_rapl_ppo_with_the_sweeps_flags():
    runs = {(e.method, e.env_id, e.seed): e for e in build("rl", "cpu")}
    for method in PPO:
        entry = runs[(method, "MinAtar/Breakout-v1", 2)]
        assert entry.run.script == "rapl_ppo" and entry.variant == {} and entry.run.needs == ()
        # MinAtar's demos ship: no --demo (the script's default), no expert; the env family's
        # PPO defaults (64 envs): no --num-envs at cpu. RAPL-PPO names its default
        # --prim-epochs 1, so its runs from before the flag (every epoch) are not these.
        assert dict(entry.run.flags) == {
            "env-id": "MinAtar/Breakout-v1", "seed": 2, "total-timesteps": 10**6,
            "eval-episodes": 30, "mode": MODES[method], "checkpoint-every": 200_000,
            **({"prim-epochs": 1} if method == "RAPL-PPO" else {})}
        qbert = dict(runs[(method, "MiniQbert-v0", 1)].run.flags)
        assert qbert["reward-scale"] == 0.01  # as every MiniQbert run of the experiment
    smoke = {e.method: dict(e.run.flags) for e in build("rl", "smoke")}
    for method in PPO:
        assert smoke[method]["num-envs"] == 4 == smoke["A2C"]["num-envs"]
        assert smoke[method]["total-timesteps"] == 1_000


def test_rapl_ppo_takes_every_flag_the_sweep_gives_it():
    fields = {f.name for f in dataclasses.fields(load_script("rapl_ppo").Args)}
    given = {flag for b in ("smoke", "cpu") for e in build("rl", b) if e.method in PPO
             for flag, _ in e.run.flags}
    # The sweep's own (backends.command) and a resumed run's.
    given |= {"run-dir", "torch-threads", "cuda", "resume", "track", "wandb-project-name",
              "wandb-entity", "log-every"}
    assert {flag.replace("-", "_") for flag in given} <= fields


def test_a_game_without_a_shipped_demo_mines_rapl_a2cs_expert_demo():
    b = Builder(dataclasses.replace(BUDGETS["cpu"], rl_games=("ALE/Amidar-v5",), seeds=1))
    rl.add_runs(b)
    entries = {e.method: e for e in b.entries.values()}
    expert = entries.pop("A2C expert")
    assert sorted(entries) == ["A2C", "MacroAction-PPO", "PPO", "RAPL-A2C", "RAPL-PPO"]
    demo = f"@run:{expert.run.key}/demo.npz"
    for method in ("RAPL-A2C", "RAPL-PPO", "MacroAction-PPO"):
        assert entries[method].run.needs == (expert.run.key,), method
        assert dict(entries[method].run.flags)["demo"] == demo, method
    for method in ("A2C", "PPO"):  # no routines: no demo to wait for
        assert entries[method].run.needs == () and "demo" not in dict(entries[method].run.flags)


@pytest.mark.parametrize("budget", ["smoke", "cpu", "paper", "long"])
def test_every_run_from_before_keeps_its_key_and_config(budget, monkeypatch):
    names = [n for n in EXPERIMENTS if registry.available(n, budget)]
    sizes = BUDGETS[budget]
    now = {n: _rows(build(n, budget)) for n in names}
    added = {n: [e for e in build(n, budget) if e.method in PPO] for n in names}
    monkeypatch.setitem(BUDGETS, budget, dataclasses.replace(sizes, rl_ppo=False))
    for n in names:
        before = _rows(build(n, budget))
        ppo = _rows(added[n])
        assert sorted(before + ppo) == now[n], n  # the old runs as they were, plus PPO's
        assert not {json.loads(m)["key"] for m, _ in before} & {e.run.key for e in added[n]}
    assert len(added["rl"]) == (3 * sizes.seeds * len(sizes.rl_games) if sizes.rl_ppo else 0)
    assert not any(added[n] for n in names if n != "rl")


def test_the_long_budgets_runs_are_exactly_those_of_the_sweep_in_progress():
    rows = _rows(build("rl", "long"))
    assert len(rows) == 45
    assert hashlib.sha256(json.dumps(rows).encode()).hexdigest() == LONG_DIGEST


def test_the_committed_cpu_snapshot_keeps_its_runs_and_a_sweep_without_ppo_runs_ppo_alone(
        tmp_path, monkeypatch):
    for name in (n for n in EXPERIMENTS if available(n, "cpu")):
        built = {e.run.key: e for e in build(name, "cpu")}
        for row in json.loads((SNAPSHOT / f"{name}.json").read_text())["runs"]:
            assert row == built[row["key"]].manifest(), (name, row["key"])
            config = json.loads((SNAPSHOT / "runs" / row["key"] / "config.json").read_text())
            assert config == json.loads(json.dumps(_config(built[row["key"]]))), (
                name, row["key"])  # as written to config.json (tuples are lists there)
    # The snapshot holds every rl run, PPO's included (they ran on 2026-12-04).
    rl_keys = [r["key"] for r in json.loads((SNAPSHOT / "rl.json").read_text())["runs"]]
    assert len(rl_keys) == 90
    assert all((SNAPSHOT / "runs" / key / "result.json").is_file() for key in rl_keys)
    # A sweep of rl continued from a copy of the snapshot's runs from before PPO (the folder
    # of a user who swept before the PPO rows came) starts the PPO runs only.
    shutil.copy(SNAPSHOT / "rl.json", tmp_path / "rl.json")
    ppo_keys = {e.run.key for e in build("rl", "cpu") if e.method in PPO}
    old = [key for key in rl_keys if key not in ppo_keys]
    for key in old:
        shutil.copytree(SNAPSHOT / "runs" / key, tmp_path / "runs" / key)
    submitted: list[dict] = []
    monkeypatch.setattr(sweep, "LocalBackend", lambda jobs: _Finishes(submitted))
    stream = io.StringIO()
    summary = sweep.run_experiment("rl", "cpu", tmp_path, jobs=2, stream=stream)
    assert summary.ok and sorted(summary.skipped) == sorted(old) and len(old) == 36
    assert "[rl] budget cpu: 90 runs, 36 finished before, 54 to run" in stream.getvalue()
    ppo = {e.run.key: e for e in build("rl", "cpu") if e.method in PPO}
    assert sorted(c["key"] for c in submitted) == sorted(ppo)
    assert {c["script"] for c in submitted} == {"rapl_ppo"}
    manifest = json.loads((tmp_path / "rl.json").read_text())
    assert manifest["version"] == 2 and len(manifest["runs"]) == 90


def test_a_sweep_with_rapl_ppos_runs_from_before_prim_epochs_reruns_them_and_lists_them_once(
        tmp_path, monkeypatch):
    # The folder of a user who swept rl before 2026-12-05: RAPL-PPO's runs had the same flags
    # but --prim-epochs (every epoch, the script's only behaviour then), so other keys.
    built = build("rl", "cpu")
    before = {e.run.key: dataclasses.replace(
        e.run, flags=tuple(f for f in e.run.flags if f[0] != "prim-epochs")).key
        for e in built if e.method == "RAPL-PPO"}
    assert len(before) == 18 and not set(before) & set(before.values())
    manifest = json.loads((SNAPSHOT / "rl.json").read_text())
    for row in manifest["runs"]:  # every run finished
        shutil.copytree(SNAPSHOT / "runs" / row["key"],
                        tmp_path / "runs" / before.get(row["key"], row["key"]))
        row["key"] = before.get(row["key"], row["key"])
    (tmp_path / "rl.json").write_text(json.dumps(manifest))
    submitted: list[dict] = []
    monkeypatch.setattr(sweep, "LocalBackend", lambda jobs: _Finishes(submitted))
    stream = io.StringIO()
    assert sweep.run_experiment("rl", "cpu", tmp_path, jobs=2, stream=stream).ok
    assert "[rl] budget cpu: 90 runs, 72 finished before, 18 to run" in stream.getvalue()
    assert sorted(c["key"] for c in submitted) == sorted(before)
    assert all(c["flags"]["prim-epochs"] == 1 for c in submitted)
    # The old runs are no longer listed (their folders stay, unlisted); nothing else moved.
    rows = json.loads((tmp_path / "rl.json").read_text())["runs"]
    assert sorted(r["key"] for r in rows) == sorted(e.run.key for e in built)
    assert (tmp_path / "runs" / next(iter(before.values())) / "result.json").is_file()


class _Finishes:
    """A backend that runs nothing: it records each run's config and reports it finished."""

    def __init__(self, submitted: list[dict]) -> None:
        self.submitted = submitted

    def submit(self, config, runs, cuda):
        self.submitted.append(config)
        return config["key"]

    def wait(self, handles, timeout):
        return [(h, {"key": h}) for h in handles]

    def close(self):
        pass
