"""RAPL-PPO (`algos/rapl_ppo.py`, `routine_gym/ppo.py`): the maths on hand-worked numbers, the
family defaults, every mode on every kind of env with tiny budgets, and kill-and-`--resume`.

The script runs in-process (`main(Args(...))`, as tests/test_rapl_a2c.py runs rapl_a2c.py);
only the kill test starts it as a subprocess, from its command line.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from resume_checks import assert_same, kill_after_first_checkpoint
from script_loader import load_script

import routine_gym  # noqa: F401  (registers MiniQbert, CoinRun, MinAtar and the ALE envs)
from routine_gym.demo import record_agent_demo
from routine_gym.envs.factory import default_env_kwargs
from routine_gym.errors import UsageError
from routine_gym.library import RoutineLibrary
from routine_gym.plumbing.run import Run
from routine_gym.ppo import (
    clipped_policy_loss,
    clipped_value_loss,
    inner_lambda_returns,
    inner_state_shares,
    normalize_advantages,
    routine_trace_decay,
    smdp_gae,
)
from routine_gym.returns import (
    decision_returns,
    primitive_returns,
    routine_reward_and_discount,
)

pytestmark = pytest.mark.filterwarnings(
    "ignore:the demo yields .* routine\\(s\\):UserWarning",  # MiniQbert's demo gives 2 of 3
    "ignore::DeprecationWarning",
)

MODES = ("ppo", "rapl", "macro")
F, T = False, True


def col(*values) -> np.ndarray:
    """A `[N, 1]` array: one env."""
    return np.array(values, dtype=np.float64)[:, None]


# -- SMDP GAE ------------------------------------------------------------------------------


def cleanrl_gae(rewards, values, dones, next_value, next_done, gamma, lam):
    """The loop of CleanRL's ppo_atari.py: `dones[t]` says observation t starts a new episode
    (the step before it ended one), `next_done` the same of the observation after the rollout."""
    advantages = np.zeros_like(rewards)
    lastgaelam = 0.0
    for t in reversed(range(len(rewards))):
        if t == len(rewards) - 1:
            nextnonterminal, nextvalues = 1.0 - next_done, next_value
        else:
            nextnonterminal, nextvalues = 1.0 - dones[t + 1], values[t + 1]
        delta = rewards[t] + gamma * nextvalues * nextnonterminal - values[t]
        advantages[t] = lastgaelam = delta + gamma * lam * nextnonterminal * lastgaelam
    return advantages


def test_smdp_gae_of_primitive_decisions_is_cleanrls_gae():
    # Hand-worked, γ = λ = 0.5: rewards 1 2 4, values 1 2 3, V(after) = 4.
    #   δ_2 = 4 + .5·4 − 3 = 3                 A_2 = 3
    #   δ_1 = 2 + .5·3 − 2 = 1.5               A_1 = 1.5 + .25·3 = 2.25
    #   δ_0 = 1 + .5·2 − 1 = 1                 A_0 = 1 + .25·2.25 = 1.5625
    no = np.zeros((3, 1), dtype=bool)
    half = np.full((3, 1), 0.5)
    adv, ret = smdp_gae(col(1, 2, 4), half, half, col(1, 2, 3), no, no, np.zeros((3, 1)),
                        np.array([4.0]))
    assert adv.ravel().tolist() == [1.5625, 2.25, 3.0]
    assert ret.ravel().tolist() == [2.5625, 4.25, 6.0]

    # Random rollouts with episode ends, every routine of length 1: CleanRL's numbers, bit for
    # bit (same operations in the same order).
    rng = np.random.default_rng(0)
    n, e, gamma, lam = 7, 5, 0.99, 0.95
    rewards, values = rng.normal(size=(n, e)), rng.normal(size=(n, e))
    ended = rng.random((n, e)) < 0.3
    bootstrap = rng.normal(size=e)
    lengths = np.ones((n, e), dtype=np.int64)
    R, discounts = routine_reward_and_discount(rewards[:, None, :], lengths, gamma)
    adv, ret = smdp_gae(R, discounts, routine_trace_decay(lengths, lam), values, ended,
                        np.zeros_like(ended), rng.normal(size=(n, e)), bootstrap)
    dones = np.concatenate([np.zeros((1, e)), ended[:-1]]).astype(np.float64)
    expected = cleanrl_gae(rewards, values, dones, bootstrap, ended[-1].astype(np.float64),
                           gamma, lam)
    np.testing.assert_array_equal(adv, expected)
    np.testing.assert_array_equal(ret, expected + values)


def test_across_a_routine_the_trace_decays_by_gamma_lambda_to_its_length():
    # γ = λ = 0.5. Decisions of length 2, 1, 3 with step rewards [1, 2], [4], [1, 0, 8]:
    #   R = 1 + .5·2 = 2, 4, 1 + 0 + .25·8 = 3;  Γ = γ^ℓ = .25, .5, .125;  Λ = λ^ℓ = .25, .5, .125
    # values 1 2 4, V(after) = 16:
    #   δ_2 = 3 + .125·16 − 4 = 1              A_2 = 1
    #   δ_1 = 4 + .5·4 − 2 = 4                 A_1 = 4 + (.5·.5)·1 = 4.25
    #   δ_0 = 2 + .25·2 − 1 = 1.5              A_0 = 1.5 + (.25·.25)·4.25 = 1.765625
    # (one λ per decision would give A_0 = 1.5 + (.25·.5)·4.25 = 2.03125)
    step_rewards = np.array([[1.0, 2.0, 0.0], [4.0, 0.0, 0.0], [1.0, 0.0, 8.0]])[:, :, None]
    lengths = np.array([[2], [1], [3]])
    R, discounts = routine_reward_and_discount(step_rewards, lengths, 0.5)
    traces = routine_trace_decay(lengths, 0.5)
    assert R.ravel().tolist() == [2.0, 4.0, 3.0]
    assert traces.ravel().tolist() == discounts.ravel().tolist() == [0.25, 0.5, 0.125]
    no = np.zeros((3, 1), dtype=bool)
    adv, ret = smdp_gae(R, discounts, traces, col(1, 2, 4), no, no, np.zeros((3, 1)),
                        np.array([16.0]))
    assert adv.ravel().tolist() == [1.765625, 4.25, 1.0]
    assert ret.ravel().tolist() == [2.765625, 6.25, 5.0]


def test_smdp_gae_cuts_the_trace_at_termination_and_bootstraps_truncation():
    # The first example's rollout (γ = λ = .5, rewards 1 2 4, values 1 2 3, V(after) 4) with an
    # episode ending during decision 1.
    half, final = np.full((3, 1), 0.5), col(0, 6, 0)
    ended = np.array([[F], [T], [F]])
    no = np.zeros((3, 1), dtype=bool)
    # Terminated: δ_1 = 2 + 0 − 2 = 0, A_1 = 0; A_0 = δ_0 = 1 + .5·2 − 1 = 1 (+ .25·0).
    adv, _ = smdp_gae(col(1, 2, 4), half, half, col(1, 2, 3), ended, no, final, np.array([4.0]))
    assert adv.ravel().tolist() == [1.0, 0.0, 3.0]
    # Truncated with V(final obs) = 6: δ_1 = 2 + .5·6 − 2 = 3, A_1 = 3; A_0 = 1 + .25·3 = 1.75.
    adv, _ = smdp_gae(col(1, 2, 4), half, half, col(1, 2, 3), no, ended, final, np.array([4.0]))
    assert adv.ravel().tolist() == [1.75, 3.0, 3.0]


def random_rollout(rng, n=6, e=4, max_len=4):
    lengths = rng.integers(1, max_len + 1, size=(n, e))
    rewards = rng.normal(size=(n, max_len, e)) * (np.arange(max_len)[None, :, None]
                                                  < lengths[:, None, :])
    terminated = rng.random((n, e)) < 0.2
    truncated = ~terminated & (rng.random((n, e)) < 0.2)
    return (rewards, lengths, terminated, truncated, rng.normal(size=(n, e)),
            rng.normal(size=(n, e)), rng.normal(size=e))


def test_with_lambda_one_the_returns_are_rapl_a2cs():
    rng = np.random.default_rng(1)
    rewards, lengths, term, trunc, final, values, bootstrap = random_rollout(rng)
    R, discounts = routine_reward_and_discount(rewards, lengths, 0.9)
    adv, ret = smdp_gae(R, discounts, routine_trace_decay(lengths, 1.0), values, term, trunc,
                        final, bootstrap)
    np.testing.assert_allclose(ret, decision_returns(R, discounts, term, trunc, final,
                                                     bootstrap), rtol=1e-12, atol=1e-12)
    # λ = 0: the one-step TD error.
    adv0, _ = smdp_gae(R, discounts, routine_trace_decay(lengths, 0.0), values, term, trunc,
                       final, bootstrap)
    following = np.where(term, 0.0, np.where(trunc, final, np.vstack([values[1:], bootstrap])))
    np.testing.assert_allclose(adv0, R + discounts * following - values, rtol=1e-12)


# -- the primitive-level critic targets ------------------------------------------------------


def test_inner_lambda_returns_carry_the_lambda_weights_to_the_routines_end():
    # The rollout of test_across_a_routine_...: γ = λ = .5, values 1 2 4, λ-returns
    # 2.765625 6.25 5, V(after) = G(after) = 16.
    # Decision 0 (ℓ 2), step 1 (k = 1 step left): 2 + .5·[(1 − .5)·V_1 + .5·G_1]
    #   = 2 + .5·(.5·2 + .5·6.25) = 4.0625;  step 0 (k = 2): 1 + .5·2 + .25·(.75·2 + .25·6.25)
    #   = 2.765625, the decision's own λ-return.
    # Decision 2 (ℓ 3): after it V = G = 16, so λ drops out: step 2: 8 + .5·16 = 16;
    #   step 1: 0 + .5·8 + .25·16 = 8; step 0: 5.
    step_rewards = np.array([[1.0, 2.0, 0.0], [4.0, 0.0, 0.0], [1.0, 0.0, 8.0]])[:, :, None]
    lengths = np.array([[2], [1], [3]])
    no = np.zeros((3, 1), dtype=bool)
    G = inner_lambda_returns(step_rewards, lengths, no, no, np.zeros((3, 1)), col(1, 2, 4),
                             col(2.765625, 6.25, 5), np.array([16.0]), 0.5, 0.5)
    assert G[:, :, 0].tolist() == [[2.765625, 4.0625, 0.0], [6.25, 0.0, 0.0], [5.0, 8.0, 16.0]]

    # Decision 0 terminated: its steps return their rewards only (2 + .5·... → 2, 1 + .5·2).
    ended = np.array([[T], [F], [F]])
    G = inner_lambda_returns(step_rewards, lengths, ended, no, col(0, 0, 0), col(1, 2, 4),
                             col(2, 6.25, 5), np.array([16.0]), 0.5, 0.5)
    assert G[0, :, 0].tolist() == [2.0, 2.0, 0.0]
    # Truncated with V(final obs) = 4: 2 + .5·4 = 4 and 1 + .5·2 + .25·4 = 3.
    G = inner_lambda_returns(step_rewards, lengths, no, ended, col(4, 0, 0), col(1, 2, 4),
                             col(3, 6.25, 5), np.array([16.0]), 0.5, 0.5)
    assert G[0, :, 0].tolist() == [3.0, 4.0, 0.0]


def test_inner_lambda_returns_start_from_the_decisions_returns_and_are_rapl_a2cs_at_lambda_one():
    rng = np.random.default_rng(2)
    rewards, lengths, term, trunc, final, values, bootstrap = random_rollout(rng)
    R, discounts = routine_reward_and_discount(rewards, lengths, 0.9)
    for lam in (0.0, 0.7, 1.0):
        _, ret = smdp_gae(R, discounts, routine_trace_decay(lengths, lam), values, term, trunc,
                          final, bootstrap)
        G = inner_lambda_returns(rewards, lengths, term, trunc, final, values, ret, bootstrap,
                                 0.9, lam)
        np.testing.assert_allclose(G[:, 0], ret, rtol=1e-12, atol=1e-12)
        assert np.all(G[np.arange(4)[None, :, None] >= lengths[:, None, :]] == 0)
    np.testing.assert_allclose(
        G, primitive_returns(rewards, lengths, term, trunc, final, bootstrap, 0.9),
        rtol=1e-12, atol=1e-12)


# -- the losses ------------------------------------------------------------------------------


def test_the_clipped_surrogate_takes_the_pessimistic_term():
    # ε = 0.2. A = +1 with ratio 1.5: max(−1.5, −1.2) = −1.2 (the gain is clipped at 1.2);
    # A = −1 with ratio 0.5: max(0.5, 0.8) = 0.8 (the clipped ratio 0.8 is more pessimistic).
    # Mean: −0.2. Inside the range the loss is −A·ratio: −1·1.1 = −1.1.
    a = torch.tensor([1.0, -1.0], dtype=torch.float64)
    old = torch.zeros(2, dtype=torch.float64)
    new = torch.tensor([math.log(1.5), math.log(0.5)], dtype=torch.float64)
    assert clipped_policy_loss(a, new, old, 0.2).item() == pytest.approx(-0.2, abs=1e-12)
    inside = torch.tensor([math.log(1.1)], dtype=torch.float64)
    assert clipped_policy_loss(a[:1], inside, old[:1], 0.2).item() == pytest.approx(-1.1)


def test_the_clipped_value_loss_takes_the_larger_error():
    # ε = 0.2. V 2 (old 1), G 3: unclipped (2 − 3)² = 1, clipped (1 + .2 − 3)² = 3.24 → 3.24.
    # V 0 (old .5), G 0: unclipped 0, clipped (.5 − .2 − 0)² = .09 → .09.
    # 0.5 · mean(3.24, .09) = 0.8325; unclipped: 0.5 · mean(1, 0) = 0.25.
    new, old, G = torch.tensor([2.0, 0.0]), torch.tensor([1.0, 0.5]), torch.tensor([3.0, 0.0])
    assert clipped_value_loss(new, old, G, 0.2).item() == pytest.approx(0.8325)
    assert clipped_value_loss(new, old, G, 0.2, clip=False).item() == pytest.approx(0.25)


def test_advantages_are_normalised_with_the_unbiased_std():
    # mean 2, std √((1 + 1)/1) = √2.
    out = normalize_advantages(torch.tensor([1.0, 3.0], dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [-1 / math.sqrt(2), 1 / math.sqrt(2)], rtol=1e-7)


# -- which epochs train the states inside routines ----------------------------------------------


class Decks:
    """`permutation` for `inner_state_shares`: the states backwards, counting the decks drawn."""

    def __init__(self) -> None:
        self.drawn = 0

    def __call__(self, n: int) -> np.ndarray:
        self.drawn += 1
        return np.arange(n)[::-1]


def test_by_default_the_epochs_split_one_deck_so_each_inner_state_is_trained_once():
    # 6 states, 4 epochs, 1 pass: 6 = 2 + 2 + 1 + 1 (np.array_split's sizes) of one deck.
    decks = Decks()
    shares = [s.tolist() for s in inner_state_shares(6, 4, 1, decks)]
    assert shares == [[5, 4], [3, 2], [1], [0]]
    assert decks.drawn == 1


def test_with_a_pass_per_epoch_each_epoch_draws_its_own_deck_when_it_starts():
    # passes = epochs: every state in every epoch, a fresh deck drawn as each epoch asks for its
    # share (lazily: rapl_ppo.py shuffles the decisions first, so the random draws come in the
    # order the script made them before --prim-epochs existed).
    decks = Decks()
    shares = inner_state_shares(3, 2, 2, decks)
    assert decks.drawn == 0
    assert next(shares).tolist() == [2, 1, 0] and decks.drawn == 1
    assert next(shares).tolist() == [2, 1, 0] and decks.drawn == 2


def test_a_share_runs_on_into_the_next_deck():
    # 5 states, 4 epochs, 2 passes: 10 = 3 + 3 + 2 + 2 from decks [4 3 2 1 0] [4 3 2 1 0].
    decks = Decks()
    shares = [s.tolist() for s in inner_state_shares(5, 4, 2, decks)]
    assert shares == [[4, 3, 2], [1, 0, 4], [3, 2], [1, 0]]
    assert decks.drawn == 2


def test_no_inner_states_draw_nothing_and_bad_passes_are_refused():
    decks = Decks()
    assert [len(s) for s in inner_state_shares(0, 3, 1, decks)] == [0, 0, 0]
    assert decks.drawn == 0
    for passes in (0, 4):
        with pytest.raises(ValueError, match=f"passes must be in \\[1, epochs=3\\], actual "
                                             f"value: {passes}"):
            next(inner_state_shares(5, 3, passes))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 40), st.integers(1, 6), st.data())
def test_each_inner_state_is_trained_passes_times_in_shares_of_even_size(num_inner, epochs, data):
    passes = data.draw(st.integers(1, epochs))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    shares = list(inner_state_shares(num_inner, epochs, passes, rng.permutation))
    assert len(shares) == epochs
    sizes = [len(s) for s in shares]
    assert max(sizes) - min(sizes) <= 1 and sizes == sorted(sizes, reverse=True)
    counts = np.bincount(np.concatenate(shares).astype(np.int64), minlength=num_inner)
    assert counts.tolist() == [passes] * num_inner


# -- the script ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rapl_ppo():
    """The script as a module."""
    yield load_script("rapl_ppo", "rapl_ppo")
    sys.modules.pop("rapl_ppo", None)


@pytest.fixture(scope="module")
def cartpole_demo(tmp_path_factory) -> str:
    rng = np.random.default_rng(0)
    demo = record_agent_demo("CartPole-v1", lambda obs: int(rng.integers(2)), num_episodes=3,
                             env_kwargs=default_env_kwargs("CartPole-v1"), progress=False)
    path = tmp_path_factory.mktemp("demos") / "cartpole.npz"
    demo.save(path, include_observations=False)
    return str(path)


#: Tiny settings: 2 envs × 8 decisions, 2 minibatches, 2 epochs.
TINY = dict(num_envs=2, num_steps=8, num_minibatches=2, update_epochs=2, eval_episodes=0,
            log_every=10**9, torch_threads=1)


def run(module, run_dir: Path, **kwargs) -> Path:
    """`main(Args(...))` with tiny defaults; returns the run folder it created."""
    settings = {**TINY, "total_timesteps": 64, "run_dir": str(run_dir), **kwargs}
    before = set(run_dir.iterdir()) if run_dir.exists() else set()
    module.main(module.Args(**settings))
    (folder,) = set(run_dir.iterdir()) - before
    return folder


def scalars(path: Path) -> dict[str, list[float]]:
    """Every scalar of a run folder's event files, or of one event file, by tag."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(path), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [e.value for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def check_run(folder: Path, mode: str) -> dict[str, list[float]]:
    """The files and the scalars every run leaves."""
    assert (folder / "routines.json").exists() == (mode != "ppo")
    if mode != "ppo":
        assert 1 <= len(RoutineLibrary.load(folder / "routines.json")) <= 3
    logged = scalars(folder)
    for tag in ("charts/SPS", "losses/value_loss", "losses/prim_value_loss",
                "losses/policy_loss", "losses/entropy", "losses/approx_kl", "losses/clipfrac",
                "losses/explained_variance", "charts/learning_rate", "counters/decisions",
                "counters/updates", "counters/steps_per_decision", "counters/primitive_share"):
        assert tag in logged, f"{tag} not logged; got {sorted(logged)}"
    assert logged["counters/updates"] == list(range(1, len(logged["counters/updates"]) + 1))
    if mode == "ppo":
        assert set(logged["counters/steps_per_decision"]) == {1.0}
        assert max(logged["losses/prim_value_loss"]) == 0
    if mode == "macro":
        assert max(logged["losses/prim_value_loss"]) == 0
    return logged


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("env_id", ["MinAtar/Breakout-v1", "MiniQbert-v0", "CartPole-v1"])
def test_every_mode_runs_on_minatar_miniqbert_and_cartpole(rapl_ppo, tmp_path, cartpole_demo,
                                                           env_id, mode):
    demo = cartpole_demo if env_id == "CartPole-v1" and mode != "ppo" else None
    folder = run(rapl_ppo, tmp_path, env_id=env_id, mode=mode, demo=demo,
                 eval_episodes=1 if env_id == "CartPole-v1" else 0)
    logged = check_run(folder, mode)
    if mode == "ppo":  # 2 envs × 8 steps = 16 primitive steps per update: 4 updates
        assert logged["counters/decisions"] == [16.0, 32.0, 48.0, 64.0]
    if mode == "rapl" and env_id != "CartPole-v1":
        # A_prim trains the critic at the states inside routines: its loss is not always 0.
        assert max(logged["losses/prim_value_loss"]) > 0
    if env_id == "CartPole-v1":
        summary = json.loads((folder / "eval.json").read_text())
        assert summary["method"] == {"ppo": "ppo", "rapl": "rapl-ppo", "macro": "macro-ppo"}[mode]
        assert summary["episodes"] == 1


