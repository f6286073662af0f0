"""Returns over routine decisions and their primitive steps (routine_gym/returns.py, SPEC §5).

Every expected number is worked out by hand in a comment. γ = 0.5 throughout, so that all the
powers of γ, and therefore all the returns, are exact binary fractions and compare with `==`.
Arrays are time-major: `[N, E]` for decisions, `[N, L, E]` for the steps inside them.
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import routine_gym.returns
from routine_gym.returns import (
    decision_returns,
    inner_states_and_targets,
    macro_reward_and_discount,
    primitive_returns,
    routine_reward_and_discount,
)

GAMMA = 0.5
F, T = False, True


def col(*values) -> np.ndarray:
    """A `[N, 1]` (or `[N, L, 1]`) array for a single env, from nested lists."""
    return np.asarray(values)[..., None]


def flags(*values: bool) -> np.ndarray:
    return col(*values).astype(bool)


# -- routine and macro rewards -------------------------------------------------------------


def test_routine_reward_is_discounted_sum_and_discount_is_gamma_to_the_length():
    # R = 1 + 0.5·2 + 0.25·4 = 3;  Γ = 0.5³ = 0.125 (γ^ℓ, not γ^(ℓ-1))
    reward, discount = routine_reward_and_discount(col([1.0, 2.0, 4.0]), np.array([[3]]), GAMMA)
    assert reward.tolist() == [[3.0]]
    assert discount.tolist() == [[0.125]]


def test_routine_reward_ignores_padding_past_the_executed_length():
    # Executed length 2 of 3; the padding entry 99 must not count even though it is non-zero.
    # R = 1 + 0.5·2 = 2;  Γ = 0.5² = 0.25
    reward, discount = routine_reward_and_discount(col([1.0, 2.0, 99.0]), np.array([[2]]), GAMMA)
    assert reward.tolist() == [[2.0]]
    assert discount.tolist() == [[0.25]]


def test_macro_reward_is_plain_sum_and_one_gamma_per_decision():
    # MacroAction: R = 1 + 2 + 4 = 7, Γ = γ = 0.5 whatever the length;
    # with length 2 and padding 99: R = 1 + 2 = 3, Γ = 0.5.
    reward, discount = macro_reward_and_discount(col([1.0, 2.0, 4.0]), np.array([[3]]), GAMMA)
    assert reward.tolist() == [[7.0]]
    assert discount.tolist() == [[0.5]]
    reward, discount = macro_reward_and_discount(col([1.0, 2.0, 99.0]), np.array([[2]]), GAMMA)
    assert reward.tolist() == [[3.0]]
    assert discount.tolist() == [[0.5]]


def test_routine_reward_of_a_rollout_is_per_decision_and_per_env():
    # rewards[N=2, L=3, E=2], lengths[N=2, E=2]
    rewards = np.zeros((2, 3, 2))
    rewards[0, :, 0] = [1, 2, 4]  # ℓ=3: R = 1 + 1 + 1 = 3,     Γ = 0.125
    rewards[0, :, 1] = [8, 7, 7]  # ℓ=1: R = 8,                 Γ = 0.5
    rewards[1, :, 0] = [4, 4, 5]  # ℓ=2: R = 4 + 2 = 6,         Γ = 0.25
    rewards[1, :, 1] = [0, 8, 8]  # ℓ=3: R = 0 + 4 + 2 = 6,     Γ = 0.125
    lengths = np.array([[3, 1], [2, 3]])
    reward, discount = routine_reward_and_discount(rewards, lengths, GAMMA)
    assert reward.tolist() == [[3.0, 8.0], [6.0, 6.0]]
    assert discount.tolist() == [[0.125, 0.5], [0.25, 0.125]]
    reward, discount = macro_reward_and_discount(rewards, lengths, GAMMA)
    assert reward.tolist() == [[7.0, 8.0], [8.0, 16.0]]  # 1+2+4, 8, 4+4, 0+8+8
    assert discount.tolist() == [[0.5, 0.5], [0.5, 0.5]]


def test_macro_return_discounts_once_per_decision_where_rapl_discounts_per_step():
    # The return `--mode macro` learns from. Decision 0: a 3-step routine [1, 2, 4]; decision 1:
    # a primitive [8]; V_boot = 16.
    # MacroAction: R = [1+2+4 = 7, 8], Γ = [0.5, 0.5]:
    #   G_1 = 8 + 0.5·16 = 16;  G_0 = 7 + 0.5·16 = 15.
    # RAPL on the same rollout: R_0 = 1 + 0.5·2 + 0.25·4 = 3, Γ_0 = 0.125:
    #   G_1 = 16;  G_0 = 3 + 0.125·16 = 5 (the primitive-level return of step (0,0)).
    step_rewards = col([1.0, 2.0, 4.0], [8.0, 0.0, 0.0])
    lengths = col(3, 1)
    rest = (flags(F, F), flags(F, F), col(0.0, 0.0), np.array([16.0]))
    macro = macro_reward_and_discount(step_rewards, lengths, GAMMA)
    assert decision_returns(*macro, *rest).tolist() == [[15.0], [16.0]]
    routine = routine_reward_and_discount(step_rewards, lengths, GAMMA)
    assert decision_returns(*routine, *rest).tolist() == [[5.0], [16.0]]


# -- decision returns ----------------------------------------------------------------------


def test_bootstrap_at_the_end_of_the_rollout():
    # One decision: G_0 = R + Γ·V_boot = 3 + 0.125·8 = 4.
    returns = decision_returns(col(3.0), col(0.125), flags(F), flags(F), col(0.0), np.array([8.0]))
    assert returns.tolist() == [[4.0]]
    # Two decisions: G_1 = 3 + 0.125·8 = 4;  G_0 = 1 + 0.5·4 = 3.
    returns = decision_returns(
        col(1.0, 3.0), col(0.5, 0.125), flags(F, F), flags(F, F), col(0.0, 0.0), np.array([8.0])
    )
    assert returns.tolist() == [[3.0], [4.0]]


def test_episode_ending_inside_the_rollout_cuts_the_return():
    # R = [1, 2, 4], Γ = 0.5 each, decision 1 terminates, V_boot = 8:
    # G_2 = 4 + 0.5·8 = 8   (the next episode's decision bootstraps from the final value)
    # G_1 = 2               (terminated: nothing follows, G_2 is another episode's)
    # G_0 = 1 + 0.5·2 = 2   (sees G_1, and through it nothing after the end)
    returns = decision_returns(
        col(1.0, 2.0, 4.0),
        col(0.5, 0.5, 0.5),
        flags(F, T, F),
        flags(F, F, F),
        col(0.0, 0.0, 0.0),
        np.array([8.0]),
    )
    assert returns.tolist() == [[2.0], [2.0], [8.0]]


def test_truncation_bootstraps_from_the_final_value_termination_from_zero():
    # R = [1, 2], Γ = 0.5, V_boot = 100; decision 0's episode ends with final value 6.
    # G_1 = 2 + 0.5·100 = 52 in every case below.
    common = dict(rewards=col(1.0, 2.0), discounts=col(0.5, 0.5), bootstrap_value=np.array([100.0]))
    final_values = col(6.0, 1000.0)  # 1000: decision 1 has no flag, so it must not be read
    # truncated: G_0 = 1 + 0.5·6 = 4
    returns = decision_returns(
        **common, terminated=flags(F, F), truncated=flags(T, F), final_values=final_values
    )
    assert returns.tolist() == [[4.0], [52.0]]
    # terminated: G_0 = 1 + 0.5·0 = 1
    returns = decision_returns(
        **common, terminated=flags(T, F), truncated=flags(F, F), final_values=final_values
    )
    assert returns.tolist() == [[1.0], [52.0]]
    # Both flags (a time limit hit on the very step that terminated, which Gymnasium's TimeLimit
    # reports as terminated=truncated=True): the MDP ended, so termination wins: G_0 = 1.
    returns = decision_returns(
        **common, terminated=flags(T, F), truncated=flags(T, F), final_values=final_values
    )
    assert returns.tolist() == [[1.0], [52.0]]


def test_routine_cut_short_by_termination_stops_the_return():
    # Decision 0: primitive, r = 1 (ℓ=1). Decision 1: a length-3 routine that terminated after
    # 2 steps, rewards [2, 4, pad 99]. V_boot = 100 must not be used.
    step_rewards = col([1.0, 0.0, 0.0], [2.0, 4.0, 99.0])
    lengths = col(1, 2)
    term, trunc, final_values = flags(F, T), flags(F, F), col(0.0, 0.0)
    boot = np.array([100.0])
    # Routine level: R_1 = 2 + 0.5·4 = 4, Γ_1 = 0.25, G_1 = 4 (stop);
    #                R_0 = 1, Γ_0 = 0.5, G_0 = 1 + 0.5·4 = 3.
    reward, discount = routine_reward_and_discount(step_rewards, lengths, GAMMA)
    assert reward.tolist() == [[1.0], [4.0]]
    assert discount.tolist() == [[0.5], [0.25]]
    returns = decision_returns(reward, discount, term, trunc, final_values, boot)
    assert returns.tolist() == [[3.0], [4.0]]
    # Primitive level: step (1,1): 4 (stop); step (1,0): 2 + 0.5·4 = 4;
    # step (0,0): 1 + 0.5·4 = 3; the padding (0,1), (0,2), (1,2) is 0.
    prim = primitive_returns(step_rewards, lengths, term, trunc, final_values, boot, GAMMA)
    assert prim[..., 0].tolist() == [[3.0, 0.0, 0.0], [4.0, 4.0, 0.0]]


def test_primitive_returns_of_a_truncated_routine_bootstrap_from_the_final_value():
    # One routine of 2 steps, rewards [2, 4], truncated, final value 8, V_boot = 100 (unused):
    # step 1: 4 + 0.5·8 = 8;  step 0: 2 + 0.5·8 = 6.
    # Routine level agrees: R = 2 + 0.5·4 = 4, Γ = 0.25, G = 4 + 0.25·8 = 6.
    prim = primitive_returns(
        col([2.0, 4.0]), col(2), flags(F), flags(T), col(8.0), np.array([100.0]), GAMMA
    )
    assert prim[..., 0].tolist() == [[6.0, 8.0]]
    # Terminated instead: step 1: 4;  step 0: 2 + 0.5·4 = 4.
    prim = primitive_returns(
        col([2.0, 4.0]), col(2), flags(T), flags(F), col(8.0), np.array([100.0]), GAMMA
    )
    assert prim[..., 0].tolist() == [[4.0, 4.0]]


def test_primitive_returns_chain_through_decisions_and_bootstrap():
    # Decision 0: routine of 3 steps [1, 2, 4]; decision 1: primitive [8]; V_boot = 16.
    # step (1,0): 8 + 0.5·16 = 16
    # step (0,2): 4 + 0.5·16 = 12;  (0,1): 2 + 0.5·12 = 8;  (0,0): 1 + 0.5·8 = 5
    prim = primitive_returns(
        col([1.0, 2.0, 4.0], [8.0, 0.0, 0.0]),
        col(3, 1),
        flags(F, F),
        flags(F, F),
        col(0.0, 0.0),
        np.array([16.0]),
        GAMMA,
    )
    assert prim[..., 0].tolist() == [[5.0, 8.0, 12.0], [16.0, 0.0, 0.0]]


def test_envs_are_independent():
    # E = 2, the same rewards R = [1, 2], Γ = 0.5, V_boot = [8, 4]:
    # env 0 terminates at decision 0:  G = [1, 2 + 0.5·8 = 6]
    # env 1 runs on:                   G_1 = 2 + 0.5·4 = 4, G_0 = 1 + 0.5·4 = 3
    returns = decision_returns(
        np.array([[1.0, 1.0], [2.0, 2.0]]),
        np.full((2, 2), 0.5),
        np.array([[T, F], [F, F]]),
        np.zeros((2, 2), bool),
        np.zeros((2, 2)),
        np.array([8.0, 4.0]),
    )
    assert returns.tolist() == [[1.0, 3.0], [6.0, 4.0]]
    # Primitive level, env 0 runs a 2-step routine [1, 2] that is truncated (final value 4),
    # env 1 a primitive [1] (ℓ=1, pad 2 ignored) then the rollout ends (V_boot = 4):
    # env 0: (0,1): 2 + 0.5·4 = 4, (0,0): 1 + 0.5·4 = 3;  env 1: (0,0): 1 + 0.5·4 = 3.
    step_rewards = np.array([[[1.0, 1.0], [2.0, 2.0]]])  # [N=1, L=2, E=2]
    prim = primitive_returns(
        step_rewards,
        np.array([[2, 1]]),
        np.array([[F, F]]),
        np.array([[T, F]]),
        np.array([[4.0, 0.0]]),
        np.array([100.0, 4.0]),
        GAMMA,
    )
    assert prim[0].tolist() == [[3.0, 3.0], [4.0, 0.0]]


# -- A_prim: inner states and their targets --------------------------------------------------


def test_inner_state_after_step_j_minus_1_is_paired_with_the_return_of_step_j():
    # N=2 decisions, L=3, E=2 envs, lengths ℓ = [[3, 1], [2, 3]]. Each observation is a tag
    # 100·i + 10·k + e for "decision i, after step k, env e"; each return 100·i + 10·j + e + 0.5
    # for "decision i, step j, env e". Padding is 999 (obs) and -1 (returns) so that reading
    # it shows. Inner steps j ≥ 1 with j < ℓ, in (decision, step, env) order:
    #   (0,1,0) (0,2,0)   env 0's 3-step routine of decision 0
    #   —               env 1's primitive of decision 0 (ℓ=1): none
    #   (1,1,0)           env 0's routine cut after 2 steps
    #   (1,1,1) (1,2,1)   env 1's 3-step routine
    # step j's state is the obs after step k = j-1:  tags 0, 10, 100, 101, 111
    # and its target the return of step j:           10.5, 20.5, 110.5, 111.5, 121.5
    lengths = np.array([[3, 1], [2, 3]])
    inner_obs = np.full((2, 2, 2, 1), 999.0)  # [N, L-1, E, obs]
    prim = np.full((2, 3, 2), -1.0)  # [N, L, E]
    for i in range(2):
        for e in range(2):
            for k in range(lengths[i, e] - 1):
                inner_obs[i, k, e, 0] = 100 * i + 10 * k + e
            for j in range(lengths[i, e]):
                prim[i, j, e] = 100 * i + 10 * j + e + 0.5
    states, targets = inner_states_and_targets(inner_obs, prim, lengths)
    assert states.tolist() == [[0.0], [10.0], [100.0], [101.0], [111.0]]
    assert targets.tolist() == [10.5, 20.5, 110.5, 111.5, 121.5]
    # The wrapper's full `routine_observations` also hold the obs after the last step (the next
    # decision's state, tag k = 2); it is not an inner state, so the pairs stay the same.
    full_obs = np.concatenate([inner_obs, np.full((2, 1, 2, 1), 999.0)], axis=1)
    states_full, targets_full = inner_states_and_targets(full_obs, prim, lengths)
    assert states_full.tolist() == states.tolist()
    assert targets_full.tolist() == targets.tolist()


def test_inner_targets_are_the_primitive_returns_from_inside_the_routine():
    # Decision 0: a 3-step routine [1, 2, 4] through states s0 → s1 → s2 → s3; decision 1: a
    # primitive [8] from s3; V_boot = 16. Primitive returns (worked in
    # test_primitive_returns_chain_through_decisions_and_bootstrap): [[5, 8, 12], [16, 0, 0]].
    # The inner states are s1 (after step 0) with 2 + 0.5·(4 + 0.5·16) = 8 and s2 with
    # 4 + 0.5·16 = 12; s0 and s3 are decisions' own states and belong to A_routine.
    prim = primitive_returns(
        col([1.0, 2.0, 4.0], [8.0, 0.0, 0.0]), col(3, 1), flags(F, F), flags(F, F),
        col(0.0, 0.0), np.array([16.0]), GAMMA,
    )
    s1, s2 = [1.0, 1.0], [2.0, 2.0]  # 2-feature observations
    inner_obs = np.zeros((2, 2, 1, 2))  # [N, L-1, E, obs]; decision 1 has no inner state
    inner_obs[0, 0, 0], inner_obs[0, 1, 0] = s1, s2
    states, targets = inner_states_and_targets(inner_obs, prim, col(3, 1))
    assert states.tolist() == [s1, s2]
    assert targets.tolist() == [8.0, 12.0]


def test_no_inner_states_when_every_decision_is_a_primitive():
    # ℓ = 1 everywhere (plain A2C, or a rollout that used no routine): nothing inside a routine,
    # and the empty arrays keep the observation shape for the critic.
    states, targets = inner_states_and_targets(
        np.ones((3, 2, 4, 5, 6)), np.ones((3, 3, 4)), np.ones((3, 4), dtype=np.int64)
    )
    assert states.shape == (0, 5, 6)
    assert targets.shape == (0,)


def test_docstring_examples_run():
    result = doctest.testmod(routine_gym.returns)
    assert result.attempted > 0 and result.failed == 0


# -- properties ----------------------------------------------------------------------------


def reference_primitive_returns(rewards, lengths, terminated, truncated, final_values, boot, gamma):
    """A plain scalar loop over each env's flat primitive trajectory (written independently)."""
    n, max_len, num_envs = rewards.shape
    out = np.zeros_like(rewards, dtype=np.float64)
    for e in range(num_envs):
        following = float(boot[e])
        for i in reversed(range(n)):
            length = int(lengths[i, e])
            if terminated[i, e]:
                following = 0.0
            elif truncated[i, e]:
                following = float(final_values[i, e])
            for j in reversed(range(length)):
                following = float(rewards[i, j, e]) + gamma * following
                out[i, j, e] = following
    return out


