"""RAPL-SQIL and plain SQIL in one CleanRL-style file (SPEC §5).

    python algos/rapl_sqil.py --env-id ALE/Qbert-v5                    # RAPL-SQIL, shipped demo
    python algos/rapl_sqil.py --env-id ALE/Qbert-v5 --num-routines 0   # plain SQIL
    python algos/rapl_sqil.py --env-id CartPole-v1 --demo demo.npz     # any discrete env

Soft Q-learning with SQIL rewards (Reddy et al. 2020) over the routine-augmented action space
`Discrete(n + K)`. Demo transitions get reward 1 per primitive step, the agent's own get 0:

    D_demo = D_prim ∪ D_routine      D_prim: (s_t, a_t, s_{t+1}) of every demo step
                                     D_routine: (s_t, n+k, s_{t+|ρ_k|}) per occurrence of ρ_k
    y = R_sq + Γ · α log Σ_a' exp(Q_target(s', a')/α)      (no bootstrap after termination)
    R_sq = Σ_{τ=1}^{ℓ} γ^{τ-1} r   (r = 1 demo, 0 agent),   Γ = γ^ℓ
    L = mean_demo (Q(s,a) − y)² + λ_sample · mean_agent (Q(s,a) − y)²

ℓ is the primitive length of a transition: 1 for a primitive action, |ρ| for a demo routine
occurrence, the executed length (`info["routine_length"]`) for an agent decision. Each batch is
half demo, half agent transitions; the agent explores with the soft-Q policy π ∝ exp(Q/α).
The target network is a copy of the Q-network refreshed every `--target-network-frequency`
gradient updates (`--tau 1`, as DQN) or moved towards it by Polyak averaging (`--tau < 1`).
Gradient updates follow primitive steps (one per `--train-frequency` steps), so SQIL and
RAPL-SQIL get the same number of updates for the same budget of env steps.

Two properties to know when reading results. A terminal transition is not bootstrapped (SPEC
§5), so with rewards ≥ 0 ending an episode is worth less than going on: SQIL agents avoid
finishing a game (on MiniQbert they colour all but the last cube and play to the time limit,
where the demo ends after 39 steps; alignment only reads the first |demo| actions). And α
matters: at α = 1 a demo step's reward 1 is only one temperature unit above the rest, so the
Boltzmann policy still strays often, and routines (several demo steps per decision) pay off
most; at α = 0.1 the policy is near-greedy (`bench/results/imitation.md` has both).

The agent's replay memory (`routine_gym.imitation.FrameReplayMemory`) stores each Atari frame
once and rebuilds the 4-frame stacks by index. Logged steps (`global_step`, `charts/SPS`) count
primitive env steps. After training the policy is evaluated by `evaluate_policy`: score and
alignment of its primitive actions with the demo's, in `eval.json`.
"""

from __future__ import annotations

from routine_gym.plumbing.openmp import shorten_spin

shorten_spin()  # before torch loads OpenMP: a shorter spin of its idle threads (see there)

import json
import os
import time
import warnings
from dataclasses import dataclass
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from torch.distributions.categorical import Categorical

import routine_gym
from routine_gym.envs import profile_for
from routine_gym.envs.factory import make_env
from routine_gym.imitation import agent_view_states, build_demo_transitions, sqil_target
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.plumbing.counters import scalars_due
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.loading import check_demo_env, load_demo, unused_routine_flags
from routine_gym.plumbing.memory import check_memory
from routine_gym.plumbing.run import Every, run_script, start_run
from routine_gym.replay_memory import FrameReplayMemory


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
    total_timesteps: int = 1_000_000
    """total primitive env steps of the experiment"""
    learning_rate: float = 1e-3
    """the learning rate of the Adam optimizer"""
    buffer_size: int = 100_000
    """replay memory capacity in frames (Atari: 84×84 B each, min(ℓ, 4) kept per ℓ-step decision)"""
    gamma: float = 0.99
    """the discount factor γ per primitive step"""
    temperature: float = 1.0
    """α, the soft-Q temperature of the target and of the Boltzmann exploration"""
    tau: float = 1.0
    """target network update rate: 1 copies the Q-network, < 1 is Polyak averaging"""
    target_network_frequency: int = 500
    """gradient updates between target network updates"""
    batch_size: int = 32
    """transitions per gradient update, half from the demo and half from the agent"""
    lambda_sample: float = 1.0
    """weight λ_sample of the agent transitions' loss"""
    learning_starts: int = 1_000
    """primitive env steps before learning starts"""
    train_frequency: int = 4
    """primitive env steps per gradient update"""

    # Routines
    num_routines: int = 3
    """K, the number of routines (0: plain SQIL on the primitive actions)"""
    routine_library: str | None = None
    """a routine library JSON to use (its best K) instead of mining the demo"""
    length_weight: float = 0.1
    """λ_length in the routine score f + λ·len"""
    alpha: int = 2
    """Levenshtein distance under which similar routines are pruned"""
    proposer: Literal["full", "random", "enumerate", "random-fetch", "repeat", "bpe"] = "full"
    """full: Sequitur (the paper's model); bpe: byte-pair encoding; the others are the discovery
    ablations"""
    max_routine_length: int = 64
    """ignore routine candidates longer than this (the wrapper pads every step to the longest)"""

    # Running it
    eval_episodes: int = 100
    """episodes to evaluate the final policy on (0 disables); results in eval.json"""
    eval_greedy: bool = False
    """evaluate the greedy policy argmax Q instead of the soft-Q policy π ∝ exp(Q/α)"""
    eval_max_steps: int | None = None
    """cap on the primitive steps of an evaluation episode (default: the env's own limit)"""
    save_model: bool = False
    """save the final model to runs/{run_name}/model.pt"""
    checkpoint_every: int = 0
    """save a resumable checkpoint every this many primitive steps (0: never)"""
    resume: str | None = None
    """checkpoint file (or run folder) to resume a killed run from (the replay memory refills)"""
    scalars_every: int = 100
    """write the per-update TensorBoard scalars (losses, Q-values, SPS, routine usage) every this
    many gradient updates; episode returns are written at every episode end"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 1
    """torch CPU threads (0: torch's default); 1 leaves the other core to the environment"""


class QNetwork(nn.Module):
    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.head = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=1.0)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(obs))


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "target", "optimizer", "global_step", "updates", "rng", "args",
                   "library")


