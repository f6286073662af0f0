"""A training run whose loss, gradient or parameters stop being numbers stops with one line
(routine_gym/plumbing/divergence.py), in every script of `algos/`: exit code 3, no eval.json,
the last checkpoint as it was (issue 46: `--reward-scale 1e30` trained on infinite losses and
exited 0 with a normal-looking eval.json; `--learning-rate 1e30` died with a traceback)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch
from one_line import stderr_lines
from script_loader import ALGOS

from routine_gym.plumbing.divergence import (
    EXIT_CODE,
    TrainingDiverged,
    as_divergence,
    check_parameters,
    check_update,
)

BIN = Path(sys.executable).parent
INF, NAN = float("inf"), float("nan")


def test_a_finite_update_passes():
    check_update(3, torch.tensor(2.5), torch.tensor(0.4), parts={"value loss": 1.0})
    check_update(3, torch.tensor(2.5))


def test_the_first_non_finite_part_of_the_loss_is_named_with_the_step():
    with pytest.raises(TrainingDiverged) as stopped:
        check_update(2_048, torch.tensor(NAN), torch.tensor(1.0),
                     parts={"policy loss": torch.tensor(0.1), "value loss": torch.tensor(INF)})
    assert str(stopped.value).startswith("training stopped at step 2,048: the value loss is inf")
    assert (stopped.value.what, stopped.value.step) == ("the value loss is inf", 2_048)


def test_a_non_finite_loss_without_parts_is_named_the_loss():
    with pytest.raises(TrainingDiverged, match="at gradient step 7: the loss is nan"):
        check_update(7, torch.tensor(NAN), unit="gradient step")


def test_a_finite_loss_with_a_non_finite_gradient_names_the_gradient_norm():
    with pytest.raises(TrainingDiverged, match="at step 5: the gradient norm is inf"):
        check_update(5, torch.tensor(1.0), torch.tensor(INF), parts={"value loss": 1.0})


def test_a_non_finite_parameter_or_optimizer_state_is_named():
    model = torch.nn.Linear(2, 1)
    optimizer = torch.optim.Adam(model.parameters())
    model(torch.ones(1, 2)).sum().backward()
    optimizer.step()
    check_parameters(10, {"model": model, "optimizer": optimizer})
    with torch.no_grad():
        model.bias.fill_(INF)
    with pytest.raises(TrainingDiverged, match="at step 10: model's bias holds a non-finite"):
        check_parameters(10, {"model": model, "optimizer": optimizer})
    with torch.no_grad():
        model.bias.fill_(0.0)
    optimizer.state_dict()  # the optimizer's state is checked too
    optimizer.state[model.weight]["exp_avg"].fill_(NAN)
    with pytest.raises(TrainingDiverged, match="optimizer's state.0.exp_avg holds"):
        check_parameters(10, {"model": model, "optimizer": optimizer})


def test_torchs_refusal_to_sample_overflowed_probabilities_is_a_divergence():
    with pytest.raises(RuntimeError) as refused:
        torch.multinomial(torch.tensor([[NAN, 1.0]]), 1)
    diverged = as_divergence(refused.value, 160)
    assert diverged is not None
    assert str(diverged).startswith("training stopped at the rollout after step 160: the "
                                    "policy's action probabilities are not finite")
    assert as_divergence(RuntimeError("something else"), 160) is None
    assert as_divergence(ValueError(str(refused.value)), 160) is None


# -- every script, as a user runs it ---------------------------------------------------------

COMMON = ("--env-id", "MiniQbert-v0", "--eval-episodes", "1", "--run-dir", "runs",
          "--torch-threads", "1")
#: A command of each script whose training goes non-finite within a few seconds.
DIVERGING = {
    "rapl_a2c": ("--mode", "a2c", "--total-timesteps", "3000", "--reward-scale", "1e30"),
    "rapl_ppo": ("--mode", "ppo", "--total-timesteps", "3000", "--reward-scale", "1e30"),
    "option_critic": ("--total-timesteps", "3000", "--reward-scale", "1e30"),
    "compile_a2c": ("--total-timesteps", "3000", "--reward-scale", "1e30",
                    "--compile-iterations", "5", "--compile-option-steps", "5"),
    "bc": ("--gradient-steps", "200", "--batch-size", "8", "--learning-rate", "3e38"),
    "rapl_sqil": ("--total-timesteps", "600", "--learning-starts", "100", "--batch-size", "8",
                  "--num-routines", "2",
                  "--learning-rate", "1e30"),
    "gail": ("--total-timesteps", "640", "--num-envs", "2", "--num-steps", "16",
             "--num-minibatches", "2", "--disc-minibatches", "2", "--learning-rate", "1e30"),
}


def user(script: str, *words: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    return subprocess.run([str(BIN / "python"), str(ALGOS / f"{script}.py"), *words], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)


def assert_stopped(proc: subprocess.CompletedProcess, script: str) -> str:
    lines = stderr_lines(proc.stderr)
    assert proc.returncode == EXIT_CODE == 3, (proc.returncode, proc.stderr[-3000:])
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert lines[0].startswith(f"{script}.py: error: training stopped at "), lines[0]
    assert "the last checkpoint, if any, is intact" in lines[0]
    return lines[0]


def test_every_training_script_has_a_diverging_command_here():
    assert set(DIVERGING) == {path.stem for path in ALGOS.glob("*.py")}


@pytest.mark.parametrize("script", sorted(DIVERGING))
def test_a_diverging_run_stops_with_one_line_and_no_result(script, tmp_path):
    line = assert_stopped(user(script, *COMMON, *DIVERGING[script], cwd=tmp_path), script)
    assert any(word in line for word in (" is inf", " is nan", "non-finite", "not finite"))
    # No result that looks like success; the run's TensorBoard curves stay for a look.
    (run,) = (tmp_path / "runs").iterdir()
    assert not (run / "eval.json").exists()
    assert any(p.name.startswith("events.out.tfevents.") for p in run.iterdir())


def test_a_learning_rate_that_overflows_the_policy_stops_with_one_line(tmp_path):
    # The weights stay finite (1e30) but the logits overflow: torch refuses to sample.
    proc = user("rapl_a2c", *COMMON, "--mode", "a2c", "--env-id", "MinAtar/Breakout-v1",
                "--total-timesteps", "20000", "--learning-rate", "1e30", cwd=tmp_path)
    line = assert_stopped(proc, "rapl_a2c")
    assert "action probabilities are not finite" in line or " is " in line


def test_the_last_good_checkpoint_is_left_as_it_was(tmp_path):
    # Breakout's first reward comes after a few rollouts of 2 envs: checkpoints before it.
    proc = user("rapl_a2c", *COMMON, "--env-id", "MinAtar/Breakout-v1", "--mode", "a2c",
                "--num-envs", "2", "--total-timesteps", "5000", "--reward-scale", "1e30",
                "--checkpoint-every", "10", cwd=tmp_path)
    line = assert_stopped(proc, "rapl_a2c")
    stopped_at = int(line.split("training stopped at step ")[1].split(":")[0].replace(",", ""))
    (run,) = (tmp_path / "runs").iterdir()
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    assert 0 < state["global_step"] < stopped_at
    for key, tensor in state["model"].items():
        assert torch.isfinite(tensor).all(), key
    # It resumes from there (other episodes: its env seeds follow the step) and stops again
    # with one line, its checkpoints still finite ones of before the new stop.
    again = assert_stopped(user("rapl_a2c", "--resume", str(run), cwd=tmp_path), "rapl_a2c")
    stopped_again = int(again.split("stopped at step ")[1].split(":")[0].replace(",", ""))
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    assert state["global_step"] < stopped_again and not (run / "eval.json").exists()
    for key, tensor in state["model"].items():
        assert torch.isfinite(tensor).all(), key