@st.composite
def rollouts(draw):
    n = draw(st.integers(1, 5))
    max_len = draw(st.integers(1, 4))
    num_envs = draw(st.integers(1, 3))

    def array(shape, elements):
        size = int(np.prod(shape))
        return np.array(draw(st.lists(elements, min_size=size, max_size=size))).reshape(shape)

    small = st.integers(-8, 8).map(float)  # integers keep every sum exact in float64
    rewards = array((n, max_len, num_envs), small)
    lengths = array((n, num_envs), st.integers(1, max_len))
    terminated = array((n, num_envs), st.booleans())
    truncated = array((n, num_envs), st.booleans())
    final_values = array((n, num_envs), small)
    boot = array((num_envs,), small)
    gamma = draw(st.sampled_from([0.5, 0.9, 0.99, 1.0]))
    return rewards, lengths, terminated, truncated, final_values, boot, gamma


@settings(max_examples=150, deadline=None)
@given(rollouts())
def test_primitive_returns_at_step_zero_equal_decision_returns_with_routine_rewards(rollout):
    rewards, lengths, terminated, truncated, final_values, boot, gamma = rollout
    prim = primitive_returns(rewards, lengths, terminated, truncated, final_values, boot, gamma)
    reward, discount = routine_reward_and_discount(rewards, lengths, gamma)
    decisions = decision_returns(reward, discount, terminated, truncated, final_values, boot)
    np.testing.assert_allclose(prim[:, 0], decisions, rtol=1e-12, atol=1e-9)
    expected = reference_primitive_returns(
        rewards, lengths, terminated, truncated, final_values, boot, gamma
    )
    np.testing.assert_allclose(prim, expected, rtol=1e-12, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(rollouts())
def test_length_one_decisions_make_primitive_decision_and_macro_returns_agree(rollout):
    rewards, _, terminated, truncated, final_values, boot, gamma = rollout
    lengths = np.ones_like(terminated, dtype=np.int64)
    prim = primitive_returns(rewards, lengths, terminated, truncated, final_values, boot, gamma)
    # A primitive is a routine of length 1: RAPL's and MacroAction's rewards and discounts agree.
    routine = routine_reward_and_discount(rewards, lengths, gamma)
    macro = macro_reward_and_discount(rewards, lengths, gamma)
    np.testing.assert_array_equal(routine[0], macro[0])
    np.testing.assert_array_equal(routine[1], macro[1])
    decisions = decision_returns(*macro, terminated, truncated, final_values, boot)
    np.testing.assert_allclose(prim[:, 0], decisions, rtol=1e-12, atol=1e-9)
    assert not prim[:, 1:].any()  # nothing past the single executed step


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_gamma_edge_values(gamma):
    # γ = 0: each return is its own first reward (0⁰ = 1 for the first step).
    # γ = 1: undiscounted sums, bootstrap included: 1 + 2 + 4 + 8 = 15.
    prim = primitive_returns(
        col([1.0, 2.0], [4.0, 0.0]), col(2, 1), flags(F, F), flags(F, F), col(0.0, 0.0),
        np.array([8.0]), gamma,
    )
    expected = [[1.0, 2.0], [4.0, 0.0]] if gamma == 0.0 else [[15.0, 14.0], [12.0, 0.0]]
    assert prim[..., 0].tolist() == expected
