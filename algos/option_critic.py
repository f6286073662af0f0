"""The option-critic baseline (A2OC) in one CleanRL-style file (SPEC §5, the paper's Figure 3).

    python algos/option_critic.py --env-id ALE/Qbert-v5
    python algos/option_critic.py --env-id MinAtar/Breakout-v1 --total-timesteps 1000000

The synchronous advantage option-critic of Harb et al. 2018 ("When waiting is not an option")
for the option-critic architecture of Bacon, Harb & Precup 2017. It uses no demo. One torso
(the env's, as in `rapl_a2c.py`) carries three heads: option values `Q_Ω(s, ·)` over 4
options, an intra-option softmax policy `π_ω(· | s)` per option and a sigmoid termination
`β_ω(s)` per option. Each env runs one option at a time: at every state the running option ω
terminates with probability `β_ω(s)` (and at the start of an episode), and a new one is chosen
ε-greedily on `Q_Ω(s, ·)` (ε = 0.1); the action is drawn from `π_ω(· | s)`. With the targets of
`routine_gym.baselines.option_critic`:

    U(s', ω) = (1 − β_ω(s')) Q_Ω(s', ω) + β_ω(s') max Q_Ω(s', ·)     G_t = r_t + γ G_{t+1}, G_N = U
    L = −log π_ω(a_t|s_t)(G_t − Q_Ω(s_t, ω_t)) − λ_entropy H(π_ω(·|s_t))
        + λ_value (G_t − Q_Ω(s_t, ω_t))² + λ_β β_ω(s_{t+1})(Q_Ω(s_{t+1}, ω_t) − V_Ω(s_{t+1}) + ξ)

with deliberation cost ξ = 0.01 and V_Ω = max_ω Q_Ω. The A2C settings are `rapl_a2c.py`'s
(16 envs × N = 5, RMSprop 7e-4 with linear decay, γ 0.99, entropy 0.01, value 0.5, grad-norm
0.5), so a curve compares methods, not plumbing. Logged steps count primitive agent steps;
`options/usage_k` is the share of steps option k ran and `options/duration` the mean length of
the options that ended in the last logging window.
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
from torch.distributions.categorical import Categorical

import routine_gym
from routine_gym.baselines.option_critic import (
    choose_options,
    option_returns,
    termination_advantage,
    value_upon_arrival,
)
from routine_gym.envs.factory import make_vector_env
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.plumbing.counters import Counters, budget_progress, budget_spent
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.memory import check_rollout_memory
from routine_gym.plumbing.run import Every, eval_env_kwargs, run_script, start_run, train_env_kwargs


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
    """the env id: `ALE/*-v5`, `procgen/CoinRun-v0`, `MinAtar/*-v1`, `MiniQbert-v0` or any
    discrete env"""
    total_timesteps: int = 10_000_000
    """total primitive agent steps of the experiment (decisions with --budget-unit decisions)"""
    budget_unit: Literal["steps", "decisions"] = "steps"
    """what --total-timesteps, the learning-rate schedule and --checkpoint-every count:
    primitive agent steps, or decisions (option choices)"""
    learning_rate: float = 7e-4
    """the learning rate of the RMSprop optimizer"""
    anneal_lr: bool = True
    """linear decay of the learning rate to 0"""
    num_envs: int = 16
    """the number of parallel environments"""
    num_steps: int = 5
    """steps per environment per rollout (N)"""
    gamma: float = 0.99
    """the discount factor γ"""
    reward_scale: float | None = None
    """multiply each reward by this for learning (after Atari's sign clipping); the logged
    returns stay the game's score. Unset: the env profile's scale (MiniQbert 0.01, its 25- and
    100-point rewards swamp the value loss at 1; every other env 1)"""
    num_options: int = 4
    """the number of options"""
    option_epsilon: float = 0.1
    """ε of the ε-greedy choice of a new option"""
    deliberation_cost: float = 0.01
    """ξ, the termination regulariser added to the termination advantage"""
    ent_coef: float = 0.01
    """coefficient of the intra-option policies' entropy bonus (λ_entropy)"""
    vf_coef: float = 0.5
    """coefficient of the option-value loss (λ_value)"""
    term_coef: float = 1.0
    """coefficient of the termination loss (λ_β)"""
    max_grad_norm: float = 0.5
    """the maximum norm for gradient clipping"""
    rmsprop_alpha: float = 0.99
    """RMSprop smoothing constant"""
    rmsprop_eps: float = 1e-5
    """RMSprop epsilon"""

    # Procgen
    num_levels: int = 100
    """Procgen: number of training levels"""
    start_level: int = 0
    """Procgen: first training level"""
    distribution_mode: Literal["easy", "hard"] = "easy"
    """Procgen: level difficulty for training"""
    eval_distribution_mode: Literal["easy", "hard"] = "easy"
    """Procgen: difficulty of the (unseen) evaluation levels"""

    # Running it
    save_model: bool = False
    """save the final model to runs/{run_name}/model.pt"""
    checkpoint_every: int = 0
    """save a resumable checkpoint every this many primitive steps (decisions with
    --budget-unit decisions; 0: never)"""
    resume: str | None = None
    """checkpoint file (or run folder) to resume a killed run from, with its saved settings
    (a --total-timesteps other than the default sets a new budget)"""
    eval_episodes: int = 10
    """episodes to evaluate the final policy on (0 disables); results in eval.json"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps (decisions with --budget-unit
    decisions)"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 0
    """torch CPU threads (0: torch's default); 1 is faster when other jobs share the CPU"""


class Agent(nn.Module):
    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int,
                 num_options: int) -> None:
        super().__init__()
        self.num_options, self.num_actions = num_options, num_actions
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        features = self.encoder.num_features
        self.q_head = layer_init(nn.Linear(features, num_options), std=1.0)
        self.policy_head = layer_init(nn.Linear(features, num_options * num_actions), std=0.01)
        self.termination_head = layer_init(nn.Linear(features, num_options), std=0.01)

    def forward(self, obs: torch.Tensor):
        """`Q_Ω(s, ·)` (B, O), the intra-option logits (B, O, A) and `β(s)` (B, O)."""
        hidden = self.encoder(obs)
        logits = self.policy_head(hidden).view(-1, self.num_options, self.num_actions)
        return self.q_head(hidden), logits, torch.sigmoid(self.termination_head(hidden))


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "iteration", "decisions", "rng", "args")


