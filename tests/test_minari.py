"""Minari datasets (`routine_gym.demo.minari`): shipped demos exported and read back with the
real `minari` package, offline (a temporary `MINARI_DATASETS_PATH`), give the same routines and
replay the same; a dataset without a decisions mask counts every step as a decision; bad input
is refused and nothing is left half-written; and the CLI and a script take `minari:ID` as a user
types it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import minari
import numpy as np
import pytest
from minari.data_collector.episode_buffer import EpisodeBuffer
from one_line import assert_one_line_error

from routine_gym.demo import Demo, export_minari, load_minari_demo, read_demo, replay
from routine_gym.errors import UsageError
from routine_gym.mining import SequiturMiner
from routine_gym.plumbing.loading import load_demo

REPO = Path(__file__).resolve().parent.parent
DEMOS = REPO / "demos"
BIN = Path(sys.executable).parent
BREAKOUT = DEMOS / "MinAtar-Breakout-v1.npz"  # bool grids: Minari's own writer
QBERT = DEMOS / "ALE-Qbert-v5.npz"  # 210×160 frames, an image space: written as PNG


@pytest.fixture()
def minari_root(tmp_path, monkeypatch) -> Path:
    """An empty local Minari folder; nothing is downloaded."""
    root = tmp_path / "minari"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    return root


def _library(demo: Demo, **kwargs) -> dict:
    """The library mined from `demo`, as its JSON holds it, without where the demo came from."""
    data = SequiturMiner(num_routines=3, **kwargs).mine(demo).to_dict()
    data["source"].pop("path", None)
    return json.loads(json.dumps(data))


@pytest.mark.parametrize(("path", "dataset_id"), [(BREAKOUT, "routine-gym/breakout-expert-v0"),
                                                  (QBERT, "qbert-expert-v0")],
                         ids=["minatar", "atari"])
def test_a_shipped_demo_round_trips_through_minari(path, dataset_id, minari_root):
    demo = Demo.load(path)
    assert not demo.has_observations
    export_minari(demo, dataset_id, source=str(path))
    back = load_minari_demo(dataset_id, env_id=demo.env_id)

    for name in ("actions", "rewards", "terminated", "truncated", "decisions",
                 "episode_lengths"):
        assert np.array_equal(getattr(back, name), getattr(demo, name)), name
    assert back.meta == {**demo.meta, "minari_dataset": dataset_id}
    # The same routines, both selections.
    assert _library(back) == _library(demo)
    assert _library(back, selection="authors") == _library(demo, selection="authors")
    # The observations the dataset holds are exactly those of the demo's replay, and the
    # dataset read back replays (every observation, reward and flag checked).
    replayed = replay(demo, record_observations=True).demo
    assert back.observations.dtype == replayed.observations.dtype
    assert np.array_equal(back.observations, replayed.observations)
    assert np.array_equal(back.final_observations, replayed.final_observations)
    assert replay(back).matched

    # What any Minari user sees: the env, the seeds and the mask in Minari's own places.
    dataset = minari.load_dataset(dataset_id)
    assert dataset.env_spec.id == demo.env_id and dataset.total_steps == len(demo)
    (episode,) = list(dataset.iterate_episodes())
    assert np.array_equal(episode.infos["decision"], np.concatenate([[False], demo.decisions]))
    assert np.array_equal(episode.observations[-1], replayed.final_observations[0])
    (episode_meta,) = dataset.storage.get_episode_metadata([0])
    assert episode_meta["seed"] == demo.seeds[0]
    metadata = dataset.storage.metadata
    assert metadata["routine_gym"]["exported_from"] == str(path)
    assert metadata["routine_gym"]["demo"]["command"] == demo.meta["command"]


def test_the_scripts_loader_reads_minari_and_checks_the_env(minari_root):
    export_minari(Demo.load(BREAKOUT), "breakout-v0")
    demo, path = load_demo("MinAtar/Breakout-v1", "minari:breakout-v0")
    assert path == "minari:breakout-v0" and len(demo) == 286  # the shipped demo's steps
    with pytest.raises(UsageError, match="recorded on MinAtar/Breakout-v1, not MinAtar/Freeway"):
        load_demo("MinAtar/Freeway-v1", "minari:breakout-v0")
    with pytest.raises(FileNotFoundError, match="--demo minari:nothing-v0: no Minari dataset"):
        load_demo("MinAtar/Breakout-v1", "minari:nothing-v0")


def _stock_dataset(dataset_id: str, demo: Demo, infos: dict | None = None) -> None:
    """`demo` written by Minari's own `create_dataset_from_buffers`, as another project would
    share it: the env and seeds, no routine-gym metadata, no decisions mask (unless `infos`)."""
    replayed = replay(demo, record_observations=True).demo
    env = gym.make("MinAtar/Breakout-v1")
    buffer = EpisodeBuffer(
        seed=demo.seeds[0],
        observations=np.concatenate([replayed.observations, replayed.final_observations]),
        actions=demo.actions, rewards=demo.rewards, terminations=demo.terminated,
        truncations=demo.truncated, infos=infos)
    minari.create_dataset_from_buffers(dataset_id, [buffer], env=env, data_format="arrow",
                                       algorithm_name="a2c", author="someone else",
                                       author_email="a@b.c", code_permalink="https://x",
                                       description="a breakout dataset")
    env.close()


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_dataset_without_the_mask_counts_every_step_as_a_decision(minari_root):
    demo = Demo.load(BREAKOUT).select([0])
    # Half the steps marked injected, to see the mask is not invented.
    marked = Demo(actions=demo.actions, rewards=demo.rewards, terminated=demo.terminated,
                  truncated=demo.truncated, episode_lengths=demo.episode_lengths,
                  meta=demo.meta, decisions=np.arange(len(demo)) % 2 == 0)
    _stock_dataset("theirs-v0", marked)
    back = read_demo("minari:theirs-v0")
    assert back.decisions.all() and back.num_decisions == len(demo)
    assert back.env_id == "MinAtar/Breakout-v1" and back.seeds == demo.seeds
    assert back.meta["source"] == "minari" and back.meta["minari_author"] == ["someone else"]
    # The same routines as the shipped demo (which has no injected step), named by their ids:
    # a foreign dataset's action meanings would need its env made.
    ours, theirs = _library(Demo.load(BREAKOUT)), _library(back)
    assert theirs["action_meanings"] == ["0", "1", "2"]
    for key in ("routines", "scores", "frequencies", "occurrences", "params"):
        assert theirs[key] == ours[key], key
    assert replay(back).matched  # env and time limit from Minari's env spec


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_malformed_decisions_mask_is_refused(minari_root):
    demo = Demo.load(BREAKOUT)
    _stock_dataset("bad-mask-v0", demo, infos={"decision": [1] * (len(demo) + 1)})
    with pytest.raises(UsageError, match=r"minari:bad-mask-v0: episode 0's infos\['decision'\] "
                                         r"is int64 of shape \(287,\)"):
        read_demo("minari:bad-mask-v0")


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_dataset_of_continuous_actions_is_not_a_demo(minari_root):
    buffer = EpisodeBuffer(observations=np.zeros((3, 2), np.float32),
                           actions=np.zeros((2, 1), np.float32),
                           rewards=[0.0, 1.0], terminations=[False, True],
                           truncations=[False, False])
    minari.create_dataset_from_buffers(
        "box-v0", [buffer], observation_space=gym.spaces.Box(-1, 1, (2,)),
        action_space=gym.spaces.Box(-1, 1, (1,)), data_format="arrow")
    with pytest.raises(UsageError, match=r"minari:box-v0: a demo's actions are Discrete\(n\)"):
        read_demo("minari:box-v0")


def test_an_existing_dataset_is_never_replaced(minari_root):
    export_minari(Demo.load(BREAKOUT), "ns/taken-v0")
    before = {p: p.stat().st_mtime_ns for p in minari_root.rglob("*")}
    with pytest.raises(UsageError, match="Minari dataset ns/taken-v0 already exists"):
        export_minari(Demo.load(QBERT), "ns/taken-v0")
    assert {p: p.stat().st_mtime_ns for p in minari_root.rglob("*")} == before


@pytest.mark.parametrize("dataset_id", ["no-version", "a b-v0", "bad/-v0"])
def test_a_malformed_dataset_id_is_refused(dataset_id, minari_root):
    with pytest.raises(UsageError, match="is not a Minari dataset id"):
        export_minari(Demo.load(BREAKOUT), dataset_id)


def test_a_failed_export_leaves_nothing_behind(minari_root, monkeypatch):
    import routine_gym.demo.minari as module

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(module, "_write_png_episodes", fail)
    with pytest.raises(OSError, match="disk full"):
        export_minari(Demo.load(QBERT), "ns/qbert-v0")
    assert list(minari_root.iterdir()) == []  # no dataset, no namespace, no staging folder


def test_a_demo_that_does_not_replay_is_not_exported(minari_root):
    demo = Demo.load(BREAKOUT)
    rewards = demo.rewards.copy()
    rewards[10] += 1
    changed = Demo(actions=demo.actions, rewards=rewards, terminated=demo.terminated,
                   truncated=demo.truncated, episode_lengths=demo.episode_lengths,
                   meta={**demo.meta, "scores": None}, decisions=demo.decisions)
    with pytest.raises(ValueError, match="diverged at step 10"):
        export_minari(changed, "changed-v0")
    assert not (minari_root / "changed-v0").exists()


def test_without_minari_installed_the_error_says_how_to_install_it(minari_root, monkeypatch):
    monkeypatch.setitem(sys.modules, "minari", None)
    for call in (lambda: export_minari(Demo.load(BREAKOUT), "x-v0"),
                 lambda: read_demo("minari:x-v0")):
        with pytest.raises(UsageError, match=r"pip install routine-gym\[minari\]"):
            call()


# -- as a user types it ---------------------------------------------------------------------


def user(*words: str | Path, cwd: Path, minari_path: Path,
         timeout: float = 300) -> subprocess.CompletedProcess:
    """A fresh process with a shell's environment (PATH, HOME) and the Minari folder."""
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8",
           "MINARI_DATASETS_PATH": str(minari_path)}
    words = [str(w) for w in words]
    if words[0] in ("routine-gym", "python"):
        words[0] = str(BIN / words[0])
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


def ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, (proc.stdout[-2000:], proc.stderr[-3000:])
    return proc.stdout


def test_export_then_mine_and_train_from_minari_as_a_user(tmp_path):
    datasets = tmp_path / "datasets"
    out = ok(user("routine-gym", "export", BREAKOUT, "--minari", "me/breakout-v0",
                  cwd=tmp_path, minari_path=datasets))
    assert "286 steps: 286 decided, 0 injected" in out
    assert (datasets / "me" / "breakout-v0" / "data" / "metadata.json").is_file()

    ok(user("routine-gym", "mine", "minari:me/breakout-v0", "--out", "from_minari.json",
            cwd=tmp_path, minari_path=datasets))
    ok(user("routine-gym", "mine", BREAKOUT, "--out", "from_npz.json", cwd=tmp_path,
            minari_path=datasets))
    from_minari = json.loads((tmp_path / "from_minari.json").read_text())
    from_npz = json.loads((tmp_path / "from_npz.json").read_text())
    assert from_minari["source"].pop("path") == "minari:me/breakout-v0"
    from_npz["source"].pop("path")
    assert from_minari == from_npz
    assert "matches the recording" in ok(user("routine-gym", "replay", "minari:me/breakout-v0",
                                              cwd=tmp_path, minari_path=datasets))

    # One line each: an id that exists, a missing demo, a missing dataset.
    assert_one_line_error(user("routine-gym", "export", BREAKOUT, "--minari", "me/breakout-v0",
                               cwd=tmp_path, minari_path=datasets),
                          "me/breakout-v0 already exists", prefix="routine-gym: error:")
    assert_one_line_error(user("routine-gym", "export", "missing.npz", "--minari", "x-v0",
                               cwd=tmp_path, minari_path=datasets),
                          "no demo file at missing.npz", prefix="routine-gym: error:")
    assert_one_line_error(user("routine-gym", "mine", "minari:me/nothing-v0", cwd=tmp_path,
                               minari_path=datasets),
                          "no Minari dataset me/nothing-v0", str(datasets))
    assert sorted(p.name for p in datasets.iterdir()) == ["me"]  # no staging folder left

    # A script, RAPL-SQIL: routines mined from the dataset, its observations as the demo states.
    ok(user("python", REPO / "algos" / "rapl_sqil.py", "--env-id", "MinAtar/Breakout-v1",
            "--demo", "minari:me/breakout-v0", "--total-timesteps", "200",
            "--learning-starts", "100", "--buffer-size", "2000", "--eval-episodes", "1",
            "--eval-max-steps", "200", "--run-dir", "runs", "--torch-threads", "1",
            cwd=tmp_path, minari_path=datasets))
    (run,) = (tmp_path / "runs").iterdir()
    routines = json.loads((run / "routines.json").read_text())
    assert routines["source"]["path"] == "minari:me/breakout-v0"
    assert routines["routines"] == from_npz["routines"]
    assert json.loads((run / "eval.json").read_text())["env_id"] == "MinAtar/Breakout-v1"


