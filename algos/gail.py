"""GAIL from one demonstration with a PPO generator, CleanRL style (the paper's GAIL baseline).

    python algos/gail.py --env-id ALE/Qbert-v5                 # the shipped Qbert demo
    python algos/gail.py --env-id MiniQbert-v0 --total-timesteps 50000

Generative adversarial imitation learning (Ho & Ermon 2016). A discriminator `D(s, a)` learns
to tell the demo's (state, action) pairs (label 1) from the generator's (label 0) by binary
cross-entropy; it is the env's encoder with one logit per action, `D(s, a) = σ(logit_a(s))`.
The generator is CleanRL's PPO (`ppo_atari.py`: GAE, clipped surrogate, value clipping,
entropy bonus) trained on the discriminator's reward instead of the env's:

    r(s, a) = −log(1 − D(s, a)) = softplus(logit_a(s))       (--reward gail, the default)
    r(s, a) = log D(s, a)       = −softplus(−logit_a(s))     (--reward logd)

The first is positive (a survival bonus: it favours long episodes), the second negative (it
favours ending episodes early); both are the usual choices of the GAIL literature. Each
iteration collects a rollout, updates D on it (against as many demo pairs), relabels the rollout
with the updated D, then runs the PPO update. `--total-timesteps` counts primitive env steps.
The trained policy is evaluated like every script's (`evaluate_policy`), in `eval.json`.
With `--checkpoint-every` a killed run resumes (`--resume`) from its last checkpoint: networks,
optimizers, step count and random generators as they were; the envs start fresh episodes.
"""

from __future__ import annotations

from routine_gym.plumbing.openmp import shorten_spin

shorten_spin()  # before torch loads OpenMP: a shorter spin of its idle threads (see there)

import os
import time
import warnings
from dataclasses import dataclass
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch.distributions.categorical import Categorical

import routine_gym
from routine_gym.envs.factory import make_env
from routine_gym.imitation import agent_view_states, demo_pairs
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.loading import check_demo_env, load_demo
from routine_gym.plumbing.memory import check_rollout_memory
from routine_gym.plumbing.run import Every, run_script, start_run


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
    learning_rate: float = 2.5e-4
    """the learning rate of the generator's Adam optimizer"""
    num_envs: int = 8
    """the number of parallel environments"""
    num_steps: int = 128
    """steps per environment per rollout"""
    anneal_lr: bool = True
    """linear decay of the generator's learning rate to 0"""
    gamma: float = 0.99
    """the discount factor γ"""
    gae_lambda: float = 0.95
    """the λ of generalised advantage estimation"""
    num_minibatches: int = 4
    """the number of PPO minibatches"""
    update_epochs: int = 4
    """the number of PPO epochs per rollout"""
    norm_adv: bool = True
    """normalise the advantages"""
    clip_coef: float = 0.1
    """the PPO clipping coefficient"""
    clip_vloss: bool = True
    """clip the value loss as PPO does"""
    ent_coef: float = 0.01
    """coefficient of the entropy bonus"""
    vf_coef: float = 0.5
    """coefficient of the value loss"""
    max_grad_norm: float = 0.5
    """the maximum norm for gradient clipping"""

    # Discriminator
    reward: Literal["gail", "logd"] = "gail"
    """gail: r = −log(1 − D(s, a)); logd: r = log D(s, a)"""
    disc_learning_rate: float = 3e-4
    """the learning rate of the discriminator's Adam optimizer"""
    disc_epochs: int = 1
    """passes of the discriminator over each rollout"""
    disc_minibatches: int = 4
    """minibatches per discriminator pass (each paired with as many demo pairs)"""

    # Running it
    eval_episodes: int = 100
    """episodes to evaluate the final policy on (0 disables); results in eval.json"""
    eval_greedy: bool = False
    """evaluate the most likely action instead of sampling the policy"""
    eval_max_steps: int | None = None
    """cap on the primitive steps of an evaluation episode (default: the env's own limit)"""
    save_model: bool = False
    """save the final generator and discriminator to runs/{run_name}/model.pt"""
    checkpoint_every: int = 0
    """save a resumable checkpoint every this many primitive steps (0: never)"""
    resume: str | None = None
    """checkpoint file (or run folder) to resume from; the envs start fresh episodes. The saved
    settings hold (a --total-timesteps other than the default raises the budget to it)"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 1
    """torch CPU threads (0: torch's default)"""


class Agent(nn.Module):
    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.actor = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)
        self.critic = layer_init(nn.Linear(self.encoder.num_features, 1), std=1.0)

    def get_value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(self.encoder(obs)).squeeze(-1)

    def get_action_and_value(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        hidden = self.encoder(obs)
        dist = Categorical(logits=self.actor(hidden))
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action), dist.entropy(), self.critic(hidden).squeeze(-1)


