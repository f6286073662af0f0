"""The CompILE baseline (SPEC §5): options from the one demo, then an A2C controller over them.

    python algos/compile_a2c.py --env-id ALE/Qbert-v5                  # the shipped demo
    python algos/compile_a2c.py --env-id MinAtar/Breakout-v1 --demo demo.npz

Phase 1, CompILE (Kipf et al. 2019; the model, its ELBO and the options are in
`routine_gym/baselines/compile/`). The demo's decisions and the states the agent saw at them
(replayed from its seeds through the agent's observation pipeline) are cut into windows of 32
decisions; a recognition model segments each into M = 10 segments (Gumbel-softmax boundaries, a
Poisson(4) prior on their lengths) with one concrete latent of 8 codes per segment, and a decoder
π(a | s, z) reconstructs the actions. The whole demo is then segmented with hard boundaries, the
decoder and a termination head β(s', z) are trained on those segments, and the K = 3 codes with the
most segments become options: option k runs argmax_a π(a | s, z_k) until β(s', z_k) > 0.5, twice
the longest segment of the K codes, or the end of the episode. The trained model is saved as
`compile_model.pt` in the run folder (state_dict and JSON, read with
`torch.load(weights_only=True)`) and in every checkpoint, so a resumed run keeps its options.

Phase 2, the controller: A2C over `Discrete(|A| + K)` with the MacroAction treatment of options
(`OptionActionWrapper` runs them inside the env, as `RoutineActionWrapper` runs routines):

    R_i = Σ_{τ=t_i}^{t_i+ℓ_i-1} r_τ,   Γ_i = γ                        (summed reward, one γ)
    A(i) = R_i + γ R_{i+1} + … + γ^{N-i} V(s_{t_N}) − V(s_{t_i})
    L = L_policy + λ_entropy L_entropy + λ_value ‖A‖²

with rapl_a2c.py's settings (16 envs × N = 5 decisions, RMSprop 7e-4 with linear decay, γ 0.99,
entropy 0.01, value 0.5, grad-norm clip 0.5). Logged steps (`global_step`, `charts/SPS`) count
primitive agent steps; `options/usage_k` is the share of decisions that chose option k.

CompILE's budget: 1000 Adam steps (lr 1e-3) of 16 windows, then 500 supervised steps of 256
decisions for the decoder and termination head (`--compile-*` flags). Measured on this 2-core
CPU with one torch thread (and other jobs running): about 0.1 s an ELBO step on MiniQbert (2
minutes in all), 0.55 s an ELBO step and 0.5 s an option step on Atari, whose encoder is the
Nature CNN (about 15 minutes in all, against hours for the controller's 10M steps).

Evaluation runs through `routine_gym.plumbing.evaluation.evaluate_policy` (eval.json, alignment
with the demo), which takes a policy of primitive actions and has no place for an env wrapper: the
evaluated policy runs the controller's options itself, one primitive a call, exactly as
`OptionActionWrapper` would (`routine_gym.baselines.compile.option_primitive_policy`).
"""

from __future__ import annotations

from routine_gym.plumbing.openmp import shorten_spin

shorten_spin()  # before torch loads OpenMP: a shorter spin of its idle threads (see there)

import os
import time
import warnings
from dataclasses import asdict, dataclass
from typing import Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