@pytest.mark.parametrize(("env_id", "mode"), [("ALE/Qbert-v5", "rapl"),
                                              ("procgen/CoinRun-v0", "macro"),
                                              ("routine_gym.envs.miniqbert:MiniQbert-v0", "rapl")])
def test_one_mode_runs_on_atari_procgen_and_a_module_env_id(rapl_ppo, tmp_path, env_id, mode):
    # The shipped demos (found for the module:EnvId form too); Procgen on its own levels.
    folder = run(rapl_ppo, tmp_path, env_id=env_id, mode=mode, num_steps=4, total_timesteps=16,
                 num_levels=5)
    check_run(folder, mode)


def test_each_family_has_its_defaults_and_a_given_flag_wins(rapl_ppo):
    def resolved(**kwargs) -> tuple:
        args = rapl_ppo.Args(**kwargs)
        rapl_ppo.family_defaults(args)
        return (args.num_envs, args.num_steps, args.num_minibatches, args.update_epochs,
                args.learning_rate, args.clip_coef, args.gamma)

    # CleanRL's ppo_atari.py, ppo_procgen.py and ppo.py; gymnax-blines' MinAtar (γ 0.99).
    assert resolved(env_id="ALE/Qbert-v5") == (8, 128, 4, 4, 2.5e-4, 0.1, 0.99)
    assert resolved(env_id="procgen/CoinRun-v0") == (64, 256, 8, 3, 5e-4, 0.2, 0.999)
    assert resolved(env_id="MinAtar/Breakout-v1") == (64, 128, 8, 4, 5e-4, 0.2, 0.99)
    assert resolved(env_id="CartPole-v1") == (4, 128, 4, 4, 2.5e-4, 0.2, 0.99)
    assert resolved(env_id="MiniQbert-v0", num_envs=16, gamma=0.9)[:2] == (16, 128)
    assert resolved(env_id="MiniQbert-v0", num_envs=16, gamma=0.9)[-1] == 0.9


