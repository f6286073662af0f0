"""Issue 46 case 11: a flag a run would not read is refused, not silently ignored; a resumed
run's `eval.json` keeps its alignment and demo score; `--track` settings that would fail every
run are refused before the first one."""

from __future__ import annotations

import dataclasses
import json
import subprocess

import pytest
from one_line import assert_one_line_error
from script_loader import load_script
from test_as_a_user import BIN, REPO, ok, user

from routine_gym.errors import UsageError
from routine_gym.plumbing.arguments import check_args
from routine_gym.plumbing.loading import MINING_FLAGS

DEMO = REPO / "demos" / "MiniQbert-v0.npz"
#: A value of each routine flag other than its default (an int, float, str or path).
OTHER = {"demo": str(DEMO), "routine_library": "lib.json", "num_routines": 5,
         "length_weight": 0.5, "alpha": 1, "proposer": "bpe", "min_routine_length": 3,
         "max_routine_length": 32, "selection": "authors"}
#: Each script's runs without routines, and the routine flags each reads for more than mining.
NO_ROUTINES = {"rapl_a2c": ({"mode": "a2c"}, "--mode a2c"),
               "rapl_ppo": ({"mode": "ppo"}, "--mode ppo"),
               "rapl_sqil": ({"num_routines": 0}, "--num-routines 0")}


def _refusal(name: str, **fields) -> str | None:
    module = load_script(name)
    args = module.Args(env_id="MiniQbert-v0", **fields)
    try:
        check_args(args, module.extra_checks)
    except UsageError as exc:
        return str(exc)
    return None


@pytest.mark.parametrize("name", list(NO_ROUTINES))
def test_every_routine_flag_is_refused_where_the_run_has_no_routines(name):
    setting, cause = NO_ROUTINES[name]
    fields = {f.name for f in dataclasses.fields(load_script(name).Args)}
    assert _refusal(name, **setting) is None
    checked = 0
    for flag, value in OTHER.items():
        if flag not in fields or flag in setting or (name == "rapl_sqil" and flag == "demo"):
            continue  # SQIL's demo is its demo buffer: read with or without routines
        message = _refusal(name, **setting, **{flag: value})
        assert message is not None and message.startswith(f"--{flag.replace('_', '-')} "), flag
        assert f"with {cause}, which uses no routines, actual value: {value}" in message
        checked += 1
    read = set(setting) | ({"demo"} if name == "rapl_sqil" else set())
    assert checked == len((fields & OTHER.keys()) - read) >= 5


@pytest.mark.parametrize(("name", "mode"), [("rapl_a2c", "a2c"), ("rapl_a2c", "macro"),
                                          ("rapl_ppo", "ppo"), ("rapl_ppo", "macro")])
def test_the_primitive_value_loss_coefficient_is_refused_outside_rapl(name, mode):
    # λ_prim weighs the value loss of the states inside routines: only RAPL trains them.
    assert _refusal(name, mode="rapl", prim_coef=0.5) is None
    assert _refusal(name, mode=mode, prim_coef=0.5) == (
        "--prim-coef needs to be 1.0 unless --mode rapl, actual value: 0.5")


@pytest.mark.parametrize("name", ["rapl_a2c", "rapl_ppo", "rapl_sqil"])
def test_mining_flags_are_refused_with_a_routine_library(name):
    fields = {f.name for f in dataclasses.fields(load_script(name).Args)}
    assert _refusal(name, routine_library="lib.json") is None
    for flag in [*MINING_FLAGS, "demo"]:
        if flag not in fields:
            continue
        message = _refusal(name, routine_library="lib.json", **{flag: OTHER[flag]})
        if flag == "demo" and name == "rapl_sqil":
            assert message is None  # the demo buffer
            continue
        assert message is not None and "with --routine-library, whose routines are not mined" \
            in message, (flag, message)
    # The defaults and the routines the library gives: nothing refused.
    assert _refusal(name, routine_library="lib.json", num_routines=2) is None


@pytest.mark.parametrize(("words", "message"), [
    (["rapl_ppo", "--mode", "ppo", "--demo", str(DEMO)],
     f"--demo needs to be left out with --mode ppo, which uses no routines, actual value: {DEMO}"),
    (["rapl_ppo", "--mode", "ppo", "--routine-library", "lib.json"],
     "--routine-library needs to be left out with --mode ppo"),
    (["rapl_ppo", "--mode", "ppo", "--proposer", "bpe"],
     "--proposer needs to be full with --mode ppo"),
    (["rapl_a2c", "--mode", "a2c", "--demo", str(DEMO)],
     "--demo needs to be left out with --mode a2c"),
    (["rapl_a2c", "--routine-library", "lib.json", "--alpha", "1"],
     "--alpha needs to be 2 with --routine-library"),
    (["rapl_sqil", "--num-routines", "0", "--proposer", "bpe"],
     "--proposer needs to be full with --num-routines 0"),
])
def test_an_unread_routine_flag_is_one_line_as_a_user_types_it(words, message, tmp_path):
    proc = user("python", REPO / "algos" / f"{words[0]}.py", "--env-id", "MiniQbert-v0",
                *words[1:], cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert list(tmp_path.iterdir()) == []  # no run folder


@pytest.mark.parametrize("name", ["rapl_a2c", "rapl_ppo"])
def test_a_resumed_run_keeps_alignment_and_demo_score_in_eval_json(name, tmp_path):
    common = ["--env-id", "MiniQbert-v0", "--num-envs", "2", "--num-steps", "16",
              "--eval-episodes", "1", "--torch-threads", "1"]
    ok(user("python", REPO / "algos" / f"{name}.py", *common, "--total-timesteps", "128",
            "--checkpoint-every", "64", cwd=tmp_path))
    (run,) = (tmp_path / "runs").iterdir()
    first = json.loads((run / "eval.json").read_text())
    ok(user("python", REPO / "algos" / f"{name}.py", "--resume", run, "--total-timesteps",
            "256", "--eval-episodes", "1", cwd=tmp_path))
    resumed = json.loads((run / "eval.json").read_text())
    assert resumed["global_step"] > first["global_step"]
    for key in ("mean_alignment", "alignments", "demo_score", "demo_length"):
        assert key in resumed, key
    assert resumed["demo_score"] == first["demo_score"] == 1050.0  # the shipped demo's
    assert resumed["demo_length"] == first["demo_length"] == 39


def _no_wandb_account(tmp_path) -> dict[str, str]:
    return {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path), "LANG": "C.UTF-8",
            "WANDB_DIR": str(tmp_path), "WANDB_SILENT": "true"}


@pytest.mark.parametrize(("extra", "offline", "message"), [
    (["--wandb-project-name", "a/b"], True,
     "--wandb-project-name a/b: W&B refuses it (Invalid project name 'a/b'"),
    ([], False, "--track: not logged in to Weights & Biases"),
])
def test_track_settings_that_would_fail_every_run_are_refused_up_front(extra, offline, message,
                                                                       tmp_path):
    pytest.importorskip("wandb")
    env = _no_wandb_account(tmp_path) | ({"WANDB_MODE": "offline"} if offline else {})
    for words in ([str(BIN / "routine-gym"), "experiment", "run", "rl", "--budget", "smoke",
                   "--out", "sweep", "--track", *extra],
                  [str(BIN / "python"), str(REPO / "algos" / "rapl_a2c.py"), "--env-id",
                   "MiniQbert-v0", "--track", *extra]):
        proc = subprocess.run(words, cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300, stdin=subprocess.DEVNULL)
        assert_one_line_error(proc, message)
        assert not (tmp_path / "sweep").exists() and not (tmp_path / "runs").exists()