#: The upper bound of --num-options.
MAX_OPTIONS = 1024


def extra_checks(args: Args) -> list[tuple[str, bool, str]]:
    """The option-critic flags' domains (the shared ones are in `plumbing.arguments.DOMAINS`)."""
    return [
        ("num_options", args.num_options >= 1, "≥ 1"),
        # Heads of num_options × actions outputs: far above the paper's 4 or 8.
        ("num_options", args.num_options <= MAX_OPTIONS, f"≤ {MAX_OPTIONS:,}"),
        ("option_epsilon", 0 <= args.option_epsilon <= 1, "in [0, 1]"),
        # A cost: a negative one would pay the agent for switching options.
        ("deliberation_cost", args.deliberation_cost >= 0, "≥ 0"),
        ("term_coef", args.term_coef >= 0, "≥ 0"),
    ]


def main(args: Args) -> dict | None:
    run = start_run(args, "option_critic.py", CHECKPOINT_KEYS, lower_budget=True,
                    extra_checks=extra_checks)
    args, device, rng, writer = run.args, run.device, run.rng, run.writer

    # Env setup: same-step autoreset, so the step that ends an episode returns the reset obs.
    # (MinAtar: all games stepped in one call, `routine_gym.envs.minatar_vector`.)
    envs = make_vector_env(args.env_id, args.num_envs, args.seed, training=True,
                           env_kwargs=train_env_kwargs(args))
    if not isinstance(envs.single_action_space, gym.spaces.Discrete):
        raise ValueError(f"option_critic.py needs a Discrete action space; {args.env_id} has "
                         f"{envs.single_action_space}")
    num_actions = int(envs.single_action_space.n)
    agent = Agent(args.env_id, envs.single_observation_space, num_actions,
                  args.num_options).to(device)
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=args.learning_rate,
                                    alpha=args.rmsprop_alpha, eps=args.rmsprop_eps)

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    # A decision is an option choice (an option that goes on is not one); with
    # --budget-unit decisions the budget, the schedule and --checkpoint-every count them.
    global_step, iteration, decisions = run.resume(
        {"model": agent, "optimizer": optimizer}, global_step=0, iteration=0, decisions=0,
        count="decisions" if args.budget_unit == "decisions" else "global_step")
    logs = Every(args.log_every, start=budget_spent(args.budget_unit, global_step, decisions))
    counts = Counters(writer, 0, args.num_options)
    n, e = args.num_steps, args.num_envs
    check_rollout_memory(envs.single_observation_space, n, e, observations=0, numbers=4)
    rewards = np.zeros((n, e), dtype=np.float64)
    dones = np.zeros((n, e), dtype=bool)
    arrival = np.zeros((n, e), dtype=bool)  # s_{t+1} continues the episode of s_t

    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw; every env starts with a fresh option.
    next_obs, _ = envs.reset(seed=args.seed + global_step)
    options = np.zeros(e, dtype=np.int64)
    starts = np.ones(e, dtype=bool)  # the option must be chosen anew at this state
    option_lengths = np.zeros(e, dtype=np.int64)
    finished_lengths: list[int] = []
    option_counts = np.zeros(args.num_options, dtype=np.int64)
    recent_returns: list[float] = []
    start_time, start_step = time.time(), global_step

    while (spent := budget_spent(args.budget_unit, global_step, decisions)) \
            < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - spent / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        # Rollout. The forward pass at each state keeps its graph: it gives the acting outputs
        # at s_t and the termination loss's β at s_t for the option that arrived there.
        q, logits, beta = agent(torch.as_tensor(next_obs, device=device))
        q_taken, logprobs, entropies, arrival_beta, arrival_q = [], [], [], [], []
        taken: list[torch.Tensor] = []
        for step in range(n):
            if step > 0:  # β_{ω_{t-1}}(s_t) and Q_Ω(s_t, ·) for the termination loss of t − 1
                arrival_beta.append(beta.gather(1, taken[-1][:, None]).squeeze(1))
                arrival_q.append(q.detach())
            # Terminate the running option with probability β_ω(s), then choose ε-greedily.
            beta_now = beta.detach().cpu().numpy()[np.arange(e), options]
            terminate = starts | (rng.random(e) < beta_now)
            finished_lengths += option_lengths[terminate & ~starts].tolist()
            option_lengths[terminate] = 0
            options = choose_options(q.detach().cpu().numpy(), options, terminate,
                                     args.option_epsilon, rng)
            decisions += int(terminate.sum())
            counts.add(options[terminate], steps=e)
            option_t = torch.as_tensor(options, device=device)
            dist = Categorical(logits=logits[torch.arange(e), option_t])
            action = dist.sample()
            q_taken.append(q.gather(1, option_t[:, None]).squeeze(1))
            logprobs.append(dist.log_prob(action))
            entropies.append(dist.entropy())
            taken.append(option_t)
            np.add.at(option_counts, options, 1)
            option_lengths += 1

            next_obs, reward, term, trunc, info = envs.step(action.cpu().numpy())
            done = term | trunc
            rewards[step] = reward * args.reward_scale
            dones[step], arrival[step] = done, ~done
            if trunc.any():  # bootstrap a cut episode from U at its last observation
                final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
                with torch.no_grad():
                    fq, _, fbeta = agent(torch.as_tensor(final_obs, device=device))
                    u = value_upon_arrival(fq, fbeta, option_t[torch.as_tensor(trunc)])
                rewards[step, trunc] += args.gamma * u.cpu().numpy()
            global_step += e
            if done.any() and "episode" in info.get("final_info", {}):
                final = info["final_info"]
                for i in np.flatnonzero(final["_episode"]):
                    ret, length = float(final["episode"]["r"][i]), int(final["episode"]["l"][i])
                    recent_returns.append(ret)
                    writer.add_scalar("charts/episodic_return", ret, global_step)
                    writer.add_scalar("charts/episodic_length", length, global_step)
            finished_lengths += option_lengths[done].tolist()
            starts = done.copy()
            q, logits, beta = agent(torch.as_tensor(next_obs, device=device))
        arrival_beta.append(beta.gather(1, taken[-1][:, None]).squeeze(1))
        arrival_q.append(q.detach())

        # Targets: G_t = r_t + γ G_{t+1} from U(s_N, ω_{N−1}); no bootstrap across an episode end.
        with torch.no_grad():
            bootstrap = value_upon_arrival(q, beta, taken[-1]).cpu().numpy()
        returns = torch.as_tensor(option_returns(rewards, dones, bootstrap, args.gamma),
                                  dtype=torch.float32, device=device)
        q_taken_t = torch.stack(q_taken)
        advantages = returns - q_taken_t  # [n, e]
        pg_loss = -(torch.stack(logprobs) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = torch.stack(entropies).mean()
        # Termination: β_ω(s_{t+1}) (Q_Ω(s_{t+1}, ω) − V_Ω(s_{t+1}) + ξ), within an episode only.
        term_adv = torch.stack([
            termination_advantage(arrival_q[t], taken[t], args.deliberation_cost)
            for t in range(n)
        ])
        continues = torch.as_tensor(arrival, dtype=torch.float32, device=device)
        term_loss = (torch.stack(arrival_beta) * term_adv * continues).mean()

        loss = pg_loss - args.ent_coef * entropy_loss + args.vf_coef * v_loss \
            + args.term_coef * term_loss
        optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        check_update(global_step, loss, grad_norm, parts={
            "value loss": v_loss, "policy loss": pg_loss, "termination loss": term_loss,
            "entropy": entropy_loss})  # stop before a non-finite update is applied
        optimizer.step()

        elapsed = max(time.time() - start_time, 1e-9)
        writer.add_scalar("charts/learning_rate", optimizer.param_groups[0]["lr"], global_step)
        writer.add_scalar("losses/value_loss", v_loss.item(), global_step)
        writer.add_scalar("losses/policy_loss", pg_loss.item(), global_step)
        writer.add_scalar("losses/entropy", entropy_loss.item(), global_step)
        writer.add_scalar("losses/termination_loss", term_loss.item(), global_step)
        writer.add_scalar("charts/SPS", int((global_step - start_step) / elapsed), global_step)
        counts.log(global_step, decisions, iteration)
        spent = budget_spent(args.budget_unit, global_step, decisions)
        if logs.due(spent) or spent >= args.total_timesteps:
            usage = option_counts / max(option_counts.sum(), 1)
            for k in range(args.num_options):
                writer.add_scalar(f"options/usage_{k}", usage[k], global_step)
            duration = float(np.mean(finished_lengths)) if finished_lengths else float("nan")
            if finished_lengths:
                writer.add_scalar("options/duration", duration, global_step)
            finished_lengths = []
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            progress = budget_progress(args.budget_unit, global_step, decisions,
                                       args.total_timesteps)
            print(f"{progress}  SPS {int((global_step - start_step) / elapsed):>5d}  "
                  f"return(last 20) {mean_ret:>8s}  episodes {len(recent_returns):>5d}  "
                  f"option duration {duration:5.1f}", flush=True)
        run.checkpoint_if_due(global_step=global_step, iteration=iteration, decisions=decisions)

    envs.close()

    # The evaluated policy carries its running option from step to step and chooses a new one
    # at the start of each episode (the evaluation env counts its episodes).
    eval_rng = np.random.default_rng(args.seed + 10_000)
    state = {"option": 0, "episode": -1}

    def policy(obs: np.ndarray, env: gym.Env) -> int:
        with torch.no_grad():
            q, logits, beta = agent(torch.as_tensor(np.asarray(obs)[None], device=device))
        episode = env.get_wrapper_attr("episode_count")
        start = episode != state["episode"]
        ends = start or eval_rng.random() < float(beta[0, state["option"]])
        state["option"] = int(choose_options(q.cpu().numpy(), np.array([state["option"]]),
                                             np.array([ends]), args.option_epsilon,
                                             eval_rng)[0])
        state["episode"] = episode
        return int(Categorical(logits=logits[0, state["option"]]).sample())

    return run.finish(policy, model=agent, method="option-critic",
                      env_kwargs=eval_env_kwargs(args), global_step=global_step,
                      iteration=iteration, decisions=decisions)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args)