def test_flat_observations_get_a_critic_torso_of_their_own_and_images_share_one(rapl_ppo):
    import gymnasium as gym

    # CleanRL's ppo.py: actor and critic MLPs apart, so the value's gradient leaves the
    # policy's torso alone; ppo_atari.py / ppo_procgen.py: one CNN for both.
    flat = rapl_ppo.Agent("CartPole-v1", gym.spaces.Box(-1, 1, (4,), np.float32), 2)
    flat.get_value(torch.ones(3, 4)).sum().backward()
    assert all(p.grad is None for p in flat.encoder.parameters())
    assert all(p.grad is not None for p in flat.critic_encoder.parameters())
    logprob, entropy, values, _ = flat.evaluate(torch.ones(5, 4), torch.zeros(2, dtype=torch.long))
    assert logprob.shape == entropy.shape == (2,) and values.shape == (5,)

    image = rapl_ppo.Agent("MinAtar/Breakout-v1",
                           gym.spaces.Box(0, 1, (4, 10, 10), np.float32), 3)
    assert image.critic_encoder is None
    image.get_value(torch.ones(2, 4, 10, 10)).sum().backward()
    assert all(p.grad is not None for p in image.encoder.parameters())


def test_target_kl_stops_a_rollouts_epochs_after_the_first(rapl_ppo, tmp_path):
    # 4 updates of 2 envs × 8 steps, 2 minibatches: 2 epochs make 16 Adam steps; with a KL
    # target every big step overshoots (lr 0.01), each rollout stops after one epoch: 8.
    steps = {}
    for target in (None, 1e-6):
        folder = run(rapl_ppo, tmp_path / str(target), env_id="CartPole-v1", mode="ppo",
                     learning_rate=0.01, target_kl=target, checkpoint_every=16)
        steps[target] = adam_steps(torch.load(folder / "checkpoint.pt", weights_only=True))
    assert steps == {None: 4 * 2 * 2, 1e-6: 4 * 1 * 2}