def test_without_minari_the_cli_says_how_to_install_it(tmp_path):
    # A user's process in which the package cannot be imported.
    code = ("import sys; sys.modules['minari'] = None\n"
            "from routine_gym.cli import main\n"
            f"sys.exit(main(['export', {str(BREAKOUT)!r}, '--minari', 'x-v0']))")
    proc = user("python", "-c", code, cwd=tmp_path, minari_path=tmp_path / "datasets")
    assert_one_line_error(proc, "pip install routine-gym[minari]", prefix="routine-gym: error:")
    assert not (tmp_path / "datasets").exists() or not os.listdir(tmp_path / "datasets")


# -- Minari's hdf5 format, and ids that nest (issue 46 case 10) -----------------------------


def _as_hdf5(datasets: Path, dataset_id: str) -> None:
    """Mark an exported dataset as stored in Minari's hdf5 format (its default; h5py, which
    writes one, is not installed here): what such a dataset's metadata says."""
    path = datasets / dataset_id / "data" / "metadata.json"
    meta = json.loads(path.read_text())
    meta["data_format"] = "hdf5"
    path.write_text(json.dumps(meta))


def test_an_hdf5_dataset_is_one_line_everywhere_before_any_run_folder(tmp_path):
    pytest.importorskip("minari")
    try:
        import h5py  # noqa: F401
        pytest.skip("h5py is installed: an hdf5 dataset can be read")
    except ImportError:
        pass
    datasets = tmp_path / "datasets"
    ok(user("routine-gym", "export", BREAKOUT, "--minari", "me/h5-v0", cwd=tmp_path,
            minari_path=datasets))
    _as_hdf5(datasets, "me/h5-v0")
    for words in (["routine-gym", "mine", "minari:me/h5-v0"],
                  ["routine-gym", "show", "minari:me/h5-v0"],
                  ["routine-gym", "replay", "minari:me/h5-v0"],
                  ["routine-gym", "picture", "minari:me/h5-v0", "--out", "p.png"],
                  ["python", REPO / "algos" / "rapl_a2c.py", "--env-id", "MinAtar/Breakout-v1",
                   "--demo", "minari:me/h5-v0", "--total-timesteps", "256"]):
        proc = user(*words, cwd=tmp_path, minari_path=datasets)
        assert_one_line_error(proc, "minari:me/h5-v0 is stored in Minari's hdf5 format",
                              "pip install 'minari[hdf5]'", "data_format='arrow'")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["datasets"]  # no run folder


def test_export_refuses_an_id_inside_or_over_an_existing_dataset(tmp_path):
    datasets = tmp_path / "datasets"
    ok(user("routine-gym", "export", BREAKOUT, "--minari", "rg/mq-v0", cwd=tmp_path,
            minari_path=datasets))
    before = sorted(str(p.relative_to(datasets)) for p in datasets.rglob("*"))
    proc = user("routine-gym", "export", BREAKOUT, "--minari", "rg/mq-v0/sub-v0",
                cwd=tmp_path, minari_path=datasets)
    assert_one_line_error(proc, "rg/mq-v0/sub-v0 would put a dataset inside the dataset "
                          "rg/mq-v0")
    # A folder that holds datasets (as one nested by the old export did) is no free id either.
    (datasets / "old-v0" / "sub-v0" / "data").mkdir(parents=True)
    proc = user("routine-gym", "export", BREAKOUT, "--minari", "old-v0", cwd=tmp_path,
                minari_path=datasets)
    assert_one_line_error(proc, "old-v0 is a folder of other datasets")
    after = sorted(str(p.relative_to(datasets)) for p in datasets.rglob("*")
                   if not str(p.relative_to(datasets)).startswith("old-v0"))
    assert after == before  # nothing written into the existing dataset
