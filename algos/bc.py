"""Behavioural cloning from one demonstration, CleanRL style (the paper's BC baseline, SPEC §6).

    python algos/bc.py --env-id ALE/Qbert-v5                 # the shipped Qbert demo
    python algos/bc.py --env-id MiniQbert-v0 --gradient-steps 2000

A policy network (the env's encoder from `routine_gym.networks` and a linear head over the
primitive actions) is fitted by cross-entropy to the demo's (state, action) pairs, with no
interaction with the env: its budget is `--gradient-steps`. The pairs are the demonstrator's
decisions (`routine_gym.imitation.demo_pairs`), with the demo's states rebuilt in the agent's
view by replaying the demo (`agent_view_states`). The trained policy is then evaluated like
every script's (`routine_gym.plumbing.evaluation.evaluate_policy`): score and alignment of
its primitive actions with the demo's, in `eval.json`. With `--checkpoint-every` a killed run
resumes (`--resume`) exactly where it stopped: same batches, same optimizer state.
"""

from __future__ import annotations

from routine_gym.plumbing.openmp import shorten_spin

shorten_spin()  # before torch loads OpenMP: a shorter spin of its idle threads (see there)

import os
import time
import warnings
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch.distributions.categorical import Categorical

import routine_gym
from routine_gym.imitation import agent_view_states, demo_pairs
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.loading import check_demo_env, load_demo
from routine_gym.plumbing.memory import check_memory
from routine_gym.plumbing.run import run_script, start_run


@dataclass
class Args:
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment"""
    seed: int = 1
    """seed of the experiment"""
    torch_deterministic: bool = True
    """if toggled, `torch.backends.cudnn.deterministic=True`"""
    cuda: bool = False
    """if toggled, use CUDA when available (the CPU is the default)"""
    track: bool = False
    """if toggled, also log the run to Weights & Biases (TensorBoard is always written)"""
    wandb_project_name: str = "routine-gym"
    """the W&B project of --track"""
    wandb_entity: str | None = None
    """the W&B entity (team) of --track (default: your W&B default entity)"""

    # Algorithm
    env_id: str = "ALE/Qbert-v5"
    """the env id: `ALE/*-v5`, `procgen/CoinRun-v0`, `MiniQbert-v0` or any discrete env"""
    demo: str | None = None
    """the demo to imitate (default: the shipped demo of the env in demos/)"""
    gradient_steps: int = 10_000
    """gradient steps of the experiment (BC does not interact with the env)"""
    learning_rate: float = 1e-3
    """the learning rate of the Adam optimizer"""
    batch_size: int = 64
    """(state, action) pairs per gradient step, drawn with replacement"""

    # Running it
    eval_episodes: int = 100
    """episodes to evaluate the final policy on (0 disables); results in eval.json"""
    eval_greedy: bool = False
    """evaluate the most likely action instead of sampling the policy"""
    eval_max_steps: int | None = None
    """cap on the primitive steps of an evaluation episode (default: the env's own limit)"""
    save_model: bool = False
    """save the final model to runs/{run_name}/model.pt"""
    checkpoint_every: int = 0
    """save a resumable checkpoint every this many gradient steps (0: never)"""
    resume: str | None = None
    """checkpoint file (or run folder) to resume from, with its saved settings
    (a --gradient-steps other than the default raises the budget to it)"""
    log_every: int = 1_000
    """print a progress line every this many gradient steps"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 1
    """torch CPU threads (0: torch's default)"""


class Policy(nn.Module):
    def __init__(self, env_id: str, obs_shape: tuple[int, ...], obs_dtype: np.dtype,
                 num_actions: int) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_shape, obs_dtype)
        self.actor = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.actor(self.encoder(obs))


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "step", "rng", "args")


def main(args: Args) -> dict | None:
    run = start_run(args, "bc.py", CHECKPOINT_KEYS, budget="gradient_steps")
    args, device, rng, writer = run.args, run.device, run.rng, run.writer

    # The demo's (state, action) pairs: one per decision, with states in the agent's view.
    demo, args.demo = load_demo(args.env_id, args.demo)
    num_actions = check_demo_env(demo, args.env_id)
    pairs = demo_pairs(demo, agent_view_states(demo, args.env_id))
    check_memory(args.batch_size * pairs.observations[0].nbytes,
                 f"a batch (--batch-size {args.batch_size:,} × {pairs.observations[0].nbytes:,} B)")
    states = torch.as_tensor(pairs.observations, device=device)
    actions = torch.as_tensor(pairs.actions, device=device)
    print(f"demo {args.demo}: score {demo.score:g}, {len(pairs)} (state, action) pairs",
          flush=True)
    policy = Policy(args.env_id, pairs.states.shape[1:], pairs.states.dtype, num_actions).to(device)
    optimizer = torch.optim.Adam(policy.parameters(), lr=args.learning_rate, fused=True)

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    step = run.resume({"model": policy, "optimizer": optimizer}, step=0)

    start_time, start_step = time.time(), step
    while step < args.gradient_steps:
        step += 1
        i = torch.as_tensor(rng.integers(0, len(pairs), size=args.batch_size), device=device)
        logits = policy(states[i])
        loss = F.cross_entropy(logits, actions[i])
        optimizer.zero_grad()
        loss.backward()
        check_update(step, loss, parts={"BC loss": loss}, unit="gradient step")
        optimizer.step()
        sps = int((step - start_step) / max(time.time() - start_time, 1e-9))
        if step % 100 == 0 or step == args.gradient_steps:
            accuracy = (logits.argmax(1) == actions[i]).float().mean().item()
            writer.add_scalar("losses/bc_loss", loss.item(), step)
            writer.add_scalar("losses/accuracy", accuracy, step)
            writer.add_scalar("charts/SPS", sps, step)
        if step % args.log_every == 0 or step == args.gradient_steps:
            print(f"step {step:>8,d}/{args.gradient_steps:,d}  loss {loss.item():.4f}  "
                  f"SPS {sps}", flush=True)
        run.checkpoint_if_due(step=step)

    def act(observation: np.ndarray) -> int:
        with torch.no_grad():
            logits = policy(torch.as_tensor(np.asarray(observation)[None], device=device))[0]
        if args.eval_greedy:
            return int(logits.argmax())
        return int(Categorical(logits=logits).sample())

    return run.finish(act, model=policy, method="bc", demo=demo, max_steps=args.eval_max_steps,
                      step=step)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args, renamed={"--total-timesteps": "--gradient-steps"})