def test_bad_ppo_settings_are_refused_by_name(rapl_ppo, tmp_path):
    with pytest.raises(UsageError, match=r"--num-minibatches needs to be ≤ --num-envs × "
                                         r"--num-steps \(16\), actual value: 32"):
        run(rapl_ppo, tmp_path, env_id="CartPole-v1", mode="ppo", num_minibatches=32)
    with pytest.raises(UsageError, match="--gae-lambda needs to be in"):
        run(rapl_ppo, tmp_path, env_id="CartPole-v1", mode="ppo", gae_lambda=1.5)
    with pytest.raises(UsageError, match="--target-kl needs to be > 0"):
        run(rapl_ppo, tmp_path, env_id="CartPole-v1", mode="ppo", target_kl=0.0)
    with pytest.raises(UsageError, match=r"--prim-epochs needs to be ≤ --update-epochs \(2\), "
                                         r"actual value: 3"):
        run(rapl_ppo, tmp_path, env_id="CartPole-v1", mode="rapl", prim_epochs=3)
    with pytest.raises(UsageError, match="--prim-epochs needs to be ≥ 1, actual value: 0"):
        run(rapl_ppo, tmp_path, env_id="CartPole-v1", mode="rapl", prim_epochs=0)
    assert list(tmp_path.iterdir()) == []  # refused before a run folder was made