class Discriminator(nn.Module):
    """`logit_a(s)` for every action; `D(s, a) = σ(logit_a(s))` is P(the pair is the demo's)."""

    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.head = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)

    def forward(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.head(self.encoder(obs)).gather(1, action[:, None]).squeeze(1)


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("agent", "discriminator", "optimizer", "disc_optimizer", "global_step", "rng",
                   "args")


def main(args: Args) -> dict | None:
    run = start_run(args, "gail.py", CHECKPOINT_KEYS)
    args, device, rng, writer = run.args, run.device, run.rng, run.writer

    # The demo's (state, action) pairs: one per decision, with states in the agent's view.
    demo, args.demo = load_demo(args.env_id, args.demo)
    num_actions = check_demo_env(demo, args.env_id)
    pairs = demo_pairs(demo, agent_view_states(demo, args.env_id))
    demo_obs = torch.as_tensor(pairs.observations, device=device)
    demo_actions = torch.as_tensor(pairs.actions, device=device)
    print(f"demo {args.demo}: score {demo.score:g}, {len(pairs)} (state, action) pairs",
          flush=True)

    # Env setup: same-step autoreset, so the step that ends an episode returns the reset obs.
    envs = gym.vector.SyncVectorEnv(
        [make_env(args.env_id, args.seed, i, training=True, env_kwargs=demo.env_kwargs)
         for i in range(args.num_envs)],
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )
    obs_space = envs.single_observation_space
    agent = Agent(args.env_id, obs_space, num_actions).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5, fused=True)
    discriminator = Discriminator(args.env_id, obs_space, num_actions).to(device)
    disc_optimizer = torch.optim.Adam(discriminator.parameters(), lr=args.disc_learning_rate,
                                      fused=True)

    batch_size = args.num_envs * args.num_steps
    minibatch_size = max(batch_size // args.num_minibatches, 1)
    num_iterations = max(args.total_timesteps // batch_size, 1)
    check_rollout_memory(obs_space, args.num_steps, args.num_envs, observations=2, numbers=6)
    obs = torch.zeros((args.num_steps, args.num_envs, *obs_space.shape),
                      dtype=torch.as_tensor(obs_space.sample()).dtype, device=device)
    actions = torch.zeros((args.num_steps, args.num_envs), dtype=torch.long, device=device)
    logprobs = torch.zeros((args.num_steps, args.num_envs), device=device)
    dones = torch.zeros((args.num_steps, args.num_envs), device=device)
    values = torch.zeros((args.num_steps, args.num_envs), device=device)

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    global_step = run.resume({"agent": agent, "discriminator": discriminator,
                              "optimizer": optimizer, "disc_optimizer": disc_optimizer},
                             global_step=0)

    start_time, start_step = time.time(), global_step
    logs = Every(args.log_every, start=global_step)
    recent_returns: list[float] = []
    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw.
    next_obs_np, _ = envs.reset(seed=args.seed + global_step)
    next_obs = torch.as_tensor(next_obs_np, device=device)
    next_done = torch.zeros(args.num_envs, device=device)

    # Each iteration is batch_size primitive steps, so a resumed run picks up at the next one.
    for iteration in range(global_step // batch_size + 1, num_iterations + 1):
        if args.anneal_lr:
            optimizer.param_groups[0]["lr"] = \
                (1.0 - (iteration - 1.0) / num_iterations) * args.learning_rate

        for step in range(args.num_steps):
            global_step += args.num_envs
            obs[step] = next_obs
            dones[step] = next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
            actions[step], logprobs[step], values[step] = action, logprob, value
            next_obs_np, _, terminated, truncated, info = envs.step(action.cpu().numpy())
            next_obs = torch.as_tensor(next_obs_np, device=device)
            next_done = torch.as_tensor(terminated | truncated, dtype=torch.float32,
                                        device=device)
            final = info.get("final_info", {})
            if "episode" in final:
                for i in np.flatnonzero(final["_episode"]):
                    ret = float(final["episode"]["r"][i])
                    recent_returns.append(ret)
                    writer.add_scalar("charts/episodic_return", ret, global_step)
                    writer.add_scalar("charts/episodic_length", int(final["episode"]["l"][i]),
                                      global_step)

        # Discriminator: the demo's pairs are 1, the rollout's 0.
        b_obs = obs.reshape(-1, *obs_space.shape)
        b_actions = actions.reshape(-1)
        disc_size = max(batch_size // args.disc_minibatches, 1)
        for _ in range(args.disc_epochs):
            order = torch.randperm(batch_size, device=device)
            for start in range(0, batch_size, disc_size):
                agent_i = order[start : start + disc_size]
                demo_i = torch.as_tensor(rng.integers(0, len(pairs), size=len(agent_i)),
                                         device=device)
                expert_logits = discriminator(demo_obs[demo_i], demo_actions[demo_i])
                agent_logits = discriminator(b_obs[agent_i], b_actions[agent_i])
                disc_loss = F.binary_cross_entropy_with_logits(
                    expert_logits, torch.ones_like(expert_logits)
                ) + F.binary_cross_entropy_with_logits(agent_logits, torch.zeros_like(agent_logits))
                disc_optimizer.zero_grad()
                disc_loss.backward()
                check_update(global_step, disc_loss, parts={"discriminator loss": disc_loss})
                disc_optimizer.step()

        # The generator's rewards from the updated discriminator.
        with torch.no_grad():
            logits = discriminator(b_obs, b_actions)
            if args.reward == "gail":
                rewards = F.softplus(logits)  # −log(1 − σ(x))
            else:
                rewards = -F.softplus(-logits)  # log σ(x)
            rewards = rewards.reshape(args.num_steps, args.num_envs)
            expert_acc = (discriminator(demo_obs, demo_actions) > 0).float().mean()

            # GAE, as CleanRL's PPO (an episode end cuts the bootstrap).
            next_value = agent.get_value(next_obs)
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                if t == args.num_steps - 1:
                    nextnonterminal = 1.0 - next_done
                    nextvalues = next_value
                else:
                    nextnonterminal = 1.0 - dones[t + 1]
                    nextvalues = values[t + 1]
                delta = rewards[t] + args.gamma * nextvalues * nextnonterminal - values[t]
                advantages[t] = lastgaelam = \
                    delta + args.gamma * args.gae_lambda * nextnonterminal * lastgaelam
            returns = advantages + values

        b_logprobs = logprobs.reshape(-1)
        b_advantages = advantages.reshape(-1)
        b_returns = returns.reshape(-1)
        b_values = values.reshape(-1)
        b_inds = np.arange(batch_size)
        clipfracs = []
        for _ in range(args.update_epochs):
            np.random.shuffle(b_inds)
            for start in range(0, batch_size, minibatch_size):
                mb_inds = b_inds[start : start + minibatch_size]
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(
                    b_obs[mb_inds], b_actions[mb_inds]
                )
                logratio = newlogprob - b_logprobs[mb_inds]
                ratio = logratio.exp()
                with torch.no_grad():
                    approx_kl = ((ratio - 1) - logratio).mean()
                    clipfracs += [((ratio - 1.0).abs() > args.clip_coef).float().mean().item()]
                mb_advantages = b_advantages[mb_inds]
                if args.norm_adv and len(mb_inds) > 1:
                    mb_advantages = (mb_advantages - mb_advantages.mean()) \
                        / (mb_advantages.std() + 1e-8)
                pg_loss1 = -mb_advantages * ratio
                pg_loss2 = -mb_advantages * torch.clamp(ratio, 1 - args.clip_coef,
                                                        1 + args.clip_coef)
                pg_loss = torch.max(pg_loss1, pg_loss2).mean()
                if args.clip_vloss:
                    v_loss_unclipped = (newvalue - b_returns[mb_inds]) ** 2
                    v_clipped = b_values[mb_inds] + torch.clamp(
                        newvalue - b_values[mb_inds], -args.clip_coef, args.clip_coef
                    )
                    v_loss_clipped = (v_clipped - b_returns[mb_inds]) ** 2
                    v_loss = 0.5 * torch.max(v_loss_unclipped, v_loss_clipped).mean()
                else:
                    v_loss = 0.5 * ((newvalue - b_returns[mb_inds]) ** 2).mean()
                entropy_loss = entropy.mean()
                loss = pg_loss - args.ent_coef * entropy_loss + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                check_update(global_step, loss, grad_norm, parts={
                    "value loss": v_loss, "policy loss": pg_loss, "entropy": entropy_loss})
                optimizer.step()

        sps = int((global_step - start_step) / max(time.time() - start_time, 1e-9))
        writer.add_scalar("charts/learning_rate", optimizer.param_groups[0]["lr"], global_step)
        writer.add_scalar("losses/value_loss", v_loss.item(), global_step)
        writer.add_scalar("losses/policy_loss", pg_loss.item(), global_step)
        writer.add_scalar("losses/entropy", entropy_loss.item(), global_step)
        writer.add_scalar("losses/approx_kl", approx_kl.item(), global_step)
        writer.add_scalar("losses/clipfrac", np.mean(clipfracs), global_step)
        writer.add_scalar("losses/disc_loss", disc_loss.item(), global_step)
        writer.add_scalar("losses/disc_expert_accuracy", expert_acc.item(), global_step)
        writer.add_scalar("charts/gail_reward", rewards.mean().item(), global_step)
        writer.add_scalar("charts/SPS", sps, global_step)
        if logs.due(global_step) or iteration == num_iterations:
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            print(f"step {global_step:>10,d}/{args.total_timesteps:,d}  "
                  f"SPS {sps:>5d}  return(last 20) {mean_ret:>8s}  "
                  f"disc loss {disc_loss.item():.3f}  gail reward {rewards.mean().item():.3f}",
                  flush=True)
        run.checkpoint_if_due(global_step=global_step)

    envs.close()

    def act(observation: np.ndarray) -> int:
        with torch.no_grad():
            hidden = agent.encoder(torch.as_tensor(np.asarray(observation)[None], device=device))
            logits = agent.actor(hidden)[0]
        if args.eval_greedy:
            return int(logits.argmax())
        return int(Categorical(logits=logits).sample())

    return run.finish(act, model={"agent": agent, "discriminator": discriminator},
                      method="gail", demo=demo, max_steps=args.eval_max_steps,
                      global_step=global_step)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args)
