"""RAPL-A2C, plain A2C and the MacroAction baseline in one CleanRL-style file (SPEC §5).

    python algos/rapl_a2c.py --env-id ALE/Qbert-v5                  # RAPL-A2C, shipped demo
    python algos/rapl_a2c.py --env-id ALE/Qbert-v5 --mode a2c       # plain A2C
    python algos/rapl_a2c.py --env-id ALE/Qbert-v5 --mode macro     # routines as black boxes

The agent acts in `Discrete(|A| + K)`: the primitive actions plus K routines mined from one
demonstration. A decision at primitive time t_i runs a routine of executed length ℓ_i; the
vector env returns the primitive rewards (and, for RAPL, observations) of every inner step in
`info`. RAPL-A2C then uses

    R_i = Σ_{τ=t_i}^{t_i+ℓ_i-1} γ^{τ-t_i} r_τ,   Γ_i = γ^{ℓ_i}                  (routine reward)
    A_routine(i) = R_i + Γ_i R_{i+1} + … + γ^{t_N - t_i} V(s_{t_N}) − V(s_{t_i})  (actor, critic)
    A_prim(τ)    = Σ_{τ'≥τ} γ^{τ'-τ} r_τ' + γ^{t_N-τ} V(s_{t_N}) − V(s_τ)         (critic only)
    L = L_policy + λ_entropy L_entropy + λ_value (‖A_routine‖² + λ_prim ‖A_prim‖²)

where A_prim is taken at every primitive state visited *inside* a routine (the states where a
routine starts already carry A_routine, whose target is the same return). `--mode macro`
treats routines as black boxes (summed reward, one γ per decision, no A_prim); `--mode a2c`
has no routines. Logged steps (`global_step`, `charts/SPS`) count primitive agent steps.
"""

from __future__ import annotations

import json
import os
import random
import sys
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import tyro
from torch.distributions.categorical import Categorical
from torch.utils.tensorboard import SummaryWriter

