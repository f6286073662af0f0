"""rapl_a2c.py's update runs the network once over the rollout: what that changes, what not.

The acting passes run without a graph; the update evaluates the rollout's n·e decision states and
the e states after it in one batch (`Agent.evaluate`). The outputs are the acting passes' bit for
bit (the network is applied to each state alone). The gradient is the same function, but its sums
over the batch are one matrix product of n·e rows instead of n products of e rows added together,
so its float32 rounding differs: within 1e-5 relative, not bit for bit. That is why training on a
fixed seed is not bit-identical to routine-gym before this change (README, "speed").
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from script_loader import load_script

import routine_gym


@pytest.fixture(scope="module")
def script():
    routine_gym.register_envs()
    return load_script("rapl_a2c", "rapl_a2c_update")


def _rollout(n=5, e=16, channels=4, actions=6, seed=0):
    rng = np.random.default_rng(seed)
    obs = rng.integers(0, 2, (n + 1, e, channels, 10, 10)).astype(np.float32)
    return obs, rng.integers(0, actions, (n, e)), rng.normal(size=(n, e)).astype(np.float32)


def test_one_pass_over_the_rollout_gives_the_acting_passes_outputs_bit_for_bit(script):
    torch.manual_seed(0)
    obs, actions, _ = _rollout()
    n, e = actions.shape
    agent = script.Agent("MinAtar/Breakout-v1", gym.spaces.Box(0.0, 1.0, obs.shape[2:],
                                                                np.float32), 6)
    with torch.no_grad():
        logprobs, entropies, values = agent.evaluate(
            torch.as_tensor(obs.reshape(-1, *obs.shape[2:])), torch.as_tensor(actions.reshape(-1)))
        for step in range(n):
            _, logprob, entropy, value = agent.get_action_and_value(
                torch.as_tensor(obs[step]), torch.as_tensor(actions[step]))
            assert torch.equal(logprob, logprobs[step * e:(step + 1) * e])
            assert torch.equal(entropy, entropies[step * e:(step + 1) * e])
            assert torch.equal(value, values[step * e:(step + 1) * e])
        assert torch.equal(agent.get_value(torch.as_tensor(obs[n])), values[n * e:])
    assert logprobs.shape == (n * e,) and values.shape == ((n + 1) * e,)


def test_its_gradient_is_the_per_step_graphs_gradient_to_float_rounding(script):
    obs, actions, returns = _rollout(seed=1)
    n, e = actions.shape
    space = gym.spaces.Box(0.0, 1.0, obs.shape[2:], np.float32)

    def loss_of(agent, logprobs, entropies, values):
        advantages = torch.as_tensor(returns) - values
        return (-(logprobs * advantages.detach()).mean() - 0.01 * entropies.mean()
                + 0.5 * advantages.pow(2).mean())

    grads = []
    for batched in (True, False):
        torch.manual_seed(0)
        agent = script.Agent("MinAtar/Breakout-v1", space, 6)
        if batched:
            logprobs, entropies, values = agent.evaluate(
                torch.as_tensor(obs.reshape(-1, *obs.shape[2:])),
                torch.as_tensor(actions.reshape(-1)))
            loss = loss_of(agent, logprobs.view(n, e), entropies.view(n, e),
                           values[: n * e].view(n, e))
        else:  # the graphs of n acting passes, stacked (routine-gym before the change)
            outputs = [agent.get_action_and_value(torch.as_tensor(obs[s]),
                                                  torch.as_tensor(actions[s]))
                       for s in range(n)]
            loss = loss_of(agent, *(torch.stack([o[k] for o in outputs]) for k in (1, 2, 3)))
        loss.backward()
        grads.append([p.grad.clone() for p in agent.parameters()])
    for batched, stacked in zip(*grads, strict=True):
        torch.testing.assert_close(batched, stacked, rtol=1e-5, atol=1e-7)


def test_acting_draws_the_actions_get_action_and_value_draws(script):
    torch.manual_seed(0)
    obs, _, _ = _rollout(seed=2)
    agent = script.Agent("MinAtar/Breakout-v1", gym.spaces.Box(0.0, 1.0, obs.shape[2:],
                                                                np.float32), 6)
    draws = []
    for act_only in (True, False):
        torch.manual_seed(7)
        with torch.no_grad():
            draws.append(torch.stack([
                agent.act(torch.as_tensor(o)) if act_only
                else agent.get_action_and_value(torch.as_tensor(o))[0] for o in obs]))
    assert torch.equal(*draws) and len(set(draws[0].flatten().tolist())) > 1


@pytest.mark.parametrize("keep_graph", [True, False])
def test_decide_and_update_forward_give_both_forwards_the_same_outputs(script, keep_graph):
    # `--update-forward` behind one pair of Agent methods: the acting passes' kept graphs, or
    # one pass over the rollout, give the same draws and the same outputs bit for bit (each
    # state's network output does not depend on its batch), with a graph to train on.
    obs, _, _ = _rollout(seed=3)  # the sizes of the first test (bit for bit at these)
    n, e = obs.shape[0] - 1, obs.shape[1]
    space = gym.spaces.Box(0.0, 1.0, obs.shape[2:], np.float32)
    torch.manual_seed(0)
    reference = script.Agent("MinAtar/Breakout-v1", space, 6)
    torch.manual_seed(0)
    agent = script.Agent("MinAtar/Breakout-v1", space, 6, keep_graph=keep_graph)
    for _ in range(2):  # a second rollout: the first one's kept passes are gone
        torch.manual_seed(7)
        actions = np.stack([agent.decide(torch.as_tensor(obs[s])).numpy() for s in range(n)])
        torch.manual_seed(7)
        with torch.no_grad():
            expected = [reference.get_action_and_value(torch.as_tensor(obs[s]))
                        for s in range(n)]
        logprobs, entropies, values, bootstrap = agent.update_forward(obs, obs[n], actions)
        assert np.array_equal(actions, np.stack([x[0].numpy() for x in expected]))
        for k, got in ((1, logprobs), (2, entropies), (3, values)):
            assert got.shape == (n * e,) and got.requires_grad
            assert torch.equal(got.detach(), torch.cat([x[k] for x in expected]))
        with torch.no_grad():
            assert np.array_equal(bootstrap,
                                  reference.get_value(torch.as_tensor(obs[n])).numpy())
