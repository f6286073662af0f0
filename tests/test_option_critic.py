"""The option-critic baseline: its targets and gradients worked by hand, and the script on
every env family, killed and resumed."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import torch
from resume_checks import kill_after_first_checkpoint
from script_loader import load_script

from routine_gym.baselines.option_critic import (
    choose_options,
    option_returns,
    termination_advantage,
    value_upon_arrival,
)


@pytest.fixture(scope="module")
def option_critic():
    yield load_script("option_critic", "option_critic")
    sys.modules.pop("option_critic", None)


# -- the targets -------------------------------------------------------------------------------


def test_value_upon_arrival_mixes_the_option_and_the_best_one_by_beta():
    # Row 0, option 1: (1 − 0.2)·4 + 0.2·max(1, 4, 2) = 3.2 + 0.8 = 4.0 (it is the best).
    # Row 1, option 0: (1 − 0.5)·1 + 0.5·5 = 0.5 + 2.5 = 3.0.
    # Row 2, option 2, β = 1: the option surely ends, U = max Q = 7.
    q = torch.tensor([[1.0, 4.0, 2.0], [1.0, 5.0, 0.0], [7.0, 0.0, 3.0]])
    beta = torch.tensor([[0.9, 0.2, 0.9], [0.5, 0.0, 0.0], [0.0, 0.0, 1.0]])
    u = value_upon_arrival(q, beta, torch.tensor([1, 0, 2]))
    assert u.tolist() == pytest.approx([4.0, 3.0, 7.0])


def test_option_returns_discount_once_per_step_and_stop_at_episode_ends():
    # γ = 0.9, two envs, three steps, U(s_3) = [10, 20]. Env 0 never ends:
    # G_2 = 1 + 0.9·10 = 10, G_1 = 0 + 0.9·10 = 9, G_0 = 2 + 0.9·9 = 10.1.
    # Env 1 ends at step 1: G_2 = 3 + 0.9·20 = 21, G_1 = 1 (no bootstrap), G_0 = 0 + 0.9·1 = 0.9.
    rewards = np.array([[2.0, 0.0], [0.0, 1.0], [1.0, 3.0]])
    dones = np.array([[False, False], [False, True], [False, False]])
    returns = option_returns(rewards, dones, np.array([10.0, 20.0]), gamma=0.9)
    np.testing.assert_allclose(returns, [[10.1, 0.9], [9.0, 1.0], [10.0, 21.0]])


def test_the_termination_gradient_ends_worse_options_and_keeps_good_ones():
    # β_ω(s') = σ(x). Option 0's value 1 is 2 below the best (3): advantage 1 − 3 + 0.01 = −1.99,
    # so the loss β·adv falls as β rises: d loss / d x = adv·σ(x)(1 − σ(x)) = −1.99·0.25 < 0.
    # Option 1 is the best: advantage +0.01, a small push towards going on.
    q_next = torch.tensor([[1.0, 3.0], [1.0, 3.0]])
    options = torch.tensor([0, 1])
    advantage = termination_advantage(q_next, options, deliberation_cost=0.01)
    assert advantage.tolist() == pytest.approx([-1.99, 0.01])
    x = torch.zeros(2, requires_grad=True)
    loss = (torch.sigmoid(x) * advantage).sum()
    loss.backward()
    assert x.grad.tolist() == pytest.approx([-1.99 * 0.25, 0.01 * 0.25])
    # One step of gradient descent raises option 0's termination and lowers option 1's.
    with torch.no_grad():
        after = torch.sigmoid(x - 1.0 * x.grad)
    assert after[0] > 0.5 > after[1]


def test_options_go_on_unless_they_end_and_are_then_chosen_epsilon_greedily():
    q = np.array([[0.0, 2.0, 1.0]] * 4)
    current = np.array([0, 0, 2, 2])
    terminate = np.array([False, True, False, True])
    greedy = choose_options(q, current, terminate, 0.0, np.random.default_rng(1))
    assert greedy.tolist() == [0, 1, 2, 1]
    # ε = 1: every chosen option is uniform; over many draws all three appear, the running
    # ones stay.
    rng = np.random.default_rng(2)
    drawn = [choose_options(q, current, terminate, 1.0, rng) for _ in range(200)]
    assert {int(d[1]) for d in drawn} == {0, 1, 2}
    assert all(d[0] == 0 and d[2] == 2 for d in drawn)


# -- the script -----------------------------------------------------------------------------


@pytest.mark.parametrize("env_id", [
    "CartPole-v1", "MiniQbert-v0", "MinAtar/Breakout-v1",
    pytest.param("ALE/Qbert-v5", marks=pytest.mark.slow),
    pytest.param("procgen/CoinRun-v0", marks=pytest.mark.slow),
])
def test_option_critic_runs_on_every_env_family(option_critic, env_id, tmp_path):
    summary = option_critic.main(option_critic.Args(
        env_id=env_id, num_envs=2, total_timesteps=60, eval_episodes=1, log_every=20,
        run_dir=str(tmp_path), torch_threads=1,
    ))
    assert summary["method"] == "option-critic" and summary["global_step"] == 60
    assert summary["episodes"] == 1 and len(summary["returns"]) == 1
    (folder,) = tmp_path.iterdir()
    saved = json.loads((folder / "eval.json").read_text())
    assert saved["env_id"] == env_id and saved == json.loads(json.dumps(summary))


def test_option_critic_logs_option_usage_and_duration(option_critic, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    option_critic.main(option_critic.Args(
        env_id="CartPole-v1", num_envs=4, total_timesteps=2000, eval_episodes=0,
        log_every=500, run_dir=str(tmp_path), torch_threads=1,
    ))
    (folder,) = tmp_path.iterdir()
    events = EventAccumulator(str(folder))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {f"options/usage_{k}" for k in range(4)} <= tags
    assert {"options/duration", "losses/termination_loss", "charts/episodic_return"} <= tags
    usage = sum(events.Scalars(f"options/usage_{k}")[-1].value for k in range(4))
    assert usage == pytest.approx(1.0)
    assert all(d.value >= 1.0 for d in events.Scalars("options/duration"))


def test_bad_option_settings_are_named(option_critic, tmp_path):
    with pytest.raises(ValueError, match="--num-options needs to be ≥ 1, actual value: 0"):
        option_critic.main(option_critic.Args(env_id="CartPole-v1", num_options=0,
                                              run_dir=str(tmp_path)))
    with pytest.raises(ValueError, match=r"--option-epsilon needs to be in \[0, 1\]"):
        option_critic.main(option_critic.Args(env_id="CartPole-v1", option_epsilon=1.5,
                                              run_dir=str(tmp_path)))


def test_killed_option_critic_resumes_and_finishes(option_critic, tmp_path, repo_root, capsys):
    # Every iteration is num_envs · num_steps = 2 · 5 = 10 steps: checkpoints at multiples of
    # 500, the run ends exactly at 4000.
    command = [
        sys.executable, str(repo_root / "algos" / "option_critic.py"), "--env-id", "CartPole-v1",
        "--num-envs", "2", "--total-timesteps", "4000", "--checkpoint-every", "500",
        "--eval-episodes", "0", "--run-dir", str(tmp_path), "--torch-threads", "1",
    ]
    checkpoint_path = kill_after_first_checkpoint(command, tmp_path)
    killed_at = torch.load(checkpoint_path, weights_only=True)["global_step"]
    assert killed_at % 500 == 0 and 500 <= killed_at < 4000
    option_critic.main(option_critic.Args(resume=str(checkpoint_path.parent)))
    assert f"resumed {checkpoint_path.parent.name} at step {killed_at}" in capsys.readouterr().out
    final = torch.load(checkpoint_path, weights_only=True)
    assert final["global_step"] == 4000 and final["iteration"] == 400