import routine_gym
from routine_gym.baselines.compile import (
    CompILE,
    CompILEConfig,
    CompILEOptions,
    OptionActionWrapper,
    OptionSummary,
    compile_from_state,
    compile_state,
    describe_options,
    fit_options,
    gru_choice,
    most_used_codes,
    option_primitive_policy,
    option_summary,
    save_compile,
    segment,
    train_compile,
)
from routine_gym.envs.factory import make_env
from routine_gym.imitation.agent_view import agent_view_states, decision_steps
from routine_gym.networks import ObservationEncoder, categorical_policy, layer_init
from routine_gym.plumbing.counters import Counters, budget_progress, budget_spent
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.errors import UsageError
from routine_gym.plumbing.loading import load_demo
from routine_gym.plumbing.memory import check_rollout_memory
from routine_gym.plumbing.run import Every, eval_env_kwargs, run_script, start_run, train_env_kwargs
from routine_gym.returns import decision_returns, macro_reward_and_discount
from routine_gym.wrapper import merge_final


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
    capture_video: bool = False
    """whether to film the agent as GIFs: the first 3 evaluation episodes in `{run}/videos/`, each
    frame captioned with the action or routine step it executes, and training env 0's episodes
    0, 1, 8, 27, ... in `videos/{run_name}/`"""

    # Algorithm
    env_id: str = "ALE/Qbert-v5"
    """the env id: `ALE/*-v5`, `*NoFrameskip-v4`, `procgen/CoinRun-v0` or any discrete env"""
    total_timesteps: int = 10_000_000
    """total primitive agent steps of the experiment (decisions with --budget-unit decisions)"""
    budget_unit: Literal["steps", "decisions"] = "steps"
    """what --total-timesteps, the learning-rate schedule and --checkpoint-every count:
    primitive agent steps, or decisions (agent calls that chose an action
    or an option)"""
    learning_rate: float = 7e-4
    """the learning rate of the RMSprop optimizer"""
    anneal_lr: bool = True
    """linear decay of the learning rate to 0"""
    num_envs: int = 16
    """the number of parallel environments"""
    num_steps: int = 5
    """decisions per environment per rollout (N)"""
    gamma: float = 0.99
    """the discount factor γ, once per decision (MacroAction)"""
    reward_scale: float | None = None
    """multiply each reward by this for learning (after Atari's sign clipping); the logged
    returns stay the game's score. Unset: the env profile's scale (MiniQbert 0.01, its 25- and
    100-point rewards swamp the value loss at 1; every other env 1)"""
    ent_coef: float = 0.01
    """coefficient of the entropy bonus (λ_entropy)"""
    vf_coef: float = 0.5
    """coefficient of the value loss (λ_value)"""
    max_grad_norm: float = 0.5
    """the maximum norm for gradient clipping"""
    rmsprop_alpha: float = 0.99
    """RMSprop smoothing constant"""
    rmsprop_eps: float = 1e-5
    """RMSprop epsilon"""
    async_envs: bool = False
    """step the environments in subprocesses (AsyncVectorEnv) instead of in this process"""

    # CompILE
    demo: str | None = None
    """demo to learn the options from (default: the shipped demo of the env in demos/)"""
    num_options: int = 3
    """K, the latent codes that become options (the most used in the demo)"""
    compile_latents: int = 8
    """codes of CompILE's concrete latent"""
    compile_segments: int = 10
    """M, segments per window"""
    compile_window: int = 32
    """decisions per training window"""
    compile_prior_rate: float = 4.0
    """λ of the Poisson prior on segment lengths"""
    compile_hidden: int = 128
    """units of the recognition GRU, the decoder and the termination head"""
    compile_iterations: int = 1000
    """Adam steps on the ELBO"""
    compile_batch_size: int = 16
    """windows per ELBO step"""
    compile_learning_rate: float = 1e-3
    """Adam's learning rate (ELBO and option training)"""
    compile_option_steps: int = 500
    """supervised steps of the decoder and termination head on the hard segments"""

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
    """save the final controller to runs/{run_name}/model.pt (CompILE is always saved)"""
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
    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.actor = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)
        self.critic = layer_init(nn.Linear(self.encoder.num_features, 1), std=1.0)

    def get_value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(self.encoder(obs)).squeeze(-1)

    def get_action_and_value(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        hidden = self.encoder(obs)
        action, logprob, entropy = categorical_policy(self.actor(hidden), action)
        return action, logprob, entropy, self.critic(hidden).squeeze(-1)


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "iteration", "decisions", "rng", "args",
                   "compile")


#: The upper bound of CompILE's size flags (codes, segments, window, hidden units, batch).
COMPILE_MAX_SIZE = 4096


