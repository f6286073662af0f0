"""Every CLI command and every script, run as a user runs it: a fresh process started from a
shell-like environment (PATH and HOME only), in a folder of its own, with none of the test
suite's set-up (no env registered in advance, no SDL or thread settings), on a shipped demo of
each env family."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from one_line import assert_one_line_error

REPO = Path(__file__).resolve().parent.parent
DEMOS = REPO / "demos"
BIN = Path(sys.executable).parent  # the venv a user installs into: routine-gym, python
#: A shipped demo of each env family, with its env id.
FAMILIES = {
    "atari": ("ALE/Qbert-v5", DEMOS / "ALE-Qbert-v5.npz"),
    "minatar": ("MinAtar/Breakout-v1", DEMOS / "MinAtar-Breakout-v1.npz"),
    "miniqbert": ("MiniQbert-v0", DEMOS / "MiniQbert-v0.npz"),
    "procgen": ("procgen/CoinRun-v0", DEMOS / "procgen-CoinRun-v0.npz"),
}


def user(*words: str | Path, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """Run a command as a user's shell would: PATH with the venv's bin first, HOME, nothing else
    (but `ROUTINE_GYM_NATIVE` where the suite runs with it: the cores-off leg of .ci/run)."""
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    if "ROUTINE_GYM_NATIVE" in os.environ:
        env["ROUTINE_GYM_NATIVE"] = os.environ["ROUTINE_GYM_NATIVE"]
    words = [str(w) for w in words]
    if words[0] in ("routine-gym", "python"):
        words[0] = str(BIN / words[0])
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-3000:])
    return proc.stdout


@pytest.mark.parametrize("family", list(FAMILIES))
def test_mine_show_and_replay_a_shipped_demo_of_each_family(family, tmp_path):
    env_id, demo = FAMILIES[family]
    mined = ok(user("routine-gym", "mine", demo, "--out", "routines.json", cwd=tmp_path))
    assert f"({env_id}, 1 episode(s)" in mined and "[0] len=" in mined
    library = json.loads((tmp_path / "routines.json").read_text())
    assert len(library["routines"]) >= 1
    shown = ok(user("routine-gym", "show", "routines.json", cwd=tmp_path))
    assert "[0] len=" in shown and str(demo) in shown
    shown = ok(user("routine-gym", "show", demo, cwd=tmp_path))
    assert f"env_id: {env_id}" in shown and "decided by the demonstrator" in shown
    replayed = ok(user("routine-gym", "replay", demo, cwd=tmp_path))
    assert replayed.strip().endswith("matches the recording")


@pytest.mark.parametrize("family", list(FAMILIES))
def test_record_a_random_policy_then_replay_it_for_each_family(family, tmp_path):
    env_id, _ = FAMILIES[family]
    # A missing folder of the output is made, as for every output (mine, upgrade, the scripts).
    out = ok(user("routine-gym", "record", env_id, "--episodes", "2", "--max-steps", "60",
                  "--out", "new/folder/mine.npz", cwd=tmp_path))
    assert "saved 1 episode(s)" in out
    assert "matches the recording" in ok(user("routine-gym", "replay", "new/folder/mine.npz",
                                              cwd=tmp_path))


def test_record_with_a_policy_module_of_the_users_own_folder(tmp_path):
    # `routine-gym` is a launcher in the venv's bin/: a module beside the user must still be
    # found, as `python -m` would find it.
    (tmp_path / "mypkg").mkdir()
    (tmp_path / "mypkg" / "__init__.py").write_text("")
    (tmp_path / "mypkg" / "policies.py").write_text("def act(obs):\n    return int(obs[2] > 0)\n")
    out = ok(user("routine-gym", "record", "CartPole-v1", "--policy", "mypkg.policies:act",
                  "--episodes", "2", "--out", "cp.npz", cwd=tmp_path))
    assert "saved 1 episode(s)" in out
    assert "matches the recording" in ok(user("routine-gym", "replay", "cp.npz", cwd=tmp_path))


def test_upgrade_a_version_1_atari_demo(tmp_path):
    # A version-1 file: the shipped Breakout demo without its decisions.
    with np.load(DEMOS / "ALE-Breakout-v5.npz", allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files if name != "decisions"}
    meta = json.loads(str(arrays["meta"][()]))
    meta["version"] = 1
    meta.pop("recorded_under", None)
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez_compressed(tmp_path / "old.npz", **arrays)
    out = ok(user("routine-gym", "upgrade", "old.npz", "--out", "new.npz", cwd=tmp_path))
    assert "saved as version 2 to new.npz" in out
    shown = ok(user("routine-gym", "show", "new.npz", cwd=tmp_path))
    assert "decided by the demonstrator" in shown and "format version 1" not in shown


def test_show_demos_lists_every_shipped_demo(tmp_path):
    out = ok(user("routine-gym", "show-demos", cwd=tmp_path))
    assert f"{len(list(DEMOS.glob('*.npz')))} demo(s) in" in out
    for _, (env_id, _) in FAMILIES.items():
        assert f"\n{env_id}  (" in out


def test_play_without_a_display_is_a_one_line_error(tmp_path):
    proc = user("routine-gym", "play", "MiniQbert-v0", "--out", "me.npz", cwd=tmp_path,
                timeout=60)
    assert_one_line_error(proc, "play needs a display", prefix="routine-gym: error: ")
    assert not (tmp_path / "me.npz").exists()


def test_experiment_list_and_report_of_a_committed_snapshot(tmp_path):
    listed = ok(user("routine-gym", "experiment", "list", cwd=tmp_path))
    for name in ("imitation", "rl", "curves", "coinrun", "scalability", "ablation"):
        assert f"\n{name} " in listed
    # The committed CoinRun results as a sweep folder of their own (the cheapest to report).
    snapshot = REPO / "bench" / "results" / "experiments" / "cpu"
    sweep = tmp_path / "sweep"
    (sweep / "runs").mkdir(parents=True)
    shutil.copy(snapshot / "coinrun.json", sweep / "coinrun.json")
    for run in json.loads((snapshot / "coinrun.json").read_text())["runs"]:
        shutil.copytree(snapshot / "runs" / run["key"], sweep / "runs" / run["key"])
    written = ok(user("routine-gym", "experiment", "report", "sweep", cwd=tmp_path))
    assert "sweep/report/fig4_coinrun.png" in written and "sweep/report/report.md" in written
    assert (sweep / "report" / "fig4_coinrun.png").stat().st_size > 10_000


# Each script once on a family (rapl_a2c on all four), with the smallest budget that trains,
# checkpoints and evaluates.
SCRIPTS = [
    ("rapl_a2c", "atari", ["--mode", "rapl", "--num-envs", "2", "--total-timesteps", "200"]),
    ("rapl_a2c", "minatar", ["--mode", "rapl", "--num-envs", "2", "--total-timesteps", "200"]),
    ("rapl_a2c", "miniqbert", ["--mode", "macro", "--num-envs", "2",
                               "--total-timesteps", "200"]),
    ("rapl_a2c", "procgen", ["--mode", "rapl", "--num-envs", "2", "--total-timesteps", "200"]),
    ("rapl_sqil", "atari", ["--total-timesteps", "200", "--learning-starts", "100",
                            "--buffer-size", "2000", "--eval-max-steps", "200"]),
    ("bc", "procgen", ["--gradient-steps", "20", "--eval-max-steps", "200"]),
    ("gail", "minatar", ["--total-timesteps", "256", "--num-envs", "2",
                         "--eval-max-steps", "200"]),
    ("option_critic", "atari", ["--num-envs", "2", "--total-timesteps", "200"]),
    ("compile_a2c", "miniqbert", ["--num-envs", "2", "--total-timesteps", "200",
                                  "--compile-iterations", "20"]),
]


@pytest.mark.parametrize(("script", "family", "flags"), SCRIPTS,
                         ids=[f"{s}-{f}" for s, f, _ in SCRIPTS])
def test_each_script_trains_checkpoints_and_evaluates(script, family, flags, tmp_path):
    env_id, demo = FAMILIES[family]
    demo_flags = [] if script == "option_critic" else ["--demo", str(demo)]
    ok(user("python", REPO / "algos" / f"{script}.py", "--env-id", env_id, *demo_flags, *flags,
            "--eval-episodes", "1", "--checkpoint-every", "100", "--run-dir", "runs",
            "--torch-threads", "1",  # two tests run at once on two cores
            cwd=tmp_path))
    (run,) = (tmp_path / "runs").iterdir()
    summary = json.loads((run / "eval.json").read_text())
    assert summary["env_id"] == env_id and len(summary["returns"]) == 1
    assert (run / "checkpoint.pt").is_file()
    assert not [p for p in run.rglob("*.tmp")]


def test_ale_greets_no_one_in_the_scripts_and_the_cli_but_a_library_user_keeps_its_logging(
        tmp_path):
    banner = ("A.L.E: Arcade Learning Environment", "[Powered by Stella]")
    replayed = user("routine-gym", "replay", DEMOS / "ALE-Qbert-v5.npz", cwd=tmp_path)
    assert ok(replayed).strip().endswith("matches the recording")
    assert not any(line in replayed.stderr for line in banner), replayed.stderr
    trained = user("python", REPO / "algos" / "rapl_a2c.py", "--env-id", "ALE/Qbert-v5",
                   "--mode", "a2c", "--num-envs", "2", "--total-timesteps", "64",
                   "--eval-episodes", "1", "--run-dir", "runs",
                   cwd=tmp_path)
    assert "eval over 1 episodes" in ok(trained)
    assert not any(line in trained.stderr for line in banner), trained.stderr
    # Importing routine-gym changes nothing of ALE's own logging.
    made = user("python", "-c", "import gymnasium as gym, routine_gym; "
                "routine_gym.register_envs(); gym.make('ALE/Qbert-v5').reset(seed=0)",
                cwd=tmp_path)
    assert all(line in ok(made) + made.stderr for line in banner), made.stderr
