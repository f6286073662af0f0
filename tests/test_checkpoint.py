"""The checkpoint files every training script writes and `--resume` reads."""

from __future__ import annotations

import pytest
import torch

from routine_gym.plumbing.checkpoint import CHECKPOINT_NAME, load_checkpoint, write_checkpoint


def test_a_checkpoint_round_trips_from_its_file_or_its_run_folder(tmp_path):
    state = {"model": {"w": torch.arange(3.0)}, "global_step": 42, "args": "{}"}
    write_checkpoint(state, tmp_path / CHECKPOINT_NAME)
    assert sorted(p.name for p in tmp_path.iterdir()) == [CHECKPOINT_NAME]  # no .tmp left
    for resume in (tmp_path, tmp_path / CHECKPOINT_NAME):
        path, loaded = load_checkpoint(resume, ["model", "global_step"], "test.py")
        assert path == str(tmp_path / CHECKPOINT_NAME)
        assert loaded["global_step"] == 42 and torch.equal(loaded["model"]["w"], torch.arange(3.0))


def test_every_wrong_resume_path_names_the_path(tmp_path):
    with pytest.raises(FileNotFoundError, match=f"--resume {tmp_path}: no checkpoint at"):
        load_checkpoint(tmp_path, [], "test.py")
    (tmp_path / "notes.txt").write_text("not a checkpoint")
    with pytest.raises(ValueError, match="notes.txt is not a checkpoint routine-gym reads"):
        load_checkpoint(tmp_path / "notes.txt", [], "test.py")
    write_checkpoint({"model": {}}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="other.pt is not a checkpoint of test.py "
                                         r"\(missing global_step, rng\)"):
        load_checkpoint(tmp_path / "other.pt", ["model", "rng", "global_step"], "test.py")


def test_resume_settings_keep_the_saved_run_and_apply_the_budget_rule(tmp_path):
    import dataclasses
    import json

    from routine_gym.plumbing.checkpoint import resume_settings

    @dataclasses.dataclass
    class Args:
        total_timesteps: int = 1000
        seed: int = 1
        resume: str | None = None

    run = tmp_path / "runs" / "my_run"
    run.mkdir(parents=True)
    saved = json.dumps(dataclasses.asdict(Args(total_timesteps=300, seed=7)))
    write_checkpoint({"args": saved, "step": 200}, run / CHECKPOINT_NAME)

    def resume(total_timesteps: int, **kwargs) -> Args:
        args, checkpoint, run_path = resume_settings(
            Args(total_timesteps=total_timesteps, resume=str(run)), ["step"], "x.py", **kwargs)
        assert checkpoint["step"] == 200 and run_path == str(run)
        assert args.seed == 7 and args.resume == str(run / CHECKPOINT_NAME)  # saved settings
        return args

    assert resume(1000).total_timesteps == 300  # the default: a bare --resume keeps 300
    assert resume(500).total_timesteps == 500  # raised
    assert resume(250).total_timesteps == 300  # never lowered ...
    assert resume(250, lower_budget=True).total_timesteps == 250  # ... unless the script says
    # A flag that contradicts the saved run is refused, not silently ignored.
    with pytest.raises(ValueError, match="started with --seed 7, not 99; drop the flag"):
        resume_settings(Args(seed=99, resume=str(run)), ["step"], "x.py")
