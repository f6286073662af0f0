"""Issue 49's mechanisms that pass what a routine did on to the primitive policy
(`routine_gym.intra_routine`): intra-routine policy learning (`--intra-coef`) and a routine's
logit started at its first primitive's (`--routine-logit first-action`), by hand and as a user
runs them."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from one_line import assert_one_line_error
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from routine_gym.intra_routine import (
    first_action_logits,
    inner_actions,
    intra_routine_loss,
    intra_routine_ppo_loss,
    routine_table,
)
from routine_gym.returns import inner_states_and_targets, primitive_returns

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
SCRIPTS = {"a2c": str(REPO / "algos" / "rapl_a2c.py"), "ppo": str(REPO / "algos" / "rapl_ppo.py")}


def user(*words, cwd, timeout=300):
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8"}
    words = [str(BIN / "python") if w == "python" else str(w) for w in words]
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, stdin=subprocess.DEVNULL)


# -- a routine of length 3, by hand ------------------------------------------------------------
# |A| = 2 primitives and one routine (1, 0, 1), called once (decision 0, ℓ = 3), rewards 1, 0, 2,
# γ = 0.5, V(state after the routine) = 4 bootstraps the rollout. Returns from each primitive
# step: G_2 = 2 + 0.5·4 = 4, G_1 = 0 + 0.5·4 = 2, G_0 = 1 + 0.5·2 = 2. The inner states s_1, s_2
# have values 1 and 3: A_prim = 2 − 1 = 1 and 4 − 3 = 1. The policy's logits there: [0, 0, 0]
# (π(a_1 = 0) = 1/3) and [ln 2, 0, 0] (π(a_2 = 1) = 1/4).

def _length_three():
    rewards = np.array([[[1.0], [0.0], [2.0]]])  # [N=1, L=3, E=1]
    lengths = np.array([[3]])
    prim = primitive_returns(rewards, lengths, np.zeros((1, 1), bool), np.zeros((1, 1), bool),
                             np.zeros((1, 1)), np.array([4.0]), 0.5)
    inner_obs = np.array([[[[10.0]], [[20.0]]]])  # [N, L − 1, E, 1]: s_1, s_2
    states, targets = inner_states_and_targets(inner_obs, prim, lengths)
    taken = inner_actions(np.array([[2]]), lengths, routine_table([(1, 0, 1)]), 2)
    return prim, states, targets, taken


def test_a_length_three_routine_gives_its_inner_states_returns_and_actions():
    prim, states, targets, taken = _length_three()
    assert prim[0, :, 0].tolist() == [2.0, 2.0, 4.0]
    assert states.tolist() == [[10.0], [20.0]]
    assert targets.tolist() == [2.0, 4.0]
    assert taken.tolist() == [0, 1]  # the routine's steps 1 and 2


def test_the_intra_routine_loss_of_a_length_three_routine_by_hand():
    _, _, targets, taken = _length_three()
    advantages = torch.as_tensor(targets, dtype=torch.float32) - torch.tensor([1.0, 3.0])
    logits = torch.tensor([[0.0, 0.0, 0.0], [math.log(2.0), 0.0, 0.0]], requires_grad=True)
    logprobs = torch.log_softmax(logits, -1).gather(1, torch.as_tensor(taken)[:, None])[:, 0]
    loss = intra_routine_loss(logprobs, advantages)
    # −½ [ (1/3)·1·ln(1/3) + (1/4)·1·ln(1/4) ] = ½ [ (ln 3)/3 + (ln 4)/4 ]
    assert loss.item() == pytest.approx(0.5 * (math.log(3) / 3 + math.log(4) / 4), rel=1e-6)
    loss.backward()
    # ∂/∂z at s_1: −½ · ρ̄ · A · (onehot(0) − π) = −(1/6) · [2/3, −1/3, −1/3]
    assert logits.grad[0].tolist() == pytest.approx([-1 / 9, 1 / 18, 1 / 18], rel=1e-6)
    # at s_2: −½ · (1/4) · 1 · (onehot(1) − [1/2, 1/4, 1/4]) = −(1/8) · [−1/2, 3/4, −1/4]
    assert logits.grad[1].tolist() == pytest.approx([1 / 16, -3 / 32, 1 / 32], rel=1e-6)


def test_the_importance_weight_is_clipped_and_constant():
    logprobs = torch.tensor([0.0], requires_grad=True)  # π(a) = 1: ρ̄ = min(0.5, 1) = 0.5
    intra_routine_loss(logprobs, torch.tensor([3.0]), clip=0.5).backward()
    assert logprobs.grad.tolist() == [-1.5]  # −ρ̄ Â, ρ̄ held constant
    empty = torch.zeros(0, requires_grad=True)
    assert intra_routine_loss(empty, torch.zeros(0)).item() == 0.0


def test_the_ppo_form_has_the_a2c_gradient_at_the_old_policy_and_clips_away_from_it():
    old = torch.log(torch.tensor([1 / 3, 1 / 4]))
    advantages = torch.tensor([1.0, 1.0])
    new_a = old.clone().requires_grad_(True)
    new_b = old.clone().requires_grad_(True)
    intra_routine_ppo_loss(new_a, old, advantages, 0.2).backward()
    intra_routine_loss(new_b, advantages).backward()
    assert new_a.grad.tolist() == pytest.approx(new_b.grad.tolist())
    # r = 1.5 on a positive advantage: clipped at 1.2, no gradient
    far = (old + math.log(1.5)).requires_grad_(True)
    loss = intra_routine_ppo_loss(far, old, advantages, 0.2)
    loss.backward()
    assert far.grad.tolist() == [0.0, 0.0]
    assert loss.item() == pytest.approx(-(1.2 / 3 + 1.2 / 4) / 2)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_inner_actions_follow_the_routines_step_by_step(data):
    """Against a plain loop over decisions, then steps, then envs."""
    num_primitives = data.draw(st.integers(1, 4))
    routines = data.draw(st.lists(st.lists(st.integers(0, num_primitives - 1), min_size=2,
                                           max_size=5), min_size=1, max_size=3))
    n, e = data.draw(st.integers(1, 4)), data.draw(st.integers(1, 3))
    actions = np.array(data.draw(st.lists(st.integers(0, num_primitives + len(routines) - 1),
                                          min_size=n * e, max_size=n * e))).reshape(n, e)
    lengths = np.ones((n, e), dtype=np.int64)
    for i in range(n):
        for j in range(e):
            if actions[i, j] >= num_primitives:
                full = len(routines[actions[i, j] - num_primitives])
                lengths[i, j] = data.draw(st.integers(1, full))
    expected = [routines[actions[i, k] - num_primitives][j]
                for i in range(n) for j in range(1, 5) for k in range(e)
                if j < lengths[i, k]]
    got = inner_actions(actions, lengths, routine_table(routines), num_primitives)
    assert got.tolist() == expected


def test_a_routine_logit_is_its_first_primitive_logit_plus_its_own():
    z = torch.tensor([[1.0, 2.0, 3.0, 0.5, -1.0], [0.0, -2.0, 1.0, 0.0, 0.0]],
                     requires_grad=True)
    out = first_action_logits(z, torch.tensor([2, 0]), 3)
    assert out.tolist() == [[1.0, 2.0, 3.0, 3.5, 0.0], [0.0, -2.0, 1.0, 1.0, 0.0]]
    out[0, 3].backward()  # the routine's logit moves with its first primitive's and its own
    assert z.grad[0].tolist() == [0.0, 0.0, 1.0, 1.0, 0.0]


# -- as a user runs them -----------------------------------------------------------------------

BREAKOUT = ["--env-id", "MinAtar/Breakout-v1", "--num-envs", "4", "--eval-episodes", "1",
            "--checkpoint-every", "0", "--torch-threads", "1"]


def _tags(run_dir: Path) -> dict[str, list[float]]:
    (folder,) = [p for p in run_dir.iterdir() if p.is_dir()]
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    events.Reload()
    return {t: [s.value for s in events.Scalars(t)] for t in events.Tags()["scalars"]}


# --intra-coef with either reading of the routines' logits: its inner actions must come from
# the routine each decision called (Breakout's routines have lengths 4, 3 and 6; a call of the
# 6-step one read as another routine takes a padding action and crashes).
@pytest.mark.parametrize("script, logit", [("a2c", "first-action"), ("ppo", "free"),
                                           ("ppo", "first-action")])
def test_intra_coef_trains_on_minatar_and_logs_the_intra_loss(tmp_path, script, logit):
    proc = user("python", SCRIPTS[script], *BREAKOUT, "--mode", "rapl", "--intra-coef", "0.5",
                "--routine-logit", logit, "--total-timesteps", "3000",
                "--scalars-every", "1", "--run-dir", tmp_path / "runs", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    tags = _tags(tmp_path / "runs")
    assert tags["losses/intra_loss"] and all(math.isfinite(v) for v in tags["losses/intra_loss"])
    assert any(v != 0.0 for v in tags["losses/intra_loss"])  # routines ran: inner states
    assert list((tmp_path / "runs").glob("*/eval.json"))


@pytest.mark.parametrize("script", ["a2c", "ppo"])
def test_without_the_flags_no_intra_loss_is_logged(tmp_path, script):
    proc = user("python", SCRIPTS[script], *BREAKOUT, "--mode", "rapl", "--total-timesteps",
                "600", "--run-dir", tmp_path / "runs", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "losses/intra_loss" not in _tags(tmp_path / "runs")


@pytest.mark.parametrize("script, flags, message", [
    ("a2c", ["--intra-coef", "-1"], "--intra-coef needs to be ≥ 0, actual value: -1"),
    ("a2c", ["--intra-coef", "1", "--mode", "macro"],
     "--intra-coef needs to be 0 unless --mode rapl"),
    ("a2c", ["--intra-coef", "1", "--authors"],
     "--intra-coef needs to be 0 with --prim-states first-n"),
    ("a2c", ["--routine-logit", "first-action", "--mode", "a2c"],
     "--routine-logit needs to be free with --mode a2c"),
    ("a2c", ["--routine-logit", "first"], "--routine-logit"),
    ("ppo", ["--intra-coef", "-0.5"], "--intra-coef needs to be ≥ 0, actual value: -0.5"),
    ("ppo", ["--intra-coef", "1", "--mode", "macro"],
     "--intra-coef needs to be 0 unless --mode rapl"),
    ("ppo", ["--routine-logit", "first-action", "--mode", "ppo"],
     "--routine-logit needs to be free with --mode ppo"),
])
def test_bad_mechanism_flags_are_one_line_errors(tmp_path, script, flags, message):
    proc = user("python", SCRIPTS[script], "--env-id", "MinAtar/Breakout-v1",
                "--total-timesteps", "20000", *flags, cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