def test_a_killed_run_resumes_from_the_unbroken_runs_state_and_finishes_like_it(
        rapl_ppo, tmp_path, repo_root, monkeypatch, capsys):
    # RAPL on MiniQbert counted in decisions: every update is 2 envs × 16 decisions = 32, the
    # run 40 updates, a checkpoint every 4 (128 decisions).
    flags = dict(env_id="MiniQbert-v0", mode="rapl", num_envs=2, num_steps=16,
                 num_minibatches=2, update_epochs=2, budget_unit="decisions",
                 total_timesteps=1280, checkpoint_every=128, eval_episodes=0,
                 log_every=10**9, torch_threads=1)

    # The unbroken run, its checkpoints kept aside by decision.
    saves = {}
    save = Run.save_checkpoint

    def save_and_keep(run_, state):
        save(run_, state)
        checkpoint = torch.load(run_.checkpoint_path, weights_only=True)
        saves[checkpoint["decisions"]] = checkpoint

    with monkeypatch.context() as m:
        m.setattr(Run, "save_checkpoint", save_and_keep)
        rapl_ppo.main(rapl_ppo.Args(**flags, run_dir=str(tmp_path / "whole")))
    assert sorted(saves) == list(range(128, 1281, 128))

    # The same run from the command line, killed (SIGKILL: no clean-up) after a checkpoint.
    command = [sys.executable, str(repo_root / "algos" / "rapl_ppo.py"),
               "--run-dir", str(tmp_path / "killed")]
    for name, value in flags.items():
        command += [f"--{name.replace('_', '-')}", str(value)]
    checkpoint_path = kill_after_first_checkpoint(command, tmp_path / "killed", poll=0.005)
    killed = torch.load(checkpoint_path, weights_only=True)
    at = killed["decisions"]
    assert at % 128 == 0 and 128 <= at < 1280

    # Up to the kill, the killed run is the unbroken run: network, Adam moments, every RNG and
    # the routine library, bit for bit.
    for key in ("model", "optimizer", "rng"):
        assert_same(killed[key], saves[at][key])
    assert killed["library"] == saves[at]["library"]
    assert (killed["global_step"], killed["iteration"]) == (saves[at]["global_step"],
                                                             saves[at]["iteration"])

    # Resumed by its folder alone, it finishes the same budget with as many updates and Adam
    # steps as the unbroken run, logging only after the checkpoint. (Its weights then differ:
    # a checkpoint holds no env state, so the envs start new episodes.)
    rapl_ppo.main(rapl_ppo.Args(resume=str(checkpoint_path.parent)))
    assert f"resumed {checkpoint_path.parent.name} at step {killed['global_step']}" \
        in capsys.readouterr().out
    final, whole = torch.load(checkpoint_path, weights_only=True), saves[1280]
    assert (final["decisions"], final["iteration"]) == (whole["decisions"], whole["iteration"])
    assert adam_steps(final) == adam_steps(whole) == 40 * 2 * 2
    assert final["library"] == whole["library"]
    assert json.loads(final["args"])["total_timesteps"] == 1280
    resumed = max(checkpoint_path.parent.glob("events.out.tfevents.*"),
                  key=lambda path: path.stat().st_mtime_ns)
    logged = scalars(resumed)
    assert logged["counters/updates"] == list(range(killed["iteration"] + 1, 41))
    assert min(logged["counters/decisions"]) > at


