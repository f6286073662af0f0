"""The fair protocol (issue 47): independent env seeds, rollouts sized in primitive steps, the
tune experiment and the flags its choices give the other runs, the fair budgets' runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from one_line import assert_one_line_error
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from routine_gym.experiments.derived import (
    choose_point,
    derived_flags,
    grid_scores,
    rollout_for_updates,
)
from routine_gym.experiments.registry import build
from routine_gym.experiments.specs import BUDGETS, TUNE_GRIDS
from routine_gym.plumbing.seeds import demo_seed, eval_seed, stride_checks, train_seed

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
A2C = str(REPO / "algos" / "rapl_a2c.py")


def user(*words, cwd, timeout=300):
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    words = [str(w) for w in words]
    if words[0] in ("routine-gym", "python"):
        words[0] = str(BIN / words[0])
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


# -- env seeds ---------------------------------------------------------------------------------

def _seeds(seed, stride, envs=16, episodes=30):
    train = {train_seed(seed, stride) + i for i in range(envs)}
    evals = {eval_seed(seed, stride) + k for k in range(episodes)}
    demos = {demo_seed(seed, stride) + k for k in range(episodes)}
    return train, evals, demos


def test_stride_one_keeps_the_old_seeds_and_shares_them_across_experiment_seeds():
    # Seeds 1, 2, 3 with 16 envs: 2..16 are in both seed 1's and seed 2's training set.
    assert train_seed(1) == 1 and eval_seed(1) == 10_001 and demo_seed(1) == 20_001
    assert train_seed(1, 1, 480) == 481  # a resumed leg: seed + global step, as before
    assert len(_seeds(1, 1)[0] & _seeds(2, 1)[0]) == 15
    assert len(_seeds(1, 1)[0] & _seeds(3, 1)[0]) == 14
    assert len(_seeds(1, 1)[1] & _seeds(2, 1)[1]) == 29


def test_a_stride_gives_every_seed_its_own_block():
    runs = [*range(1, 6), 101, 102]  # the fair budget's evaluation and tuning seeds
    blocks = {s: set().union(*_seeds(s, 1000)) for s in runs}
    for s in runs:
        train, evals, demos = _seeds(s, 1000)
        assert not (train & evals or train & demos or evals & demos)
        assert min(blocks[s]) == s * 1000 and max(blocks[s]) < (s + 1) * 1000
        for other in runs:
            if other != s:
                assert not blocks[s] & blocks[other]
    # A resumed leg's seeds lie above every block.
    assert 2**31 <= train_seed(5, 1000, 200_000) < 2**32 - 2**16
    assert train_seed(5, 1000, 200_000) != train_seed(5, 1000, 400_000)


def test_stride_checks_by_hand():
    class Args:
        seed, seed_stride, num_envs, eval_episodes, demo_episodes = 5, 1000, 16, 30, 10

    assert all(holds for _, holds, _ in stride_checks(Args))
    Args.num_envs = 501  # more than half a block
    assert [needs for _, holds, needs in stride_checks(Args) if not holds] == [
        "≥ 2 × --num-envs (1002): the training envs take half of a run's seed block"]
    Args.num_envs, Args.seed = 16, 2_200_000  # (seed + 1) · stride past 2^31
    assert not all(holds for _, holds, _ in stride_checks(Args))


@pytest.mark.parametrize("flags, message", [
    (["--seed-stride", "2"], "--seed-stride needs to be 1 (the old seeds) or ≥ 4"),
    (["--seed-stride", "16"], "--seed-stride needs to be ≥ 2 × --num-envs (32)"),
    (["--seed-stride", "100", "--eval-episodes", "30"],
     "--seed-stride needs to be ≥ 4 × --eval-episodes (120)"),
    (["--seed-stride", "0"], "--seed-stride needs to be ≥ 1"),
    (["--rollout-unit", "steps", "--authors"], "--rollout-unit needs to be decisions with"),
    (["--rollout-unit", "steps", "--budget-unit", "decisions"],
     "--rollout-unit needs to be decisions with --budget-unit decisions"),
])
def test_bad_seed_stride_and_rollout_unit_are_one_line_errors(tmp_path, flags, message):
    proc = user("python", A2C, "--env-id", "MinAtar/Breakout-v1", "--total-timesteps", "100",
                *flags, cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def _scalars(run_dir: Path) -> dict[str, list]:
    (folder,) = [p for p in (run_dir).iterdir() if p.is_dir()]
    ea = EventAccumulator(str(folder))
    ea.Reload()
    return {tag: ea.Scalars(tag) for tag in ea.Tags()["scalars"]}


def test_a_seed_stride_run_evaluates_on_its_block(tmp_path):
    proc = user("python", A2C, "--env-id", "MinAtar/Breakout-v1", "--mode", "a2c",
                "--num-envs", "4", "--total-timesteps", "400", "--eval-episodes", "2",
                "--seed", "3", "--seed-stride", "1000", "--torch-threads", "1", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (evaluation,) = (tmp_path / "runs").glob("*/eval.json")
    assert json.loads(evaluation.read_text())["seed"] == 3500


# -- rollouts sized in primitive steps ---------------------------------------------------------

def test_rollouts_sized_in_primitive_steps_give_rapl_the_updates_of_a2c(tmp_path):
    """4 envs × 5 steps: an A2C update every 20 primitive steps, so 2,000 steps are 100
    updates; RAPL with --rollout-unit steps makes 100 too (± the last rollout), with fewer
    decisions than A2C's 2,000 (its routines run several steps a decision), while plain RAPL
    makes one update per 20 decisions, fewer than 100."""
    common = ["--env-id", "MinAtar/Breakout-v1", "--num-envs", "4", "--total-timesteps",
              "2000", "--eval-episodes", "0", "--torch-threads", "1", "--seed", "2"]
    counts = {}
    for name, flags in (("a2c", ["--mode", "a2c"]),
                        ("rapl", ["--mode", "rapl"]),
                        ("rapl-steps", ["--mode", "rapl", "--rollout-unit", "steps"])):
        folder = tmp_path / name
        folder.mkdir()
        proc = user("python", A2C, *common, *flags, cwd=folder)
        assert proc.returncode == 0, proc.stderr[-2000:]
        scalars = _scalars(folder / "runs")
        counts[name] = {tag.split("/")[1]: scalars[tag][-1].value
                        for tag in ("counters/updates", "counters/decisions")}
        counts[name]["steps"] = scalars["counters/updates"][-1].step
    assert counts["a2c"]["updates"] == 100
    assert abs(counts["rapl-steps"]["updates"] - counts["rapl-steps"]["steps"] / 20) <= 1
    assert counts["rapl-steps"]["decisions"] < counts["a2c"]["decisions"]
    assert counts["rapl"]["updates"] < 100
    assert counts["rapl"]["updates"] == counts["rapl"]["decisions"] / 20


# -- derived flags -----------------------------------------------------------------------------

def test_the_tuned_point_by_hand():
    points = [((("learning-rate", 7e-4), ("anneal-lr", True)), [3.0, 5.0]),   # mean 4
              ((("learning-rate", 7e-4), ("anneal-lr", False)), [10.0, 6.0]),  # mean 8
              ((("learning-rate", 3.5e-4), ("anneal-lr", True)), [8.0, 8.0])]  # mean 8
    assert grid_scores(points) == [4.0, 8.0, 8.0]
    assert choose_point(points) == 1  # a tie keeps the first in grid order
    with pytest.raises(ValueError, match="no grid point"):
        choose_point([((), [])])


def test_rollout_for_updates_by_hand():
    # RAPL at 1.28 steps per decision runs 5 × 1.28 = 6.4 primitive steps per env a rollout.
    assert rollout_for_updates(5, [1.2, 1.36]) == 6
    assert rollout_for_updates(5, [3.87]) == 19
    with pytest.raises(ValueError):
        rollout_for_updates(5, [0.5])


def _finished(runs: Path, key: str, score: float, steps: int = 0, decisions: int = 0) -> None:
    folder = runs / key
    folder.mkdir(parents=True)
    result = {"key": key, "eval": {"mean_return": score}}
    if decisions:
        result["counters"] = {"primitive_steps": steps, "decisions": decisions}
    (folder / "result.json").write_text(json.dumps(result))


def test_derived_flags_read_the_finished_runs(tmp_path):
    _finished(tmp_path, "a1", 2.0)
    _finished(tmp_path, "b1", 9.0)
    _finished(tmp_path, "r1", 0.0, steps=1300, decisions=1000)
    _finished(tmp_path, "r2", 0.0, steps=1500, decisions=1000)
    derived = [["tuned", [[[["learning-rate", 0.0007], ["anneal-lr", True]], ["a1"]],
                          [[["learning-rate", 0.0014], ["anneal-lr", False]], ["b1"]]]],
               ["updates-of", [5, ["r1", "r2"]]]]
    assert derived_flags(derived, tmp_path) == {"learning-rate": 0.0014, "anneal-lr": False,
                                                "num-steps": 7}
    with pytest.raises(Exception, match="has not finished"):
        derived_flags([["updates-of", [5, ["missing"]]]], tmp_path)


# -- the fair budgets --------------------------------------------------------------------------

def test_the_fair_budget_tunes_every_method_on_its_own_seeds():
    tune = build("tune", "fair")
    assert len(tune) == 6 * 5 * 10 * 2  # methods × games × grid points × tuning seeds
    assert {dict(e.run.flags)["seed"] for e in tune} == {101, 102}
    lrs = {e.run.script: set() for e in tune}
    for e in tune:
        lrs[e.run.script].add((dict(e.run.flags)["learning-rate"], dict(e.run.flags)["anneal-lr"]))
    both = (True, False)
    assert lrs["rapl_a2c"] == {(lr, a) for lr in (7e-4, 3.5e-4, 1.4e-3, 2.8e-3, 5.6e-3)
                                 for a in both}
    assert lrs["rapl_ppo"] == {(lr, a) for lr in (5e-4, 2.5e-4, 1e-3, 2e-3, 4e-3)
                                 for a in both}
    assert len(TUNE_GRIDS["a2c"]) == len(TUNE_GRIDS["ppo"]) == 10
    rl = [e for e in build("rl", "fair") if e.role == "main"]
    assert {e.method for e in rl} == {"A2C", "RAPL-A2C", "PPO", "RAPL-PPO", "MacroAction-PPO"}
    for e in rl:
        flags = dict(e.run.flags)
        assert flags["seed"] in range(1, 6) and flags["seed-stride"] == 1000
        assert "learning-rate" not in flags  # decided by the tune runs, which it needs
        (rule, params), = e.run.derived
        assert rule == "tuned" and len(params) == 10
        assert set(e.run.needs) >= {k for _, keys in params for k in keys}
    assert BUDGETS["fair"].seeds >= 5 and BUDGETS["fair-long"].seeds >= 5


def test_a_sweep_of_one_seed_trains_the_runs_of_other_seeds_it_needs():
    every = {e.run.key: e for e in build("diagnosis", "smoke-fair")}
    chosen = build("diagnosis", "smoke-fair", seeds=[1])
    keys = {e.run.key for e in chosen}
    assert {k for e in chosen for k in e.run.needs} <= keys
    # beyond seed 1 and the tune runs: RAPL-A2C's seed-2 run alone (A2C at RAPL's updates)
    others = [every[k] for k in keys if every[k].role == "main" and every[k].seed != 1]
    assert [(e.method, e.seed, e.variant) for e in others] == [("RAPL-A2C", 2, {})]


def test_the_fair_diagnosis_arms_each_change_one_thing():
    entries = [e for e in build("diagnosis", "fair", envs=["MinAtar/Freeway-v1"])
               if e.role == "main" and e.seed == 1]
    arms = {(e.method, e.variant.get("diagnosis")): e for e in entries}
    assert set(arms) == {("A2C", None), ("RAPL-A2C", None), ("A2C", "rapl-updates"),
                         ("RAPL-A2C", "a2c-updates"), ("RAPL-A2C", "authors"),
                         ("A2C", "constant-lr"), ("MacroAction", "a2c-updates")}
    a2c, fewer = arms["A2C", None].run, arms["A2C", "rapl-updates"].run
    assert dict(fewer.flags) == dict(a2c.flags)  # the same flags: only the rollout differs
    assert [r for r, _ in fewer.derived] == ["tuned", "updates-of"]
    rapl_keys = {e.run.key for e in build("diagnosis", "fair", envs=["MinAtar/Freeway-v1"])
                 if e.method == "RAPL-A2C" and not e.variant and e.role == "main"}
    assert set(fewer.derived[1][1][1]) == rapl_keys and len(rapl_keys) == 5
    more = arms["RAPL-A2C", "a2c-updates"].run
    assert dict(more.flags) == {**dict(arms["RAPL-A2C", None].run.flags),
                                "rollout-unit": "steps"}
    # The preset's constant lr on both sides: each arm's grid holds constant points only.
    for key in (("RAPL-A2C", "authors"), ("A2C", "constant-lr")):
        (_, params), = arms[key].run.derived
        assert {dict(point)["anneal-lr"] for point, _ in params} == {False}


def test_the_first_protocols_runs_keep_their_keys_and_demos():
    manifest = json.loads((REPO / "bench/results/experiments/cpu/rl.json").read_text())
    committed = {r["key"] for r in manifest["runs"]}
    built = {e.run.key for e in build("rl", "cpu")}
    assert built == committed
    for e in build("rl", "cpu"):
        if e.env_id.startswith("MinAtar/") and dict(e.run.flags)["mode"] not in ("a2c", "ppo"):
            assert dict(e.run.pinned) == {
                "demo": f"@demos/first/{e.env_id.replace('/', '-')}.npz"}


def test_a_fair_sweep_tunes_then_runs_the_diagnosis_and_equal_frames_and_reports_them(tmp_path):
    """As a user: the smoke-fair tune experiment, then its diagnosis on one seed (whose runs
    learn with the choices), then equal-frames on the same seed (both families' arms and the
    A2C family's leave-one-out arms, reusing the runs the others finished), then the report."""
    out = tmp_path / "sweep"
    for name, seeds in (("tune", ()), ("diagnosis", ("--seeds", "1"))):  # one seed: seconds
        proc = user("routine-gym", "experiment", "run", name, "--budget", "smoke-fair",
                    "--out", out, "--jobs", "2", *seeds, cwd=tmp_path, timeout=600)
        assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-2000:])
        assert "0 failed" in proc.stdout + proc.stderr
    assert "6 finished before" in proc.stdout + proc.stderr  # the tune runs, trained once
    tuned = 0
    for config in (out / "runs").glob("*/config.json"):
        config = json.loads(config.read_text())
        if config.get("derived"):
            (folder,) = [p for p in (out / "runs" / config["key"]).iterdir() if p.is_dir()]
            ea = EventAccumulator(str(folder))
            ea.Reload()
            (text,) = ea.Tensors("hyperparameters/text_summary")
            table = text.tensor_proto.string_val[0].decode()
            assert "|learning_rate|0.0007|" in table  # the smoke grid's learning rate
            assert "|anneal_lr|True|" in table or "|anneal_lr|False|" in table
            tuned += 1
    # every main run of the 7 arms on seed 1 learned as tuned, and RAPL-A2C's on seed 2: A2C
    # at RAPL's updates is sized by RAPL-A2C's steps per decision over both seeds
    assert tuned == 7 + 1
    finished = {p.parent.name for p in (out / "runs").glob("*/result.json")}

    proc = user("routine-gym", "experiment", "run", "equal-frames", "--budget", "smoke-fair",
                "--out", out, "--jobs", "2", "--seeds", "1", cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-2000:])
    printed = proc.stdout + proc.stderr
    # 4 tuned methods × 2 grid points, then 18 arms: 14 of both families, 4 leave one out;
    # the runs the diagnosis made already (A2C's and RAPL-A2C's tune runs, their seed-1 runs,
    # RAPL at A2C's updates, which is + equal updates) are not trained again
    assert "runs 26/26 done, 0 running, 0 failed" in printed
    keys = {r["key"] for r in json.loads((out / "equal-frames.json").read_text())["runs"]
            if r["seed"] == 1}  # the manifest holds both seeds; the tune runs are labelled 1
    assert len(keys) == 26 and len(keys & finished) == 7 and "7 finished before" in printed
    configs = [json.loads((out / "runs" / k / "config.json").read_text()) for k in keys]
    # the A2C family's arm without interruption: the other three mechanisms, no stop rule,
    # and RAPL-A2C's tuned settings (derived from its tune runs)
    (no_stop,) = [c for c in configs if c["script"] == "rapl_a2c"
                  and c["flags"].get("intra-coef") == 1.0 and "interrupt" not in c["flags"]
                  and c["flags"].get("rollout-unit") == "steps"
                  and c["flags"].get("routine-logit") == "first-action"]
    assert no_stop["flags"]["seed"] == 1 and no_stop["derived"][0][0] == "tuned"

    proc = user("routine-gym", "experiment", "report", out, cwd=tmp_path, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = (out / "report" / "report.md").read_text()
    assert "## Tuning" in report and "**chosen**" in report
    assert "fewer updates alone" in report and "more updates alone" in report
    assert "the authors' code at the same lr schedule" in report
    assert "over 100 episodes" in report  # the fair budgets' random references
    assert "## Demos" in report and "`demos/MinAtar-Breakout-v1.npz` | current |" in report
    rows = (out / "report" / "tune.csv").read_text().splitlines()
    # the tune experiment's own: A2C, RAPL-A2C, MacroAction × 2 grid points (the PPO family's
    # tune runs, equal-frames' at this budget, are in its manifest, not tune's)
    assert len(rows) == 1 + 3 * 2
    assert "#### Leave one out: which mechanisms carry RAPL-A2C + all" in report
    assert "| RAPL-A2C + all but interruption | Breakout | 1 |" in report
    for name in ("equal_frames.png", "equal_frames_curves.png", "equal_frames_leave_one_out.png",
                 "equal_frames_a2c_leave_one_out.csv", "equal_frames_ppo_counters.csv"):
        assert (out / "report" / name).stat().st_size > 0, name
