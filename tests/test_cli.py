"""The `routine-gym` command line (routine_gym/cli.py), called in-process.

User errors end with exit code 2 and one `routine-gym: error: ...` line, never a traceback.
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers MiniQbert)
import routine_gym.demo
from routine_gym.cli import main
from routine_gym.demo import Demo, replay
from routine_gym.library import RoutineLibrary

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

SUBCOMMANDS = ("mine", "show", "replay", "show-demos", "picture", "export", "record", "play")


@pytest.fixture
def shipped_demo(repo_root) -> str:
    return str(repo_root / "demos" / "MiniQbert-v0.npz")


def fails_with(capsys, argv: list[str], message: str) -> str:
    """Run the CLI, expect exit code 2 and `message` in a one-line error, return stderr."""
    with pytest.raises(SystemExit) as excinfo:
        main(argv)
    assert excinfo.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert message in err, err
    return err


def count_overlapping(sequence: list[int], routine: list[int]) -> int:
    n = len(routine)
    return sum(sequence[i : i + n] == routine for i in range(len(sequence) - n + 1))


# -- help ----------------------------------------------------------------------------------


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_help_of_every_subcommand(capsys, command):
    with pytest.raises(SystemExit) as excinfo:
        main([command, "--help"])
    assert excinfo.value.code == 0
    assert f"usage: routine-gym {command}" in capsys.readouterr().out


def test_top_level_help_lists_the_subcommands(capsys):
    with pytest.raises(SystemExit) as excinfo:
        main(["--help"])
    assert excinfo.value.code == 0
    out = capsys.readouterr().out
    assert all(command in out for command in SUBCOMMANDS)


def test_no_subcommand_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as excinfo:
        main([])
    assert excinfo.value.code == 2


# -- record --------------------------------------------------------------------------------


def test_record_random_policy_keeps_the_best_episode(capsys, tmp_path):
    out = tmp_path / "random.npz"
    assert main(["record", "MiniQbert-v0", "--out", str(out), "--episodes", "3",
                 "--seed", "7"]) == 0
    assert "saved 1 episode(s)" in capsys.readouterr().out
    demo = Demo.load(out, env_id="MiniQbert-v0")
    candidates = demo.meta["candidates"]
    assert candidates["seeds"] == [7, 8, 9]
    assert demo.score == max(candidates["scores"])
    assert demo.seeds[0] in (7, 8, 9)
    assert not demo.has_observations
    assert replay(demo).matched


def test_record_expert_with_and_without_noise(capsys, tmp_path):
    # The noiseless scripted expert clears MiniQbert's 3 levels: 1050 points in 33 steps
    # (routine_gym.envs.miniqbert.scripted_expert's documented figures).
    out = tmp_path / "expert.npz"
    assert main(["record", "MiniQbert-v0", "--policy", "expert", "--episodes", "1",
                 "--out", str(out), "--observations"]) == 0
    demo = Demo.load(out)
    assert demo.score == 1050.0 and len(demo) == 33
    assert demo.has_observations
    # With noise some actions are random: a different action sequence, still a valid demo.
    noisy = tmp_path / "noisy.npz"
    assert main(["record", "MiniQbert-v0", "--policy", "expert", "--expert-noise", "0.3",
                 "--episodes", "2", "--keep", "all", "--out", str(noisy), "--seed", "1"]) == 0
    noisy_demo = Demo.load(noisy)
    assert noisy_demo.num_episodes == 2
    assert not np.array_equal(noisy_demo.episode_actions()[0], demo.actions)
    assert replay(noisy_demo).matched


def test_record_passes_env_kwargs_and_max_steps(capsys, tmp_path):
    out = tmp_path / "small.npz"
    assert main(["record", "MiniQbert-v0", "--env-kwarg", "size=3", "--env-kwarg", "lives=1",
                 "--max-steps", "5", "--episodes", "1", "--out", str(out)]) == 0
    demo = Demo.load(out)
    assert demo.env_kwargs == {"size": 3, "lives": 1}  # values parsed as JSON: ints
    assert demo.meta["max_episode_steps"] == 5
    assert len(demo) <= 5


def test_record_with_a_module_function_policy(capsys, tmp_path, monkeypatch):
    (tmp_path / "my_policy.py").write_text("def always_down(obs):\n    return 5\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "down.npz"
    assert main(["record", "MiniQbert-v0", "--policy", "my_policy:always_down",
                 "--episodes", "1", "--out", str(out)]) == 0
    demo = Demo.load(out)
    assert set(demo.actions.tolist()) == {5}
    # Always DOWN on the 4-row pyramid: (1,0), (2,0), (3,0) coloured (3 × 25), the 4th jump
    # falls off; the next two lives land on coloured cubes (0) and fall the same way.
    # Score 75 in 3 lives × 4 jumps = 12 steps.
    assert demo.score == 75.0
    assert len(demo) == 12 and demo.terminated[-1]


def test_record_errors(capsys, tmp_path):
    out = str(tmp_path / "x.npz")
    fails_with(capsys, ["record", "MiniQbert-v0", "--out", out, "--policy", "bogus"],
               "unknown policy 'bogus'")
    fails_with(capsys, ["record", "MiniQbert-v0", "--out", out, "--policy", "no_such_mod:f"],
               "cannot import policy 'no_such_mod:f'")
    fails_with(capsys, ["record", "CartPole-v1", "--out", out, "--policy", "expert"],
               "MiniQbert's scripted expert")
    fails_with(capsys, ["record", "MiniQbert-v0", "--out", out, "--env-kwarg", "size"],
               "--env-kwarg takes KEY=VALUE, got 'size'")
    fails_with(capsys, ["record", "MiniQbert-v0", "--out", out, "--env-kwarg", "size=1"],
               "size needs to be an integer ≥ 2, actual value: 1")
    fails_with(capsys, ["record", "NoSuchEnv-v0", "--out", out], "NoSuchEnv")
    fails_with(capsys, ["record", "MiniQbert-v0", "--out", out, "--episodes", "0"],
               "--episodes needs to be ≥ 1, actual value: 0")
    assert not (tmp_path / "x.npz").exists()


# -- mine and show -------------------------------------------------------------------------


def test_mine_prints_routines_with_names_scores_and_frequencies(capsys, tmp_path, shipped_demo):
    out = tmp_path / "lib.json"
    assert main(["mine", shipped_demo, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "MiniQbert-v0, 1 episode(s), 39 actions, score 1050" in captured.out
    library = RoutineLibrary.load(out)
    actions = Demo.load(shipped_demo).actions.tolist()
    meanings = ["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"]
    assert len(library) >= 1
    for routine, score, frequency in zip(library.routines, library.scores, library.frequencies,
                                         strict=True):
        # Frequency: overlapping occurrences in the demo; score = f + 0.1 · |ρ|.
        assert frequency == count_overlapping(actions, list(routine))
        assert score == pytest.approx(frequency + 0.1 * len(routine))
        name = " ".join(meanings[a] for a in routine)
        assert name in captured.out
        assert f"freq={frequency}" in captured.out
        assert f"score={score:.2f}" in captured.out
    assert f"saved to {out}" in captured.out
    # The shipped demo has fewer than K=3 distinct routines: said on stderr, not hidden.
    assert "warning:" in captured.err


def test_mine_with_an_ablation_proposer_and_options(capsys, tmp_path, shipped_demo):
    out = tmp_path / "random.json"
    assert main(["mine", shipped_demo, "--proposer", "random", "--seed", "3", "-k", "2",
                 "--out", str(out)]) == 0
    library = RoutineLibrary.load(out)
    assert library.params["proposer"] == "random"
    assert len(library) <= 2
    capsys.readouterr()
    again = tmp_path / "again.json"
    main(["mine", shipped_demo, "--proposer", "random", "--seed", "3", "-k", "2",
          "--out", str(again)])
    assert RoutineLibrary.load(again).routines == library.routines  # seeded


def test_mine_errors(capsys, tmp_path, shipped_demo):
    fails_with(capsys, ["mine", str(tmp_path / "missing.npz")], "no demo file at")
    fails_with(capsys, ["mine", shipped_demo, "-k", "0"], "--num-routines needs to be ≥ 1")
    (tmp_path / "junk.npz").write_bytes(b"not a zip at all")
    fails_with(capsys, ["mine", str(tmp_path / "junk.npz")], "not a routine-gym demo")
    with pytest.raises(SystemExit) as excinfo:  # argparse's own check of the choices
        main(["mine", shipped_demo, "--proposer", "magic"])
    assert excinfo.value.code == 2


def test_show_a_library(capsys, tmp_path, shipped_demo):
    main(["mine", shipped_demo, "--out", str(tmp_path / "lib.json")])
    capsys.readouterr()
    assert main(["show", str(tmp_path / "lib.json")]) == 0
    out = capsys.readouterr().out
    assert "LEFT DOWN LEFT DOWN" in out
    assert "source:" in out and "MiniQbert-v0" in out


def test_show_a_demo(capsys, shipped_demo):
    assert main(["show", shipped_demo, "--head", "3"]) == 0
    out = capsys.readouterr().out
    actions = Demo.load(shipped_demo).actions
    meanings = ["NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN"]
    assert "env_id: MiniQbert-v0" in out
    assert "episodes: 1, actions: 39, observations: no" in out
    counts = np.bincount(actions, minlength=6)
    for meaning, count in zip(meanings, counts, strict=True):
        assert (f"{meaning}={count}" in out) == (count > 0)
    first = " ".join(meanings[a] for a in actions[:3])
    assert f"first decided actions: {first}\n" in out


def test_show_errors(capsys, tmp_path):
    fails_with(capsys, ["show", str(tmp_path / "nothing.json")], "no file at")
    (tmp_path / "bad.json").write_text("{not json")
    err = fails_with(capsys, ["show", str(tmp_path / "bad.json")], "routine-gym: error:")
    assert len(err.strip().splitlines()) == 1


# -- replay --------------------------------------------------------------------------------


def test_replay_a_matching_demo(capsys, shipped_demo):
    assert main(["replay", shipped_demo]) == 0
    assert "episode 0: score 1050, length 39: matches the recording" in capsys.readouterr().out
    assert main(["replay", shipped_demo, "--episode", "0"]) == 0


def test_replay_a_tampered_demo_fails_with_exit_code_1(capsys, tmp_path, shipped_demo):
    demo = Demo.load(shipped_demo)
    # The first action DOWN (+25) becomes NOOP (0): the file is consistent, the game is not.
    assert demo.actions[0] == 5 and demo.rewards[0] == 25.0
    actions = demo.actions.copy()
    actions[0] = 0
    dataclasses.replace(demo, actions=actions).save(tmp_path / "tampered.npz")
    assert main(["replay", str(tmp_path / "tampered.npz")]) == 1
    err = capsys.readouterr().err
    assert "replay FAILED" in err and "at step 0" in err
    assert "Traceback" not in err


def test_replay_errors(capsys, tmp_path, shipped_demo):
    fails_with(capsys, ["replay", str(tmp_path / "missing.npz")], "no demo file at")
    fails_with(capsys, ["replay", shipped_demo, "--episode", "5"], "episode 5 out of range")


# -- play (no keyboard here: the CLI wiring only) ------------------------------------------


def test_play_passes_its_options_and_saves_the_demo(capsys, tmp_path, monkeypatch, shipped_demo):
    calls = []
    recorded = Demo.load(shipped_demo)

    def fake_record_human_demo(env_id, **kwargs):
        calls.append((env_id, kwargs))
        return recorded

    monkeypatch.setattr(routine_gym.demo, "record_human_demo", fake_record_human_demo)
    out = tmp_path / "human.npz"
    assert main(["play", "MiniQbert-v0", "--out", str(out), "--seed", "4", "--episodes", "2",
                 "--fps", "8", "--zoom", "2.5", "--env-kwarg", "lives=1"]) == 0
    assert calls == [("MiniQbert-v0", {"seed": 4, "fps": 8, "zoom": 2.5,
                                       "env_kwargs": {"lives": 1}, "num_episodes": 2})]
    saved = Demo.load(out)
    np.testing.assert_array_equal(saved.actions, recorded.actions)
    assert "saved 1 episode(s), 39 actions, score 1050" in capsys.readouterr().out


def test_play_with_nothing_played_is_a_clear_error(capsys, tmp_path, monkeypatch):
    def nothing_played(env_id, **kwargs):
        raise RuntimeError("no step was played, so there is no demo to return")

    monkeypatch.setattr(routine_gym.demo, "record_human_demo", nothing_played)
    fails_with(capsys, ["play", "MiniQbert-v0", "--out", str(tmp_path / "h.npz")],
               "no demo recorded: no step was played")
    assert not (tmp_path / "h.npz").exists()


def test_library_json_from_mine_is_plain_json(tmp_path, shipped_demo, capsys):
    out = tmp_path / "lib.json"
    main(["mine", shipped_demo, "--out", str(out)])
    data = json.loads(out.read_text())
    assert [list(r) for r in RoutineLibrary.load(out).routines] == [
        list(r) for r in data["routines"]
    ]


# -- show-demos ----------------------------------------------------------------------------


def test_show_demos_lists_each_demo_with_its_mined_routines(capsys, tmp_path, shipped_demo):
    shutil.copy(shipped_demo, tmp_path / "MiniQbert-v0.npz")
    assert main(["show-demos", "--dir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "1 demo(s)" in out
    assert "MiniQbert-v0  (MiniQbert-v0.npz" in out
    assert "score 1050, 39 steps (39 decided, 0 injected), 1 episode(s)" in out
    # The shipped MiniQbert demo mines to these two routines (see test_shipped_demos).
    assert "routine 0: LEFT DOWN LEFT DOWN  (f = 5)" in out
    assert "routine 1: RIGHT RIGHT RIGHT LEFT DOWN LEFT DOWN  (f = 3)" in out
    assert "only 2 routine(s) survive" in out
    # Every suite env without a demo in the folder is named, with the file it expects.
    assert "ALE/Breakout-v5: no demo" in out and "ALE-Breakout-v5.npz" in out
    assert "procgen/CoinRun-v0: no demo" in out


def test_show_demos_with_k_one_and_a_missing_folder(capsys, tmp_path, shipped_demo):
    shutil.copy(shipped_demo, tmp_path / "MiniQbert-v0.npz")
    assert main(["show-demos", "--dir", str(tmp_path), "-k", "1"]) == 0
    out = capsys.readouterr().out
    assert "routine 0: LEFT DOWN LEFT DOWN" in out and "routine 1:" not in out
    with pytest.raises(SystemExit) as excinfo:
        main(["show-demos", "--dir", str(tmp_path / "nowhere")])
    assert excinfo.value.code == 2
    assert "no demo folder at" in capsys.readouterr().err
