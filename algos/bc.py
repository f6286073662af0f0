"""Behavioural cloning from one demonstration, CleanRL style (the paper's BC baseline, SPEC §6).

    python algos/bc.py --env-id ALE/Qbert-v5                 # the shipped Qbert demo
    python algos/bc.py --env-id MiniQbert-v0 --total-timesteps 2000

A policy network (the env's encoder from `routine_gym.networks` and a linear head over the
primitive actions) is fitted by cross-entropy to the demo's (state, action) pairs, with no
interaction with the env: `--total-timesteps` counts gradient steps. The demo's states are
rebuilt in the agent's view by replaying the demo (`routine_gym.imitation.agent_view_states`).
The trained policy is then evaluated like SQIL's and GAIL's (`evaluate_imitation`): score and
alignment of its primitive actions with the demo's, in `eval.json`. With `--checkpoint-every` a
killed run resumes (`--resume`) exactly where it stopped: same batches, same optimizer state.
"""

from __future__ import annotations

import json
import os
import random
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from torch.distributions.categorical import Categorical
from torch.utils.tensorboard import SummaryWriter

import routine_gym
from routine_gym.checkpoint import resume_settings, write_checkpoint
from routine_gym.imitation import (
    agent_view_states,
    build_demo_transitions,
    check_demo_env,
    evaluate_imitation,
    load_demo,
    save_evaluation,
)
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.rng import rng_state, set_rng_state


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

    # Algorithm
    env_id: str = "ALE/Qbert-v5"
    """the env id: `ALE/*-v5`, `procgen/CoinRun-v0`, `MiniQbert-v0` or any discrete env"""
    demo: str | None = None
    """the demo to imitate (default: the shipped demo of the env in demos/)"""
    total_timesteps: int = 10_000
    """gradient steps (BC does not interact with the env)"""
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
    (a --total-timesteps other than the default raises the budget to it)"""
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


def save_checkpoint(path: str, policy: Policy, optimizer, step: int, args: Args,
                    rng: np.random.Generator) -> None:
    """Write a resumable checkpoint atomically (a kill mid-write keeps the previous one)."""
    write_checkpoint(
        {
            "model": policy.state_dict(),
            "optimizer": optimizer.state_dict(),
            "step": step,
            "rng": rng_state(rng),
            "args": json.dumps(asdict(args)),
        },
        path,
    )


def main(args: Args) -> dict | None:
    for name, ok in (("total_timesteps", args.total_timesteps >= 0),
                     ("batch_size", args.batch_size >= 1),
                     ("eval_episodes", args.eval_episodes >= 0)):
        if not ok:
            raise ValueError(f"--{name.replace('_', '-')} needs to be ≥ {int(name == 'batch_size')}"
                             f", actual value: {getattr(args, name)}")
    if args.resume:
        # The saved settings; an explicit --total-timesteps may raise the budget.
        args, checkpoint, run_path = resume_settings(args, CHECKPOINT_KEYS, "bc.py")
        run_name = os.path.basename(run_path)
    else:
        checkpoint = None
        env_name = args.env_id.replace("/", "-")
        run_name = f"{env_name}__{args.exp_name}__{args.seed}__{int(time.time())}"
        run_path = os.path.join(args.run_dir, run_name)
    os.makedirs(run_path, exist_ok=True)
    writer = SummaryWriter(run_path)
    writer.add_text(
        "hyperparameters",
        "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items()),
    )
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")

    # The demo's (state, action) pairs: D_prim, with states in the agent's view.
    demo, args.demo = load_demo(args.env_id, args.demo)
    num_actions = check_demo_env(demo, args.env_id)
    pairs = build_demo_transitions(demo, agent_view_states(demo, args.env_id), gamma=1.0)
    states = torch.as_tensor(pairs.states[pairs.state_index], device=device)
    actions = torch.as_tensor(pairs.actions, device=device)
    print(f"demo {args.demo}: score {demo.score:g}, {len(pairs)} (state, action) pairs",
          flush=True)
    policy = Policy(args.env_id, pairs.states.shape[1:], pairs.states.dtype, num_actions).to(device)
    optimizer = torch.optim.Adam(policy.parameters(), lr=args.learning_rate, fused=True)

    step = 0
    if checkpoint is not None:
        policy.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        step = checkpoint["step"]
        set_rng_state(checkpoint["rng"], rng)
        print(f"resumed {run_name} at step {step}")
    checkpoint_path = os.path.join(run_path, "checkpoint.pt")

    start_time, start_step = time.time(), step
    while step < args.total_timesteps:
        step += 1
        i = torch.as_tensor(rng.integers(0, len(pairs), size=args.batch_size), device=device)
        logits = policy(states[i])
        loss = F.cross_entropy(logits, actions[i])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        sps = int((step - start_step) / max(time.time() - start_time, 1e-9))
        if step % 100 == 0 or step == args.total_timesteps:
            accuracy = (logits.argmax(1) == actions[i]).float().mean().item()
            writer.add_scalar("losses/bc_loss", loss.item(), step)
            writer.add_scalar("losses/accuracy", accuracy, step)
            writer.add_scalar("charts/SPS", sps, step)
        if step % args.log_every == 0 or step == args.total_timesteps:
            print(f"step {step:>8,d}/{args.total_timesteps:,d}  loss {loss.item():.4f}  "
                  f"SPS {sps}", flush=True)
        if args.checkpoint_every > 0 and step % args.checkpoint_every == 0:
            save_checkpoint(checkpoint_path, policy, optimizer, step, args, rng)

    if args.checkpoint_every > 0:
        save_checkpoint(checkpoint_path, policy, optimizer, step, args, rng)

    if args.save_model:
        model_path = os.path.join(run_path, "model.pt")
        torch.save(policy.state_dict(), model_path + ".tmp")
        os.replace(model_path + ".tmp", model_path)
        print(f"model saved to {model_path}")

    summary = None
    if args.eval_episodes > 0:
        def act(observation: np.ndarray) -> int:
            with torch.no_grad():
                logits = policy(torch.as_tensor(np.asarray(observation)[None], device=device))[0]
            if args.eval_greedy:
                return int(logits.argmax())
            return int(Categorical(logits=logits).sample())

        summary = evaluate_imitation(args.env_id, act, demo, args.eval_episodes,
                                     seed=args.seed + 10_000, max_steps=args.eval_max_steps)
        summary.update(method="bc", global_step=step)
        save_evaluation(summary, run_path, writer, step)
    writer.close()
    return summary


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    main(tyro.cli(Args))
