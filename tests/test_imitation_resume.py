"""Checkpoints and `--resume` of algos/bc.py and algos/gail.py: a killed run goes on from its
last checkpoint, a finished one trains further when its budget is raised, and a bad `--resume`
is named."""

from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import pytest
import torch
from resume_checks import assert_same
from script_loader import load_script

import routine_gym  # noqa: F401  (registers MiniQbert-v0)
from routine_gym.plumbing.run import Run

SCRIPTS = {name: load_script(name, f"algos_{name}_resume") for name in ("bc", "gail")}
# Tiny budgets on MiniQbert; GAIL's iterations are 2 envs × 16 steps = 32 primitive steps.
TINY = {
    "bc": dict(batch_size=8, checkpoint_every=20),
    "gail": dict(num_envs=2, num_steps=16, num_minibatches=2, update_epochs=4,
                 disc_minibatches=2, disc_epochs=1, checkpoint_every=32),
}


class Killed(Exception):
    """Stands in for a SIGKILL right after a checkpoint is written."""


def run(script: str, **kwargs) -> None:
    module = SCRIPTS[script]
    if "resume" not in kwargs:
        kwargs = {**TINY[script], "env_id": "MiniQbert-v0", "eval_episodes": 2,
                  "eval_max_steps": 60, "log_every": 1000, **kwargs}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        module.main(module.Args(**kwargs))


def run_killed_at_first_checkpoint(script: str, monkeypatch, **kwargs) -> Path:
    """Run a script until it has written its first checkpoint; return the run folder."""
    save = Run.save_checkpoint

    def save_and_die(run_, state):
        save(run_, state)
        raise Killed

    with monkeypatch.context() as m:
        m.setattr(Run, "save_checkpoint", save_and_die)
        with pytest.raises(Killed):
            run(script, **kwargs)
    (folder,) = Path(kwargs["run_dir"]).iterdir()
    return folder


def load(folder: Path) -> dict:
    return torch.load(folder / "checkpoint.pt", weights_only=True)


def evaluation(folder: Path) -> dict:
    with open(folder / "eval.json") as f:
        return json.load(f)


def test_bc_resumed_after_a_kill_trains_exactly_as_an_uninterrupted_run(tmp_path, monkeypatch,
                                                                         capsys):
    # The uninterrupted run: 60 gradient steps, its checkpoints at steps 20, 40, 60 kept aside.
    saves = {}
    save = Run.save_checkpoint

    def save_and_keep(run_, state):
        save(run_, state)
        checkpoint = torch.load(run_.checkpoint_path, weights_only=True)
        saves[checkpoint["step"]] = checkpoint

    with monkeypatch.context() as m:
        m.setattr(Run, "save_checkpoint", save_and_keep)
        run("bc", gradient_steps=60, run_dir=str(tmp_path / "whole"))
    (whole,) = (tmp_path / "whole").iterdir()
    assert sorted(saves) == [20, 40, 60]

    # A 40-step run killed after its checkpoint at step 20, resumed as configured.
    folder = run_killed_at_first_checkpoint("bc", monkeypatch, gradient_steps=40,
                                            run_dir=str(tmp_path / "killed"))
    assert load(folder)["step"] == 20
    run("bc", resume=str(folder))
    assert f"resumed {folder.name} at step 20" in capsys.readouterr().out
    resumed = load(folder)
    assert resumed["step"] == 40 and json.loads(resumed["args"])["gradient_steps"] == 40
    # Same batches (the generators continued) and the same Adam moments: bit-identical.
    for key in ("model", "optimizer", "rng"):
        assert_same(resumed[key], saves[40][key])

    # The finished run trains on when its budget is raised, and still matches.
    run("bc", resume=str(folder / "checkpoint.pt"), gradient_steps=60)
    assert f"resumed {folder.name} at step 40" in capsys.readouterr().out
    raised = load(folder)
    assert raised["step"] == 60
    for key in ("model", "optimizer", "rng"):
        assert_same(raised[key], saves[60][key])
    assert evaluation(folder)["global_step"] == 60
    assert evaluation(folder) == evaluation(whole)  # the same policy, sampled the same way


def test_gail_resumes_from_its_checkpoint_with_its_networks_and_optimizers(tmp_path,
                                                                           monkeypatch, capsys):
    # A 64-step run (2 iterations) killed after its checkpoint at step 32.
    folder = run_killed_at_first_checkpoint("gail", monkeypatch, total_timesteps=64,
                                            eval_episodes=1, run_dir=str(tmp_path))
    assert load(folder)["global_step"] == 32

    def adam_steps(checkpoint: dict) -> tuple[int, int]:
        """Updates so far of the generator's and the discriminator's optimizers."""
        return tuple(int(next(iter(checkpoint[key]["state"].values()))["step"])
                     for key in ("optimizer", "disc_optimizer"))

    # Resumed as configured: one more iteration. Per iteration the generator takes 4 epochs × 2
    # minibatches = 8 Adam steps and the discriminator 1 × 2 = 2, counted on from the checkpoint.
    run("gail", resume=str(folder))
    assert f"resumed {folder.name} at step 32" in capsys.readouterr().out
    finished = load(folder)
    assert finished["global_step"] == 64 and adam_steps(finished) == (16, 4)
    assert evaluation(folder)["global_step"] == 64

    # A raised budget trains on from step 64; the saved settings (1 evaluation episode) hold.
    run("gail", resume=str(folder / "checkpoint.pt"), total_timesteps=128)
    assert f"resumed {folder.name} at step 64" in capsys.readouterr().out
    raised = load(folder)
    assert raised["global_step"] == 128 and adam_steps(raised) == (32, 8)
    summary = evaluation(folder)
    assert summary["global_step"] == 128 and summary["episodes"] == 1

    # A bare --resume of the finished run keeps its budget: it trains no further, and the
    # checkpoint it writes again holds exactly the networks and optimizers it loaded.
    run("gail", resume=str(folder))
    assert f"resumed {folder.name} at step 128" in capsys.readouterr().out
    again = load(folder)
    for key in ("agent", "discriminator", "optimizer", "disc_optimizer", "global_step"):
        assert_same(again[key], raised[key])
    assert evaluation(folder)["global_step"] == 128


@pytest.mark.parametrize("script", ["bc", "gail"])
def test_a_bad_resume_path_is_named(script, tmp_path):
    module = SCRIPTS[script]

    def resume(path) -> None:
        module.main(module.Args(resume=str(path), run_dir=str(tmp_path / "runs")))

    missing = tmp_path / "missing.pt"
    with pytest.raises(FileNotFoundError, match=f"no checkpoint at {re.escape(str(missing))}"):
        resume(missing)
    with pytest.raises(FileNotFoundError,
                       match=re.escape(f"no checkpoint at {tmp_path / 'checkpoint.pt'}")):
        resume(tmp_path)  # a folder without a checkpoint
    (tmp_path / "notes.pt").write_text("not a checkpoint")
    with pytest.raises(ValueError, match=f"{re.escape(str(tmp_path / 'notes.pt'))} is not a "
                                         "checkpoint routine-gym reads"):
        resume(tmp_path / "notes.pt")
    torch.save({"model": {}, "step": 3}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match=f"other.pt is not a checkpoint of {script}.py"):
        resume(tmp_path / "other.pt")
    assert not (tmp_path / "runs").exists()  # rejected before a run folder is made