def extra_checks(args: Args) -> list[tuple[str, bool, str]]:
    """SQIL's rule on top of `routine_gym.plumbing.arguments.DOMAINS`: a batch is half demo, half
    agent."""
    return [("batch_size", args.batch_size >= 2, "≥ 2 (half demo, half agent)"),
            # A routine flag the run would not read (the demo is SQIL's demo buffer: read).
            *unused_routine_flags(args, "--num-routines 0" if args.num_routines == 0 else None,
                                  demo_only_mined=False)]


def main(args: Args) -> dict | None:
    run = start_run(args, "rapl_sqil.py", CHECKPOINT_KEYS, extra_checks=extra_checks)
    args, device, rng, writer = run.args, run.device, run.rng, run.writer

    # The demo, its routines, and the demo buffer D_prim ∪ D_routine in the agent's view.
    demo, args.demo = load_demo(args.env_id, args.demo)
    num_primitives = check_demo_env(demo, args.env_id)
    library = run.routines(demo, meanings=lambda: demo.action_meanings)
    demo_buffer = build_demo_transitions(
        demo, agent_view_states(demo, args.env_id), args.gamma, library, num_primitives
    )
    print(f"demo {args.demo}: score {demo.score:g}, {len(demo)} steps; demo buffer "
          f"{int((~demo_buffer.is_routine).sum())} primitive + "
          f"{int(demo_buffer.is_routine.sum())} routine transitions", flush=True)

    # The agent acts in the env the demo was recorded in (its gym.make keyword arguments).
    env = make_env(args.env_id, args.seed, 0, routines=library, training=True,
                   env_kwargs=demo.env_kwargs)()
    obs_space = env.observation_space
    if obs_space.shape != demo_buffer.states.shape[1:]:
        raise ValueError(f"demo states {demo_buffer.states.shape[1:]} do not match the env's "
                         f"observations {obs_space.shape}")
    num_actions = int(env.action_space.n)

    q_network = QNetwork(args.env_id, obs_space, num_actions).to(device)
    target_network = QNetwork(args.env_id, obs_space, num_actions).to(device)
    target_network.load_state_dict(q_network.state_dict())
    # fused: one kernel per step instead of a dozen per tensor (8× faster on this CPU)
    optimizer = torch.optim.Adam(q_network.parameters(), lr=args.learning_rate, fused=True)
    frame_stack = profile_for(args.env_id).frame_stack
    frame_bytes = obs_space.dtype.itemsize * int(np.prod(obs_space.shape)) // frame_stack
    check_memory(args.buffer_size * (frame_bytes + 48),  # a frame and six numbers a transition
                 f"the replay memory (--buffer-size {args.buffer_size:,} × {frame_bytes:,} B)")
    memory = FrameReplayMemory(args.buffer_size, obs_space.shape, obs_space.dtype,
                               frame_stack=frame_stack)
    half = args.batch_size // 2

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    global_step, updates = run.resume(
        {"model": q_network, "target": target_network, "optimizer": optimizer},
        global_step=0, updates=0,
        extra={"library": json.dumps(library.to_dict()) if library is not None else ""})
    learning_starts = global_step + args.learning_starts  # a resumed run refills its memory first
    session_updates = 0  # updates of this process (a resumed run also counts the earlier ones)

    obs, _ = env.reset(seed=args.seed + global_step)
    memory.start_episode(obs)
    start_time, start_step = time.time(), global_step
    logs = Every(args.log_every, start=global_step)
    action_counts = np.zeros(num_actions, dtype=np.int64)
    recent_returns: list[float] = []

    while global_step < args.total_timesteps:
        # Boltzmann exploration with the soft-Q policy π(a|s) ∝ exp(Q(s, a)/α).
        with torch.no_grad():
            q = q_network(torch.as_tensor(np.asarray(obs)[None], device=device))
            action = int(Categorical(logits=q[0] / args.temperature).sample())
        next_obs, _, terminated, truncated, info = env.step(action)
        length = int(info.get("routine_length", 1))
        memory.add(action, length, terminated, next_obs)  # SQIL ignores the env's reward
        global_step += length
        action_counts[action] += 1
        if "episode" in info:  # the real game ended (not only a life, in training mode)
            ret = float(info["episode"]["r"])
            recent_returns.append(ret)
            writer.add_scalar("charts/episodic_return", ret, global_step)
            writer.add_scalar("charts/episodic_length", int(info["episode"]["l"]), global_step)
        if terminated or truncated:
            obs, _ = env.reset()
            memory.start_episode(obs)
        else:
            obs = next_obs

        # Gradient updates: one per train_frequency primitive steps after learning_starts.
        due = (global_step - learning_starts) // args.train_frequency + 1
        while global_step >= learning_starts and len(memory) > 0 and session_updates < due:
            d = demo_buffer.sample(half, rng)
            a = memory.sample(args.batch_size - half, rng)
            agent_rewards = np.zeros(len(a["actions"]))  # r = 0 for the agent: R_sq = 0
            batch = {
                "obs": np.concatenate([d["obs"], a["obs"]]),
                "actions": np.concatenate([d["actions"], a["actions"]]),
                "rewards": np.concatenate([d["rewards"], agent_rewards]),
                "discounts": np.concatenate([d["discounts"], args.gamma ** a["lengths"]]),
                "next_obs": np.concatenate([d["next_obs"], a["next_obs"]]),
                "terminated": np.concatenate([d["terminated"], a["terminated"]]),
            }
            b = {k: torch.as_tensor(v, device=device) for k, v in batch.items()}
            with torch.no_grad():
                target = sqil_target(b["rewards"].float(), b["discounts"].float(),
                                     b["terminated"], target_network(b["next_obs"]),
                                     args.temperature)
            q_values = q_network(b["obs"]).gather(1, b["actions"][:, None]).squeeze(1)
            td = (q_values - target).pow(2)
            demo_loss, agent_loss = td[:half].mean(), td[half:].mean()
            loss = demo_loss + args.lambda_sample * agent_loss
            optimizer.zero_grad()
            loss.backward()
            check_update(global_step, loss, parts={"demo loss": demo_loss,
                                                   "agent loss": agent_loss})
            optimizer.step()
            updates += 1
            session_updates += 1

            if updates % args.target_network_frequency == 0:
                for target_param, param in zip(target_network.parameters(),
                                               q_network.parameters(), strict=True):
                    target_param.data.copy_(args.tau * param.data
                                            + (1.0 - args.tau) * target_param.data)
            if scalars_due(updates, args.scalars_every, last=False):
                writer.add_scalar("losses/td_loss", loss.item(), global_step)
                writer.add_scalar("losses/demo_loss", demo_loss.item(), global_step)
                writer.add_scalar("losses/agent_loss", agent_loss.item(), global_step)
                writer.add_scalar("losses/demo_q_values", q_values[:half].mean().item(),
                                  global_step)
                writer.add_scalar("losses/agent_q_values", q_values[half:].mean().item(),
                                  global_step)
                elapsed = max(time.time() - start_time, 1e-9)
                writer.add_scalar("charts/SPS", int((global_step - start_step) / elapsed),
                                  global_step)
                usage = action_counts / max(action_counts.sum(), 1)
                for k in range(num_actions - num_primitives):
                    writer.add_scalar(f"routines/usage_{k}", usage[num_primitives + k],
                                      global_step)

        if logs.due(global_step) or global_step >= args.total_timesteps:
            elapsed = max(time.time() - start_time, 1e-9)
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            usage = action_counts[num_primitives:].sum() / max(action_counts.sum(), 1)
            print(f"step {global_step:>10,d}/{args.total_timesteps:,d}  "
                  f"SPS {int((global_step - start_step) / elapsed):>5d}  "
                  f"return(last 20) {mean_ret:>8s}  episodes {len(recent_returns):>5d}  "
                  f"updates {updates:>7d}  routine use {usage:5.1%}", flush=True)
        run.checkpoint_if_due(global_step=global_step, updates=updates)

    env.close()

    def policy(observation: np.ndarray) -> int:
        with torch.no_grad():
            q = q_network(torch.as_tensor(np.asarray(observation)[None], device=device))[0]
        if args.eval_greedy:
            return int(q.argmax())
        return int(Categorical(logits=q / args.temperature).sample())

    return run.finish(policy, model=q_network,
                      method="rapl-sqil" if library is not None else "sqil",
                      summary={"num_routines": len(library or ())}, demo=demo, routines=library,
                      max_steps=args.eval_max_steps, global_step=global_step, updates=updates)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args, renamed={"--routines": "--routine-library"})