def record_shares(rapl_ppo, monkeypatch) -> list[tuple[int, int, int, list[np.ndarray]]]:
    """Each update's `inner_state_shares` call in the script: (states, epochs, passes, shares)."""
    calls = []

    def recording(num_inner, epochs, passes):
        shares = []
        calls.append((num_inner, epochs, passes, shares))
        for share in inner_state_shares(num_inner, epochs, passes):
            shares.append(share)
            yield share

    monkeypatch.setattr(rapl_ppo, "inner_state_shares", recording)
    return calls


@pytest.mark.parametrize(("prim_epochs", "passes"), [(None, 1), (2, 2)])
def test_the_update_trains_each_inner_state_in_prim_epochs_of_its_epochs(
        rapl_ppo, tmp_path, monkeypatch, prim_epochs, passes):
    # RAPL on MiniQbert, 2 envs × 8 decisions, 2 epochs of 2 minibatches, 4 updates.
    calls = record_shares(rapl_ppo, monkeypatch)
    run(rapl_ppo, tmp_path, env_id="MiniQbert-v0", mode="rapl", prim_epochs=prim_epochs,
        budget_unit="decisions")
    assert len(calls) == 4 and sum(num_inner for num_inner, *_ in calls) > 0
    for num_inner, epochs, used, shares in calls:
        assert (epochs, used, len(shares)) == (2, passes, 2)
        counts = np.bincount(np.concatenate(shares).astype(np.int64), minlength=num_inner)
        assert counts.tolist() == [passes] * num_inner


def test_a_checkpoint_from_before_prim_epochs_resumes_training_inner_states_every_epoch(
        rapl_ppo, tmp_path, monkeypatch):
    # A checkpoint's saved settings without the field (made before the flag existed) resume
    # as that run was made: every inner state in every epoch.
    # Two updates of 16 decisions, then two more on a resume with a budget of 64.
    folder = run(rapl_ppo, tmp_path, env_id="MiniQbert-v0", mode="rapl",
                 budget_unit="decisions", total_timesteps=32, checkpoint_every=32)
    checkpoint = torch.load(folder / "checkpoint.pt", weights_only=True)
    saved = json.loads(checkpoint["args"])
    assert (checkpoint["decisions"], saved["prim_epochs"]) == (32, 1)
    del saved["prim_epochs"]
    checkpoint["args"] = json.dumps(saved)
    torch.save(checkpoint, folder / "checkpoint.pt")
    calls = record_shares(rapl_ppo, monkeypatch)
    rapl_ppo.main(rapl_ppo.Args(resume=str(folder), total_timesteps=64))
    assert [passes for _, _, passes, _ in calls] == [2, 2]


def adam_steps(checkpoint: dict) -> int:
    return int(next(iter(checkpoint["optimizer"]["state"].values()))["step"])