def extra_checks(args: Args) -> list[tuple[str, bool, str]]:
    """The CompILE flags' domains (the shared ones are in `plumbing.arguments.DOMAINS`)."""
    at_least_1 = ("num_options", "compile_latents", "compile_segments", "compile_window",
                  "compile_hidden", "compile_iterations", "compile_batch_size")
    checks = [(name, getattr(args, name) >= 1, "≥ 1") for name in at_least_1]
    # The sizes the model's memory follows from (windows × decisions × hidden units): capped
    # far above the paper's (8 codes, 32 decisions, 128 units, 16 windows).
    checks += [(name, getattr(args, name) <= COMPILE_MAX_SIZE, f"≤ {COMPILE_MAX_SIZE:,}")
               for name in ("compile_latents", "compile_segments", "compile_window",
                            "compile_hidden", "compile_batch_size")]
    checks.append(("compile_option_steps", args.compile_option_steps >= 0, "≥ 0"))
    checks.append(("compile_prior_rate", args.compile_prior_rate > 0, "> 0"))
    checks.append(("compile_learning_rate", args.compile_learning_rate > 0, "> 0"))
    checks.append(("num_options", args.num_options <= args.compile_latents,
                   "at most --compile-latents"))
    return checks


def learn_options(args: Args, demo, obs_space: gym.spaces.Box, num_actions: int,
                  meanings: list[str] | None, device: torch.device,
                  writer) -> tuple[CompILE, dict]:
    """Phase 1: CompILE on the demo, the hard segmentation, the decoder and termination head on
    it, and the K most used codes; returns the model and the options' description."""
    states = agent_view_states(demo, args.env_id)
    steps = decision_steps(demo)
    if states.shape[1:] != obs_space.shape:
        raise UsageError(f"--demo {args.demo}: its states in the agent's view are "
                         f"{states.shape[1:]}, the env's observations {obs_space.shape}")
    config = CompILEConfig(
        env_id=args.env_id, obs_shape=obs_space.shape, obs_dtype=str(obs_space.dtype),
        num_actions=num_actions, num_latents=args.compile_latents,
        num_segments=args.compile_segments, window=args.compile_window,
        prior_rate=args.compile_prior_rate, hidden_dim=args.compile_hidden)
    print(f"CompILE on {len(steps.actions)} decisions of {demo.num_episodes} episode(s): "
          f"{args.compile_iterations} steps of {args.compile_batch_size} windows", flush=True)

    def progress(entry: dict[str, float]) -> None:
        for key in ("loss", "nll", "kl_z", "kl_b"):
            writer.add_scalar(f"compile/{key}", entry[key], entry["iteration"])
        print(f"  CompILE step {entry['iteration']:>6d}  -ELBO {entry['loss']:8.3f}  "
              f"nll {entry['nll']:8.3f}  kl_z {entry['kl_z']:6.3f}  kl_b {entry['kl_b']:6.3f}",
              flush=True)

    model, log = train_compile(
        states, steps.actions, steps.lengths, config, iterations=args.compile_iterations,
        batch_size=args.compile_batch_size, learning_rate=args.compile_learning_rate,
        seed=args.seed, device=device, log_every=max(args.compile_iterations // 10, 1),
        progress=progress)
    segmentation = segment(model, states, steps.actions, steps.lengths)
    option_log = fit_options(model, states, steps.actions, steps.lengths, segmentation,
                             steps=args.compile_option_steps,
                             learning_rate=args.compile_learning_rate, seed=args.seed)
    codes = most_used_codes(segmentation, args.num_options)
    if len(codes) < args.num_options:
        warnings.warn(f"the demo's segmentation uses {len(codes)} code(s), fewer than "
                      f"--num-options {args.num_options}; using {len(codes)}", stacklevel=2)
    chosen = np.isin(segmentation.codes, codes)
    max_length = 2 * int(segmentation.lengths[chosen].max())
    summaries = option_summary(model, states, steps.actions, segmentation, steps.lengths, codes,
                               meanings)
    meta = {
        "codes": codes, "max_length": max_length, "demo": args.demo,
        "options": [asdict(s) for s in summaries], "elbo_log": log, "option_log": option_log,
        "segmentation": {k: getattr(segmentation, k).tolist()
                         for k in ("episodes", "starts", "lengths", "codes")},
    }
    return model.cpu(), meta


def main(args: Args) -> dict | None:
    gru_choice()  # ROUTINE_GYM_COMPILE_GRU checked before a run folder is made
    run = start_run(args, "compile_a2c.py", CHECKPOINT_KEYS, lower_budget=True,
                    extra_checks=extra_checks)
    args, device, writer = run.args, run.device, run.writer

    def thunk(i: int):
        return make_env(args.env_id, args.seed, i, training=True,
                        env_kwargs=train_env_kwargs(args), capture_video=args.capture_video,
                        run_name=run.name, first_video_episode=run.first_video_episode)

    probe = make_env(args.env_id, args.seed, 0, training=True, env_kwargs=train_env_kwargs(args))()
    obs_space, num_primitives = probe.observation_space, int(probe.action_space.n)
    meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
    probe.close()

    # Phase 1: the options, learnt from the demo (or the resumed run's own).
    demo, args.demo = load_demo(args.env_id, args.demo, purpose="compile_a2c.py")
    if run.checkpoint is not None:
        compile_model, meta = compile_from_state(run.checkpoint["compile"])
    else:
        compile_model, meta = learn_options(args, demo, obs_space, num_primitives, meanings,
                                            device, writer)
        save_compile(os.path.join(run.path, "compile_model.pt"), compile_model, meta)
    codes, max_len = meta["codes"], meta["max_length"]
    print(describe_options([OptionSummary(**s) for s in meta["options"]], max_len))
    options = CompILEOptions(compile_model, codes)

    # Env setup: same-step autoreset, so the step that ends an episode returns the reset obs.
    def option_env(i: int):
        inner = thunk(i)

        def make() -> gym.Env:
            env = OptionActionWrapper(inner(), options, max_len)
            env.action_space.seed(args.seed + i)
            return env

        return make

    vector_cls = gym.vector.AsyncVectorEnv if args.async_envs else gym.vector.SyncVectorEnv
    envs = vector_cls([option_env(i) for i in range(args.num_envs)],
                      autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    num_options = len(codes)
    num_actions = num_primitives + num_options

    agent = Agent(args.env_id, envs.single_observation_space, num_actions).to(device)
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=args.learning_rate,
                                    alpha=args.rmsprop_alpha, eps=args.rmsprop_eps)

    # Rollout storage, time-major: [decision, env] and [decision, step in option, env].
    n, e = args.num_steps, args.num_envs
    check_rollout_memory(envs.single_observation_space, n, e, observations=0,
                         numbers=4 + max_len)  # the observations are the acting graph's
    step_rewards = np.zeros((n, max_len, e), dtype=np.float64)
    lengths = np.ones((n, e), dtype=np.int64)
    terminated = np.zeros((n, e), dtype=bool)
    truncated = np.zeros((n, e), dtype=bool)
    final_values = np.zeros((n, e), dtype=np.float64)

    # What a checkpoint holds (the options' model with it); a resumed run starts where its
    # checkpoint left off.
    global_step, iteration, decisions = run.resume(
        {"model": agent, "optimizer": optimizer}, global_step=0, iteration=0, decisions=0,
        count="decisions" if args.budget_unit == "decisions" else "global_step", filmed=envs,
        extra={"compile": compile_state(compile_model, meta)})

    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw.
    next_obs, _ = envs.reset(seed=args.seed + global_step)
    start_time, start_step, start_decisions = time.time(), global_step, decisions
    logs = Every(args.log_every, start=budget_spent(args.budget_unit, global_step, decisions))
    counts = Counters(writer, num_primitives, num_options)
    action_counts = np.zeros(num_actions, dtype=np.int64)
    option_steps = np.zeros(num_options, dtype=np.int64)
    recent_returns: list[float] = []

    while (spent := budget_spent(args.budget_unit, global_step, decisions)) \
            < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - spent / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        # The policy does not change during a rollout, so the acting forward pass keeps its
        # graph and the update reuses it.
        logprobs, entropies, values = [], [], []
        for step in range(n):
            action_t, logprob_t, entropy_t, value_t = agent.get_action_and_value(
                torch.as_tensor(next_obs, device=device))
            logprobs.append(logprob_t)
            entropies.append(entropy_t)
            values.append(value_t)
            action = action_t.cpu().numpy()
            next_obs, reward, term, trunc, info = envs.step(action)
            done = term | trunc
            terminated[step], truncated[step] = term, trunc
            # An option's primitive rewards, whichever step of it ended an episode.
            lengths[step] = merge_final(info, "routine_length", done)
            step_rewards[step] = merge_final(info, "routine_rewards", done).T
            if args.reward_scale != 1.0:
                step_rewards[step] *= args.reward_scale
            if trunc.any():  # bootstrap a cut episode from the value of its last observation
                final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
                with torch.no_grad():
                    v = agent.get_value(torch.as_tensor(final_obs, device=device))
                final_values[step, trunc] = v.cpu().numpy()

            global_step += int(lengths[step].sum())
            decisions += e
            counts.add(action, lengths[step].sum())
            np.add.at(action_counts, action, 1)
            chose = action >= num_primitives
            np.add.at(option_steps, action[chose] - num_primitives, lengths[step][chose])
            if done.any() and "episode" in info.get("final_info", {}):
                final = info["final_info"]
                for i in np.flatnonzero(final["_episode"]):
                    ret, length = float(final["episode"]["r"][i]), int(final["episode"]["l"][i])
                    recent_returns.append(ret)
                    writer.add_scalar("charts/episodic_return", ret, global_step)
                    writer.add_scalar("charts/episodic_length", length, global_step)

        # Returns: the MacroAction treatment, summed reward and one γ per decision.
        rewards, discounts = macro_reward_and_discount(step_rewards, lengths, args.gamma)
        with torch.no_grad():
            bootstrap = agent.get_value(torch.as_tensor(next_obs, device=device)).cpu().numpy()
        returns = decision_returns(rewards, discounts, terminated, truncated, final_values,
                                   bootstrap)

        advantages = torch.as_tensor(returns, dtype=torch.float32, device=device) \
            - torch.stack(values)
        pg_loss = -(torch.stack(logprobs) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = torch.stack(entropies).mean()
        loss = pg_loss - args.ent_coef * entropy_loss + args.vf_coef * v_loss
        optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        check_update(global_step, loss, grad_norm, parts={
            "value loss": v_loss, "policy loss": pg_loss, "entropy": entropy_loss})
        optimizer.step()

        elapsed = max(time.time() - start_time, 1e-9)
        sps = int((global_step - start_step) / elapsed)
        writer.add_scalar("charts/learning_rate", optimizer.param_groups[0]["lr"], global_step)
        writer.add_scalar("losses/value_loss", v_loss.item(), global_step)
        writer.add_scalar("losses/policy_loss", pg_loss.item(), global_step)
        writer.add_scalar("losses/entropy", entropy_loss.item(), global_step)
        writer.add_scalar("charts/SPS", sps, global_step)
        writer.add_scalar("charts/decisions_per_second",
                          int((decisions - start_decisions) / elapsed), global_step)
        counts.log(global_step, decisions, iteration)
        usage = action_counts / max(action_counts.sum(), 1)
        writer.add_scalar("options/primitive_usage", usage[:num_primitives].sum(), global_step)
        for k in range(num_options):
            writer.add_scalar(f"options/usage_{k}", usage[num_primitives + k], global_step)
            chosen = action_counts[num_primitives + k]
            if chosen:
                writer.add_scalar(f"options/length_{k}", option_steps[k] / chosen, global_step)

        spent = budget_spent(args.budget_unit, global_step, decisions)
        if logs.due(spent) or spent >= args.total_timesteps:
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            progress = budget_progress(args.budget_unit, global_step, decisions,
                                       args.total_timesteps)
            print(f"{progress}  SPS {sps:>5d}  "
                  f"return(last 20) {mean_ret:>8s}  episodes {len(recent_returns):>5d}  "
                  f"option use {usage[num_primitives:].sum():5.1%}", flush=True)
        run.checkpoint_if_due(global_step=global_step, iteration=iteration, decisions=decisions)

    envs.close()

    def controller(obs: np.ndarray) -> int:
        with torch.no_grad():
            action, _, _, _ = agent.get_action_and_value(
                torch.as_tensor(np.asarray(obs)[None], device=device))
        return int(action[0])

    # Full games on the evaluation view (Procgen: unseen levels), aligned with the demo.
    # evaluate_policy takes primitive actions, so the policy runs the options itself.
    policy = option_primitive_policy(controller, options, max_len, num_primitives)
    return run.finish(policy, model=agent, method="compile",
                      summary={"option_codes": codes, "option_max_length": max_len}, demo=demo,
                      env_kwargs=eval_env_kwargs(args), global_step=global_step,
                      iteration=iteration, decisions=decisions)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args)
