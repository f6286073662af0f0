"""SQIL's pure pieces (routine_gym.imitation): the soft target, D_prim and D_routine, and the demo
states in the agent's view (the replay memory is tested in test_replay_memory.py)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

import routine_gym  # noqa: F401  (registers MiniQbert-v0)
from routine_gym.demo import Demo, shipped_demo_path
from routine_gym.envs.miniqbert import MiniQbertEnv
from routine_gym.imitation import (
    agent_view_states,
    build_demo_transitions,
    primitive_transitions,
    routine_transitions,
    soft_value,
    sqil_reward_and_discount,
    sqil_target,
    state_offsets,
)
from routine_gym.mining import SequiturMiner

# -- the SQIL target ---------------------------------------------------------------------------


def test_sqil_reward_is_one_per_primitive_step_discounted_and_discount_is_gamma_to_the_length():
    rewards, discounts = sqil_reward_and_discount([1, 2, 3], gamma=0.9)
    np.testing.assert_allclose(rewards, [1.0, 1.9, 2.71])  # 1, 1 + .9, 1 + .9 + .81
    np.testing.assert_allclose(discounts, [0.9, 0.81, 0.729])
    agent_rewards, _ = sqil_reward_and_discount([4], gamma=0.9, reward=0.0)
    assert agent_rewards.tolist() == [0.0]


def test_soft_value_is_temperature_times_logsumexp():
    q = torch.tensor([[0.0, math.log(3.0)]])
    assert soft_value(q, 1.0).item() == pytest.approx(math.log(4.0))  # log(1 + 3)
    # α = 0.5: 0.5 · log(e^0 + e^{2 log 3}) = 0.5 · log(1 + 9)
    assert soft_value(q, 0.5).item() == pytest.approx(0.5 * math.log(10.0))
    # A cold temperature gives the hard max of Q-learning.
    assert soft_value(torch.tensor([[1.0, 2.0, 3.0]]), 0.01).item() == pytest.approx(3.0, abs=1e-6)
    with pytest.raises(ValueError, match="temperature"):
        soft_value(q, 0.0)


def test_sqil_target_bootstraps_with_gamma_to_the_length_and_stops_at_termination():
    next_q = torch.tensor([[0.0, math.log(3.0)], [math.log(3.0), 0.0], [5.0, 7.0]])
    rewards = torch.tensor([1.0, 1.9, 0.0])  # a demo primitive, a demo routine of 2, the agent's
    discounts = torch.tensor([0.9, 0.81, 0.81])
    terminated = torch.tensor([False, False, True])
    target = sqil_target(rewards, discounts, terminated, next_q, temperature=1.0)
    expected = [1.0 + 0.9 * math.log(4.0), 1.9 + 0.81 * math.log(4.0), 0.0]
    np.testing.assert_allclose(target.numpy(), expected, rtol=1e-6)


# -- D_prim and D_routine ----------------------------------------------------------------------

# Two episodes: [2 3 2 3 1] (terminated) and [2 3 0] (truncated). States: 0..5 and 6..9.
LENGTHS = np.array([5, 3])
ACTIONS = np.array([2, 3, 2, 3, 1, 2, 3, 0])
TERMINATED = np.array([0, 0, 0, 0, 1, 0, 0, 0], dtype=bool)


def test_state_offsets_leave_room_for_each_final_state():
    assert state_offsets(LENGTHS).tolist() == [0, 6]


def test_primitive_transitions_link_each_step_to_the_next_state_of_its_episode():
    d = primitive_transitions(LENGTHS, ACTIONS, TERMINATED)
    assert d["state_index"].tolist() == [0, 1, 2, 3, 4, 6, 7, 8]
    assert d["next_state_index"].tolist() == [1, 2, 3, 4, 5, 7, 8, 9]
    assert d["actions"].tolist() == ACTIONS.tolist()
    assert d["lengths"].tolist() == [1] * 8
    assert d["terminated"].tolist() == TERMINATED.tolist()


def test_routine_transitions_jump_the_routine_length_with_action_n_plus_k():
    routines = [(2, 3), (3, 2, 3), (3, 1)]
    occurrences = [((0, 0), (0, 2), (1, 0)), ((0, 1),), ((0, 3),)]
    d = routine_transitions(LENGTHS, ACTIONS, TERMINATED, routines, occurrences, num_primitives=4)
    assert d["state_index"].tolist() == [0, 2, 6, 1, 3]
    assert d["actions"].tolist() == [4, 4, 4, 5, 6]
    assert d["lengths"].tolist() == [2, 2, 2, 3, 2]
    assert d["next_state_index"].tolist() == [2, 4, 8, 4, 5]
    # Routine 2 ends on the episode's terminating step: no bootstrap after it.
    assert d["terminated"].tolist() == [False, False, False, False, True]


def test_routine_transitions_reject_occurrences_that_are_not_in_this_demo():
    with pytest.raises(ValueError, match=r"are \[3, 2\], not routine 0"):
        routine_transitions(LENGTHS, ACTIONS, TERMINATED, [(2, 3)], [((0, 1),)], 4)
    with pytest.raises(ValueError, match="leaves the demo"):
        routine_transitions(LENGTHS, ACTIONS, TERMINATED, [(2, 3)], [((1, 2),)], 4)
    with pytest.raises(ValueError, match="leaves the demo"):
        routine_transitions(LENGTHS, ACTIONS, TERMINATED, [(2, 3)], [((2, 0),)], 4)


def _toy_demo() -> Demo:
    return Demo(actions=ACTIONS, rewards=np.zeros(8), terminated=TERMINATED,
                truncated=np.array([0, 0, 0, 0, 0, 0, 0, 1], dtype=bool), episode_lengths=LENGTHS,
                meta={"num_actions": 4, "seeds": [0, 1]})


def test_demo_transitions_carry_sqil_rewards_of_one_per_primitive_step():
    demo = _toy_demo()
    states = np.arange(10, dtype=np.float32)[:, None]
    library = SequiturMiner(num_routines=1, prune_primitives=False).mine(demo)
    assert library.routines == ((2, 3),)
    d = build_demo_transitions(demo, states, gamma=0.5, library=library)
    assert len(d) == 8 + 3
    assert d.is_routine.tolist() == [False] * 8 + [True] * 3
    np.testing.assert_allclose(d.rewards, [1.0] * 8 + [1.5] * 3)  # 1 + 0.5
    np.testing.assert_allclose(d.discounts, [0.5] * 8 + [0.25] * 3)
    batch = d.sample(64, np.random.default_rng(0))
    # Each state holds its own index: s' − s is the transition's length.
    np.testing.assert_array_equal(batch["next_obs"][:, 0] - batch["obs"][:, 0], batch["lengths"])


def test_demo_transitions_locate_a_library_mined_elsewhere_in_this_demo():
    demo = _toy_demo()
    other = SequiturMiner(num_routines=1, prune_primitives=False).mine(
        [[0, 2, 3, 0, 2, 3, 2, 3]]
    )  # occurrences (0, 1), (0, 4), (0, 6) of another action sequence
    d = build_demo_transitions(demo, np.zeros((10, 1)), gamma=0.9, library=other)
    routine = d.is_routine
    assert d.state_index[routine].tolist() == [0, 2, 6]
    with pytest.raises(ValueError, match="states for a demo that needs 10"):
        build_demo_transitions(demo, np.zeros((9, 1)), gamma=0.9)


def _miniqbert_step_from(state: np.ndarray, actions) -> np.ndarray:
    """Put a MiniQbert env in the state an observation describes, play `actions`, return obs."""
    env = MiniQbertEnv()
    env.reset(seed=0)
    n = env.n_cubes
    env._colours[:] = state[:n] > 0.5
    env._pos = int(np.argmax(state[n : 2 * n]))
    env._level = round(float(state[-2]) * env.num_levels)
    env._lives = round(float(state[-1]) * env.max_lives)
    for a in actions:
        obs, *_ = env.step(int(a))
    return obs


def test_miniqbert_demo_buffer_states_line_up_with_the_actions():
    """Playing a transition's actions from its state gives its next state: D_prim and D_routine
    both index the right states (MiniQbert's observation is its full state)."""
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"), env_id="MiniQbert-v0")
    assert not demo.has_observations  # the states come from replaying the demo from its seed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        library = SequiturMiner(num_routines=3).mine(demo)
    d = build_demo_transitions(demo, agent_view_states(demo, "MiniQbert-v0"), 0.99, library)
    assert int(d.is_routine.sum()) == sum(library.frequencies) > 0
    n = demo.num_actions
    for i in range(len(d)):
        a = int(d.actions[i])
        actions = (a,) if a < n else library.routines[a - n]
        assert len(actions) == d.lengths[i]
        expected = _miniqbert_step_from(d.states[d.state_index[i]], actions)
        np.testing.assert_array_equal(d.states[d.next_state_index[i]], expected, err_msg=str(i))
    # The very first state is the reset state: every cube uncoloured, agent on top, all lives.
    first = d.states[0]
    assert first[:10].sum() == 0 and first[10] == 1.0 and first[-1] == 1.0


def test_demo_without_observations_or_seeds_cannot_give_states():
    demo = Demo(actions=np.array([5, 2]), rewards=np.array([25.0, 0.0]),
                terminated=np.zeros(2, bool), truncated=np.zeros(2, bool),
                episode_lengths=np.array([2]), meta={"env_id": "MiniQbert-v0", "num_actions": 6})
    with pytest.raises(ValueError, match="cannot be replayed"):
        agent_view_states(demo, "MiniQbert-v0")


def test_demo_with_stored_observations_is_used_as_it_is():
    obs = np.arange(6, dtype=np.float32).reshape(3, 2)
    demo = Demo(actions=np.array([1, 0, 1]), rewards=np.zeros(3),
                terminated=np.array([0, 0, 1], bool), truncated=np.zeros(3, bool),
                episode_lengths=np.array([3]), observations=obs,
                final_observations=np.array([[9.0, 9.0]], np.float32),
                meta={"env_id": "CartPole-v1", "num_actions": 2})  # no seeds: not replayable
    states = agent_view_states(demo, "CartPole-v1")
    np.testing.assert_array_equal(states, [[0, 1], [2, 3], [4, 5], [9, 9]])


def test_the_docstring_examples_run():
    import doctest

    import routine_gym.imitation

    assert doctest.testmod(routine_gym.imitation).failed == 0