import routine_gym
from routine_gym.atomic import atomic_write_text
from routine_gym.checkpoint import resume_settings, write_checkpoint
from routine_gym.demo import Demo, record_agent_demo, shipped_demo_path
from routine_gym.envs import profile_for, same_env
from routine_gym.envs.factory import (
    default_env_kwargs,
    make_env,
    make_primitive_env,
    preprocess,
)
from routine_gym.library import RoutineLibrary
from routine_gym.metrics import human_normalized_score
from routine_gym.mining import make_proposer
from routine_gym.networks import ObservationEncoder, layer_init
from routine_gym.returns import (
    decision_returns,
    inner_states_and_targets,
    macro_reward_and_discount,
    primitive_returns,
    routine_reward_and_discount,
)
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
    capture_video: bool = False
    """whether to capture videos of the agent (in `videos/`)"""

    # Algorithm
    env_id: str = "ALE/Qbert-v5"
    """the env id: `ALE/*-v5`, `*NoFrameskip-v4`, `procgen/CoinRun-v0` or any discrete env"""
    mode: Literal["rapl", "a2c", "macro"] = "rapl"
    """rapl: RAPL-A2C; a2c: plain A2C on primitives; macro: the MacroAction baseline"""
    total_timesteps: int = 10_000_000
    """total primitive agent steps of the experiment"""
    learning_rate: float = 7e-4
    """the learning rate of the RMSprop optimizer"""
    anneal_lr: bool = True
    """linear decay of the learning rate to 0"""
    num_envs: int = 16
    """the number of parallel environments"""
    num_steps: int = 5
    """decisions per environment per rollout (N)"""
    gamma: float = 0.99
    """the discount factor γ per primitive step"""
    reward_scale: float = 1.0
    """multiply each primitive reward by this for learning (after Atari's sign clipping); the
    logged returns stay the game's score. Large rewards (MiniQbert's 25 and 100) train better
    at 0.01"""
    ent_coef: float = 0.01
    """coefficient of the entropy bonus (λ_entropy)"""
    vf_coef: float = 0.5
    """coefficient of the value loss (λ_value)"""
    prim_coef: float = 1.0
    """coefficient of the primitive-level value loss (λ_prim), RAPL only"""
    max_grad_norm: float = 0.5
    """the maximum norm for gradient clipping"""
    rmsprop_alpha: float = 0.99
    """RMSprop smoothing constant"""
    rmsprop_eps: float = 1e-5
    """RMSprop epsilon"""
    async_envs: bool = False
    """step the environments in subprocesses (AsyncVectorEnv) instead of in this process"""

    # Routines
    demo: str | None = None
    """demo to mine routines from (default: the shipped demo of the env in demos/)"""
    routines: str | None = None
    """a routine library JSON to use instead of mining a demo"""
    num_routines: int = 3
    """K, the number of routines to mine"""
    length_weight: float = 0.1
    """λ_length in the routine score f + λ·len"""
    alpha: int = 2
    """Levenshtein distance under which similar routines are pruned"""
    proposer: Literal["full", "random", "enumerate", "random-fetch", "repeat"] = "full"
    """full: Sequitur (the paper's model); the others are the discovery ablations"""

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
    """save a resumable checkpoint every this many primitive steps (0: never)"""
    resume: str | None = None
    """checkpoint file (or run folder) to resume a killed run from, with its saved settings
    (a --total-timesteps other than the default sets a new budget)"""
    eval_episodes: int = 10
    """episodes to evaluate the final policy on (0 disables); results in eval.json"""
    record_demo: str | None = None
    """record the best of --demo-episodes episodes of the trained agent to this demo file"""
    demo_episodes: int = 10
    """episodes to pick the best demo from"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 0
    """torch CPU threads (0: torch's default, fastest on an idle machine); 1 is faster when
    other jobs share the CPU"""


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


# ---------------------------------------------------------------------------------------------
# Routines, checkpoints, evaluation
# ---------------------------------------------------------------------------------------------


def load_routines(args: Args) -> RoutineLibrary | None:
    """The routine library of this run: from --routines, --demo, or the shipped demo."""
    if args.mode == "a2c":
        return None
    if args.routines:
        library = RoutineLibrary.load(args.routines)
        if not same_env(library.source.get("env_id"), args.env_id):
            raise ValueError(
                f"{args.routines} was mined from a demo of {library.source['env_id']}, "
                f"not {args.env_id}"
            )
        return _nonempty(library, args.routines, args)
    demo_path = args.demo or shipped_demo_path(args.env_id)
    if demo_path is None:
        raise SystemExit(
            f"--mode {args.mode} needs routines, and no demo of {args.env_id} ships in demos/.\n"
            f"Record one, then pass it with --demo:\n"
            f"  routine-gym record {args.env_id} --policy random --episodes 10 --out demo.npz\n"
            f"  python algos/rapl_a2c.py --env-id {args.env_id} --mode a2c "
            f"--record-demo demo.npz   # a trained A2C expert's demo, as in the paper\n"
            f"or give a mined library with --routines LIB.json (routine-gym mine DEMO --out ...)"
        )
    demo = Demo.load(demo_path, env_id=args.env_id)
    proposer = make_proposer(
        args.proposer, args.num_routines, args.length_weight, args.alpha, seed=args.seed
    )
    return _nonempty(proposer.mine(demo, source={"path": demo_path}), demo_path, args)


def _nonempty(library: RoutineLibrary, where: str, args: Args) -> RoutineLibrary:
    # Without routines the action space has nothing to add and no routine info to learn from.
    if len(library) == 0:
        raise SystemExit(
            f"--mode {args.mode} found no routine in {where} (the demo may be too short or "
            f"too varied); use --mode a2c, a longer demo, or a smaller --alpha"
        )
    return library


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "iteration", "rng", "args", "library")


def save_checkpoint(path: str, agent, optimizer, global_step: int, iteration: int,
                    args: Args, library: RoutineLibrary | None) -> None:
    """Write a resumable checkpoint atomically (a kill mid-write keeps the previous one)."""
    write_checkpoint(
        {
            "model": agent.state_dict(),
            "optimizer": optimizer.state_dict(),
            "global_step": global_step,
            "iteration": iteration,
            "rng": rng_state(),
            "args": json.dumps(asdict(args)),
            "library": json.dumps(library.to_dict()) if library is not None else "",
        },
        path,
    )


def evaluate(agent: Agent, args: Args, library, device, episodes: int) -> dict:
    """Run the trained policy for `episodes` full games (no training wrappers)."""
    env_kwargs = eval_env_kwargs(args)
    env = make_env(args.env_id, args.seed + 10_000, routines=library, training=False,
                   env_kwargs=env_kwargs)()
    returns, lengths = [], []
    obs, _ = env.reset(seed=args.seed + 10_000)
    while len(returns) < episodes:
        with torch.no_grad():
            action, _, _, _ = agent.get_action_and_value(torch.as_tensor(obs[None], device=device))
        obs, _, terminated, truncated, info = env.step(int(action[0]))
        if terminated or truncated:
            returns.append(float(info["episode"]["r"]))
            lengths.append(int(info["episode"]["l"]))
            obs, _ = env.reset()
    env.close()
    summary = {
        "env_id": args.env_id, "mode": args.mode, "episodes": episodes,
        "returns": returns, "lengths": lengths,
        "mean_return": float(np.mean(returns)), "std_return": float(np.std(returns)),
        "env_kwargs": env_kwargs,
    }
    score_key = profile_for(args.env_id).score_key(args.env_id)
    if score_key is not None:
        try:
            summary["human_normalized_score"] = human_normalized_score(
                summary["mean_return"], score_key
            )
        except (KeyError, ValueError):
            pass
    return summary


def train_env_kwargs(args: Args) -> dict:
    """The training levels (Procgen); other envs have none."""
    return profile_for(args.env_id).level_kwargs(
        args.num_levels, args.start_level, args.distribution_mode, args.eval_distribution_mode,
        training=True)


def eval_env_kwargs(args: Args) -> dict:
    """Procgen is evaluated on levels never trained on; other envs as in training."""
    return profile_for(args.env_id).level_kwargs(
        args.num_levels, args.start_level, args.distribution_mode, args.eval_distribution_mode,
        training=False)


def merge_final(info: dict, key: str, done: np.ndarray) -> np.ndarray:
    """`info[key]` per env, taken from `final_info` for envs whose episode just ended.

    With same-step autoreset, the step that ends an episode returns the reset's info, and the
    ended step's info moves to `info["final_info"]`.
    """
    value = info[key].copy() if key in info else None
    if done.any():
        final = info["final_info"]
        mask = final[f"_{key}"]
        if value is None:
            value = np.zeros_like(final[key])
        value[mask] = final[key][mask]
    return value


def main(args: Args) -> None:
    if not args.reward_scale > 0:
        raise ValueError(f"--reward-scale needs to be > 0, actual value: {args.reward_scale}")
    if args.resume:
        # The saved settings. An explicit --total-timesteps sets a new budget: higher to train
        # on, or at most the steps done to go straight to evaluation and demo recording.
        args, checkpoint, run_path = resume_settings(args, CHECKPOINT_KEYS, "rapl_a2c.py",
                                                     lower_budget=True)
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
    torch.backends.cudnn.deterministic = args.torch_deterministic
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")

    # Routines: mined from the demo (or loaded), printed with action names, saved with the run.
    if checkpoint is not None and checkpoint["library"]:
        library = RoutineLibrary.from_dict(json.loads(checkpoint["library"]))
    else:
        library = load_routines(args)
    if library is not None:
        probe = make_primitive_env(args.env_id, **train_env_kwargs(args))
        meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
        probe.close()
        print(library.describe(meanings))
        library.save(os.path.join(run_path, "routines.json"))

    # Env setup: same-step autoreset, so the step that ends an episode returns the reset obs.
    thunks = [
        make_env(args.env_id, args.seed, i, routines=library, training=True,
                 record_observations=args.mode == "rapl", env_kwargs=train_env_kwargs(args),
                 capture_video=args.capture_video, run_name=run_name)
        for i in range(args.num_envs)
    ]
    vector_cls = gym.vector.AsyncVectorEnv if args.async_envs else gym.vector.SyncVectorEnv
    envs = vector_cls(thunks, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    assert isinstance(envs.single_action_space, gym.spaces.Discrete), "only discrete actions"
    num_actions = int(envs.single_action_space.n)
    num_routines = len(library) if library is not None else 0
    num_primitives = num_actions - num_routines
    max_len = max(library.lengths) if library is not None else 1

    agent = Agent(args.env_id, envs.single_observation_space, num_actions).to(device)
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=args.learning_rate,
                                    alpha=args.rmsprop_alpha, eps=args.rmsprop_eps)

    # Rollout storage, time-major: [decision, env] and [decision, step in routine, env].
    n, e = args.num_steps, args.num_envs
    obs_shape = envs.single_observation_space.shape
    obs_dtype = envs.single_observation_space.dtype
    actions = np.zeros((n, e), dtype=np.int64)
    step_rewards = np.zeros((n, max_len, e), dtype=np.float64)
    lengths = np.ones((n, e), dtype=np.int64)
    terminated = np.zeros((n, e), dtype=bool)
    truncated = np.zeros((n, e), dtype=bool)
    final_values = np.zeros((n, e), dtype=np.float64)
    inner_obs = np.zeros((n, max(max_len - 1, 1), e, *obs_shape), dtype=obs_dtype)

    global_step, start_iteration = 0, 1
    if checkpoint is not None:
        agent.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        global_step, start_iteration = checkpoint["global_step"], checkpoint["iteration"] + 1
        set_rng_state(checkpoint["rng"])
        print(f"resumed {run_name} at step {global_step}")
    checkpoint_path = os.path.join(run_path, "checkpoint.pt")
    next_checkpoint = (global_step // args.checkpoint_every + 1) * args.checkpoint_every \
        if args.checkpoint_every > 0 else None

    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw.
    next_obs, _ = envs.reset(seed=args.seed + global_step)
    start_time, start_step = time.time(), global_step
    decisions, next_log = 0, (global_step // args.log_every + 1) * args.log_every
    routine_counts = np.zeros(num_actions, dtype=np.int64)
    recent_returns: list[float] = []
    iteration = start_iteration - 1

    while global_step < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - global_step / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        # The policy does not change during a rollout, so the acting forward pass keeps its
        # graph and the update reuses it instead of running the network over the rollout again.
        logprobs, entropies, values = [], [], []
        for step in range(n):
            action_t, logprob_t, entropy_t, value_t = agent.get_action_and_value(
                torch.as_tensor(next_obs, device=device)
            )
            logprobs.append(logprob_t)
            entropies.append(entropy_t)
            values.append(value_t)
            action = action_t.cpu().numpy()
            actions[step] = action
            next_obs, reward, term, trunc, info = envs.step(action)
            done = term | trunc
            terminated[step], truncated[step] = term, trunc

            if args.mode == "a2c":
                lengths[step] = 1
                step_rewards[step, 0] = reward
            else:
                lengths[step] = merge_final(info, "routine_length", done)
                step_rewards[step] = merge_final(info, "routine_rewards", done).T
                if args.mode == "rapl" and max_len > 1:
                    inner = merge_final(info, "routine_observations", done)
                    inner_obs[step] = np.swapaxes(inner[:, : max_len - 1], 0, 1)
            if args.reward_scale != 1.0:
                step_rewards[step] *= args.reward_scale
            if trunc.any():  # bootstrap a cut episode from the value of its last observation
                final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
                with torch.no_grad():
                    v = agent.get_value(torch.as_tensor(final_obs, device=device))
                final_values[step, trunc] = v.cpu().numpy()

            global_step += int(lengths[step].sum())
            decisions += e
            np.add.at(routine_counts, action, 1)
            if done.any() and "episode" in info.get("final_info", {}):
                final = info["final_info"]
                for i in np.flatnonzero(final["_episode"]):
                    ret, length = float(final["episode"]["r"][i]), int(final["episode"]["l"][i])
                    recent_returns.append(ret)
                    writer.add_scalar("charts/episodic_return", ret, global_step)
                    writer.add_scalar("charts/episodic_length", length, global_step)

        # Returns. RAPL: discounted routine reward and γ^ℓ; MacroAction and A2C: summed reward
        # and one γ per decision (identical for A2C, whose routines all have length 1).
        if args.mode == "rapl":
            rewards, discounts = routine_reward_and_discount(step_rewards, lengths, args.gamma)
        else:
            rewards, discounts = macro_reward_and_discount(step_rewards, lengths, args.gamma)
        with torch.no_grad():
            bootstrap = agent.get_value(torch.as_tensor(next_obs, device=device)).cpu().numpy()
        returns = decision_returns(rewards, discounts, terminated, truncated, final_values,
                                   bootstrap)

        b_returns = torch.as_tensor(returns, dtype=torch.float32, device=device)
        advantages = b_returns - torch.stack(values)  # A_routine, [n, e]
        pg_loss = -(torch.stack(logprobs) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = torch.stack(entropies).mean()

        prim_loss = torch.zeros((), device=device)
        if args.mode == "rapl" and max_len > 1:
            # A_prim at the primitive states inside routines (step j ≥ 1 of a decision).
            prim = primitive_returns(step_rewards, lengths, terminated, truncated, final_values,
                                     bootstrap, args.gamma)
            inner_states, prim_targets = inner_states_and_targets(inner_obs, prim, lengths)
            if len(prim_targets):
                states = torch.as_tensor(inner_states, device=device)
                targets = torch.as_tensor(prim_targets, dtype=torch.float32, device=device)
                prim_loss = (targets - agent.get_value(states)).pow(2).mean()

        loss = pg_loss - args.ent_coef * entropy_loss \
            + args.vf_coef * (v_loss + args.prim_coef * prim_loss)
        optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        optimizer.step()

        elapsed = max(time.time() - start_time, 1e-9)
        writer.add_scalar("charts/learning_rate", optimizer.param_groups[0]["lr"], global_step)
        writer.add_scalar("losses/value_loss", v_loss.item(), global_step)
        writer.add_scalar("losses/prim_value_loss", prim_loss.item(), global_step)
        writer.add_scalar("losses/policy_loss", pg_loss.item(), global_step)
        writer.add_scalar("losses/entropy", entropy_loss.item(), global_step)
        writer.add_scalar("charts/SPS", int((global_step - start_step) / elapsed), global_step)
        writer.add_scalar("charts/decisions_per_second", int(decisions / elapsed), global_step)
        if num_routines:
            usage = routine_counts / max(routine_counts.sum(), 1)
            writer.add_scalar("routines/primitive_usage", usage[:num_primitives].sum(),
                              global_step)
            for k in range(num_routines):
                writer.add_scalar(f"routines/usage_{k}", usage[num_primitives + k], global_step)

        if global_step >= next_log or global_step >= args.total_timesteps:
            next_log = (global_step // args.log_every + 1) * args.log_every
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            usage = routine_counts[num_primitives:].sum() / max(routine_counts.sum(), 1)
            print(f"step {global_step:>10,d}/{args.total_timesteps:,d}  "
                  f"SPS {int((global_step - start_step) / elapsed):>5d}  "
                  f"return(last 20) {mean_ret:>8s}  episodes {len(recent_returns):>5d}  "
                  f"routine use {usage:5.1%}", flush=True)
        if next_checkpoint is not None and global_step >= next_checkpoint:
            save_checkpoint(checkpoint_path, agent, optimizer, global_step, iteration, args,
                            library)
            next_checkpoint = (global_step // args.checkpoint_every + 1) * args.checkpoint_every

    envs.close()
    if args.checkpoint_every > 0:
        save_checkpoint(checkpoint_path, agent, optimizer, global_step, iteration, args, library)
    if args.save_model:
        model_path = os.path.join(run_path, "model.pt")
        torch.save(agent.state_dict(), model_path + ".tmp")
        os.replace(model_path + ".tmp", model_path)
        print(f"model saved to {model_path}")

    if args.eval_episodes > 0:
        summary = evaluate(agent, args, library, device, args.eval_episodes)
        summary["global_step"] = global_step
        atomic_write_text(os.path.join(run_path, "eval.json"), json.dumps(summary, indent=2))
        writer.add_scalar("eval/mean_return", summary["mean_return"], global_step)
        print(f"eval over {args.eval_episodes} episodes: mean return "
              f"{summary['mean_return']:.1f} ± {summary['std_return']:.1f}")

    if args.record_demo:
        def policy(obs):
            with torch.no_grad():
                action, _, _, _ = agent.get_action_and_value(
                    torch.as_tensor(np.asarray(obs)[None], device=device))
            return int(action[0])

        def wrap(env):
            return preprocess(gym.wrappers.RecordEpisodeStatistics(env), args.env_id,
                              training=False)

        # The demo marks the agent's decisions (each step of a chosen routine included) apart
        # from the steps the preprocessing injects (no-op start, FIRE, served lives).
        demo = record_agent_demo(
            args.env_id, policy, num_episodes=args.demo_episodes, seed=args.seed + 20_000,
            env_kwargs={**default_env_kwargs(args.env_id), **train_env_kwargs(args)},
            wrap_env=wrap, routines=library,
            meta={"trained_steps": global_step, "command": " ".join(sys.argv),
                  "mode": args.mode, "run": run_name},
        )
        demo.save(args.record_demo, include_observations=False)
        print(f"demo saved to {args.record_demo}: score {demo.score:g}, {len(demo)} steps")
    writer.close()


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    main(tyro.cli(Args))
