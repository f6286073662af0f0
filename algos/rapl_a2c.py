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
has no routines. Logged steps (`global_step`, `charts/SPS`) count primitive agent steps; the
run's decisions, updates, steps per decision and routine shares are logged under `counters/`
(`routine_gym.plumbing.counters`), and `--budget-unit decisions` counts the budget in decisions.

The authors' released code differs from the paper in ways SPEC §5b lists; each is a flag here
(`--routine-discount`, `--critic-loss`, `--prim-states`, `--anneal-lr`, `--selection`) and
`--authors` sets them all. The defaults follow the paper.
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

import routine_gym
from routine_gym.envs import profile_for
from routine_gym.envs.factory import make_primitive_env, make_vector_env
from routine_gym.errors import UsageError
from routine_gym.networks import (
    ObservationEncoder,
    categorical_policy,
    layer_init,
    sample_categorical,
)
from routine_gym.plumbing.arguments import given_flags
from routine_gym.plumbing.counters import Counters, budget_progress, budget_spent, scalars_due
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.loading import unused_routine_flags
from routine_gym.plumbing.memory import check_rollout_memory
from routine_gym.plumbing.run import (
    Every,
    eval_env_kwargs,
    level_env_kwargs,
    run_script,
    start_run,
    train_env_kwargs,
)
from routine_gym.plumbing.seeds import train_seed
from routine_gym.returns import (
    critic_loss,
    decision_returns,
    first_steps,
    inner_states_and_targets,
    macro_reward_and_discount,
    primitive_returns,
    routine_discount_minus_one,
    routine_reward_and_discount,
    window_returns,
)
from routine_gym.wrapper import merge_final


@dataclass
class Args:
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment"""
    seed: int = 1
    """seed of the experiment"""
    seed_stride: int = 1
    """env seeds: 1 resets training env i with seed + i (experiment seeds then share env seeds);
    S ≥ 4 gives each seed its own block [seed·S, (seed+1)·S) of env seeds
    (`routine_gym.plumbing.seeds`)"""
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
    mode: Literal["rapl", "a2c", "macro"] = "rapl"
    """rapl: RAPL-A2C; a2c: plain A2C on primitives; macro: the MacroAction baseline"""
    total_timesteps: int = 10_000_000
    """total primitive agent steps of the experiment (decisions with --budget-unit decisions)"""
    budget_unit: Literal["steps", "decisions"] = "steps"
    """what --total-timesteps, the learning-rate schedule and --checkpoint-every count:
    primitive agent steps, or decisions (agent calls; then a RAPL run makes as many updates
    as A2C with the same number)"""
    learning_rate: float = 7e-4
    """the learning rate of the RMSprop optimizer"""
    anneal_lr: bool = True
    """linear decay of the learning rate to 0"""
    num_envs: int = 16
    """the number of parallel environments"""
    num_steps: int = 5
    """decisions per environment per rollout (N); with --rollout-unit steps, primitive steps"""
    rollout_unit: Literal["decisions", "steps"] = "decisions"
    """what --num-steps counts: decisions (the paper: a rollout holds N decisions per env, each
    running 1 to ℓ primitive steps), or primitive steps (a rollout ends as soon as its decisions
    ran N·num_envs primitive steps in all (to the nearest vector step, counted over the whole
    run), so RAPL and MacroAction make as many updates as A2C on as many frames)"""
    gamma: float = 0.99
    """the discount factor γ per primitive step"""
    reward_scale: float | None = None
    """multiply each reward by this for learning (after Atari's sign clipping); the logged
    returns stay the game's score. Unset: the env profile's scale (MiniQbert 0.01, its 25- and
    100-point rewards swamp the value loss at 1; every other env 1)"""
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
    update_forward: Literal["auto", "acting", "rollout"] = "auto"
    """where the update's forward pass comes from: `acting` keeps each acting pass's graph
    (no second pass: fastest for the large Atari and Procgen CNNs), `rollout` runs the network
    once more over the whole rollout in one batch (fewer, larger calls: fastest for MinAtar's
    and the MLP's small networks); auto picks by the env's network. The same numbers up to
    float rounding"""

    # Routines
    demo: str | None = None
    """demo to mine routines from (default: the shipped demo of the env in demos/)"""
    routine_library: str | None = None
    """a routine library JSON to use (its best K) instead of mining a demo"""
    num_routines: int = 3
    """K, the number of routines to mine"""
    length_weight: float = 0.1
    """λ_length in the routine score f + λ·len"""
    alpha: int = 2
    """Levenshtein distance under which similar routines are pruned"""
    proposer: Literal["full", "random", "enumerate", "random-fetch", "repeat", "bpe"] = "full"
    """full: Sequitur (the paper's model); bpe: byte-pair encoding; the others are the discovery
    ablations"""
    min_routine_length: int = 2
    """ignore routine candidates shorter than this (the scalability experiment's longer
    routines; the ablations copy the lengths the full model then finds)"""
    max_routine_length: int = 64
    """ignore routine candidates longer than this (the wrapper pads every step to the longest)"""

    # The authors' released code (SPEC §5b); the defaults follow the paper
    routine_discount: Literal["paper", "authors"] = "paper"
    """RAPL: a routine decision's discount, γ^ℓ (paper) or γ^(ℓ−1) (authors' code)"""
    critic_loss: Literal["paper", "authors"] = "paper"
    """RAPL: the critic loss L_routine + λ_prim·L_prim (paper) or 0.5·L_routine + 0.5·L_prim with
    L_prim dropped when above 10 (authors' code)"""
    prim_states: Literal["inside", "first-n"] = "inside"
    """RAPL: the states of A_prim, every primitive state inside a routine (paper: the return to
    the rollout's end), or the first --num-steps primitive steps of each env's rollout with
    N-step targets (authors' code)"""
    selection: Literal["paper", "authors"] = "paper"
    """the routine score and pruning: f + λ·len and Levenshtein pruning (paper), or f / mean f
    with pruning of routines containing or contained in a kept one, in rule order (authors')"""
    authors: bool = False
    """the authors' code in one flag: --routine-discount authors --critic-loss authors
    --prim-states first-n --no-anneal-lr --selection authors (RAPL only)"""

    # Procgen
    num_levels: int = 100
    """Procgen: number of training levels"""
    start_level: int = 0
    """Procgen: first training level"""
    distribution_mode: Literal["easy", "hard"] = "easy"
    """Procgen: level difficulty for training"""
    eval_distribution_mode: Literal["easy", "hard"] = "easy"
    """Procgen: difficulty of the (unseen) evaluation levels"""
    extra_evals: tuple[Literal["train", "easy", "hard"], ...] = ()
    """Procgen: more evaluations after the main one, each in eval-NAME.json: `train` (the
    training levels), `easy` or `hard` (unseen levels of that difficulty)"""

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
    record_demo: str | None = None
    """record the best of --demo-episodes episodes of the trained agent to this demo file"""
    demo_episodes: int = 10
    """episodes to pick the best demo from"""
    scalars_every: int = 100
    """write the per-update TensorBoard scalars (losses, learning rate, SPS, counters) every this
    many updates and at the last one, like SB3's `log_interval` (A2C: 100); episode returns are
    written at every episode end"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps (decisions with --budget-unit
    decisions)"""
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
        # A categorical policy: `Categorical(logits=...)`'s numbers and draws, computed without
        # building the distribution object (`routine_gym.networks`), on the hot path.
        hidden = self.encoder(obs)
        action, logprob, entropy = categorical_policy(self.actor(hidden), action)
        return action, logprob, entropy, self.critic(hidden).squeeze(-1)

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Sample actions (the same draws as `get_action_and_value`, nothing else computed)."""
        return sample_categorical(self.actor(self.encoder(obs)))

    def evaluate(self, obs: torch.Tensor, action: torch.Tensor):
        """One pass over a rollout: log-probabilities and entropies of the `len(action)` first
        states' actions, and the values of all `len(obs)` states (the rest: bootstraps)."""
        hidden = self.encoder(obs)
        _, logprob, entropy = categorical_policy(self.actor(hidden[: len(action)]),
                                                           action)
        return logprob, entropy, self.critic(hidden).squeeze(-1)


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "iteration", "decisions", "rng", "args",
                   "library")

#: What `--authors` sets: the authors' code where it differs from the paper (SPEC §5b).
AUTHORS_PRESET = {"routine_discount": "authors", "critic_loss": "authors",
                  "prim_states": "first-n", "anneal_lr": False, "selection": "authors"}


def _as_flag(field: str, value) -> str:
    """A field's value as typed: `--critic-loss authors`, `--no-anneal-lr`."""
    name = field.replace("_", "-")
    if isinstance(value, bool):
        return f"--{name}" if value else f"--no-{name}"
    return f"--{name} {value}"


def authors_preset(args: Args) -> None:
    """`--authors`: set every flag of the authors' variant, refusing one given otherwise."""
    if not args.authors:
        return
    given = given_flags()
    for field, value in AUTHORS_PRESET.items():
        if field in given and getattr(args, field) != value:
            raise UsageError(f"--authors sets {_as_flag(field, value)}; drop "
                             f"{_as_flag(field, getattr(args, field))} or --authors")
        setattr(args, field, value)


def extra_checks(args: Args) -> list[tuple[str, bool, str]]:
    """The rules between flags (each flag's own domain is in `plumbing.arguments.DOMAINS`)."""
    rapl_only = args.mode == "rapl"
    return [("min_routine_length", args.min_routine_length <= args.max_routine_length,
             f"≤ --max-routine-length ({args.max_routine_length})"),
            # K = 0 left the routine env without its routine-length info: a KeyError mid-run.
            ("num_routines", args.mode == "a2c" or args.num_routines >= 1,
             "≥ 1 with --mode {rapl,macro} (--mode a2c has no routines)"),
            ("authors", rapl_only or not args.authors, "off unless --mode rapl"),
            ("routine_discount", rapl_only or args.routine_discount == "paper",
             "paper unless --mode rapl"),
            ("critic_loss", rapl_only or args.critic_loss == "paper",
             "paper unless --mode rapl"),
            ("prim_states", rapl_only or args.prim_states == "inside",
             "inside unless --mode rapl"),
            ("rollout_unit", args.rollout_unit == "decisions" or args.prim_states == "inside",
             "decisions with --prim-states first-n (its N primitive steps per env need N "
             "decisions per env)"),
            ("rollout_unit", args.rollout_unit == "decisions" or args.budget_unit == "steps",
             "decisions with --budget-unit decisions (steps sizes rollouts in primitive steps)"),
            ("prim_coef", rapl_only or args.prim_coef == 1.0, "1.0 unless --mode rapl"),
            # A routine flag a run would not read: every one with --mode a2c, the mining
            # flags and --demo with --routine-library.
            *unused_routine_flags(args, "--mode a2c" if args.mode == "a2c" else None)]


def action_meanings(args: Args) -> list[str] | None:
    """The primitive actions' names of the training env (None when it has none)."""
    probe = make_primitive_env(args.env_id, **train_env_kwargs(args))
    meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
    probe.close()
    return meanings


def main(args: Args) -> None:
    # An explicit --total-timesteps on --resume sets a new budget: higher to train on, or at
    # most the steps done to go straight to evaluation and demo recording.
    run = start_run(args, "rapl_a2c.py", CHECKPOINT_KEYS, lower_budget=True,
                    extra_checks=extra_checks, preset=authors_preset)
    args, device, writer = run.args, run.device, run.writer
    for levels in args.extra_evals:
        level_env_kwargs(args, levels)  # refused now, not after training

    # Routines: mined from the demo (or loaded), printed with action names, saved with the run.
    demo, library = None, None
    if args.mode != "a2c":
        # Loaded on --resume too (the library is the checkpoint's): the evaluation aligns with it.
        demo = run.routine_demo(f"--mode {args.mode}")
        library = run.routines(demo, meanings=lambda: action_meanings(args),
                               env_kwargs=train_env_kwargs(args), required=f"--mode {args.mode}")

    # Env setup: same-step autoreset, so the step that ends an episode returns the reset obs.
    # (MinAtar: all games stepped in one call, `routine_gym.envs.minatar_vector`.)
    envs = make_vector_env(args.env_id, args.num_envs, args.seed, routines=library,
                           training=True, record_observations=args.mode == "rapl",
                           env_kwargs=train_env_kwargs(args), capture_video=args.capture_video,
                           run_name=run.name, first_video_episode=run.first_video_episode,
                           async_envs=args.async_envs)
    assert isinstance(envs.single_action_space, gym.spaces.Discrete), "only discrete actions"
    num_actions = int(envs.single_action_space.n)
    num_routines = len(library) if library is not None else 0
    num_primitives = num_actions - num_routines
    max_len = max(library.lengths) if library is not None else 1

    agent = Agent(args.env_id, envs.single_observation_space, num_actions).to(device)
    # foreach: one kernel per step for all tensors instead of a loop (same arithmetic)
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=args.learning_rate,
                                    alpha=args.rmsprop_alpha, eps=args.rmsprop_eps, foreach=True)

    # Rollout storage, time-major: [decision, env] and [decision, step in routine, env].
    n, e = args.num_steps, args.num_envs
    obs_shape = envs.single_observation_space.shape
    obs_dtype = envs.single_observation_space.dtype
    # The storage below, refused now when it cannot fit (--num-steps, --num-envs, the routines).
    check_rollout_memory(envs.single_observation_space, n, e,
                         observations=1 + max(max_len - 1, 1), numbers=5 + max_len)
    actions = np.zeros((n, e), dtype=np.int64)
    step_rewards = np.zeros((n, max_len, e), dtype=np.float64)
    lengths = np.ones((n, e), dtype=np.int64)
    terminated = np.zeros((n, e), dtype=bool)
    truncated = np.zeros((n, e), dtype=bool)
    final_values = np.zeros((n, e), dtype=np.float64)
    inner_obs = np.zeros((n, max(max_len - 1, 1), e, *obs_shape), dtype=obs_dtype)
    first_n = args.mode == "rapl" and args.prim_states == "first-n"
    # --update-forward auto: the acting passes' graphs for the large CNNs (a second pass over
    # the rollout would cost about a fifth of their time), one batched pass for the others.
    keep_graph = args.update_forward == "acting" or (
        args.update_forward == "auto"
        and profile_for(args.env_id).network in ("nature_cnn", "impala_cnn"))
    rollout_obs = np.zeros((n + 1, e, *obs_shape), dtype=obs_dtype)  # + the state after it
    a2c_discounts = np.full((n, e), args.gamma)
    decision_obs = rollout_obs[:n]
    steps_sized = args.rollout_unit == "steps" and args.mode != "a2c"  # A2C: the same rollout

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    # --budget-unit decisions: the budget, the schedule and --checkpoint-every count decisions.
    global_step, iteration, decisions = run.resume(
        {"model": agent, "optimizer": optimizer}, global_step=0, iteration=0, decisions=0,
        count="decisions" if args.budget_unit == "decisions" else "global_step", filmed=envs,
        extra={"library": json.dumps(library.to_dict()) if library is not None else ""})

    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw.
    next_obs, _ = envs.reset(seed=train_seed(args.seed, args.seed_stride, global_step))
    start_time, start_step, start_decisions = time.time(), global_step, decisions
    logs = Every(args.log_every, start=budget_spent(args.budget_unit, global_step, decisions))
    routine_counts = np.zeros(num_actions, dtype=np.int64)
    counts = Counters(writer, num_primitives, num_routines)
    recent_returns: list[float] = []

    while (spent := budget_spent(args.budget_unit, global_step, decisions)) \
            < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - spent / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        # Acting keeps its graph for the update (--update-forward acting), or needs none: the
        # update then runs the network once over the whole rollout.
        acting_outputs = []
        for step in range(n):
            obs_t = torch.as_tensor(next_obs, device=device)
            if keep_graph:
                action_t, logprob, entropy, value = agent.get_action_and_value(obs_t)
                acting_outputs.append((logprob, entropy, value))
            else:
                with torch.inference_mode():
                    action_t = agent.act(obs_t)
            action = action_t.cpu().numpy()
            actions[step] = action
            decision_obs[step] = next_obs
            next_obs, reward, term, trunc, info = envs.step(action)
            terminated[step], truncated[step] = term, trunc
            # Same-step autoreset: `final_obs` and `final_info` come when an episode ended.
            ended = "final_obs" in info

            if args.mode == "a2c":  # lengths: all 1 (as allocated)
                step_rewards[step, 0] = reward
            else:
                done = term | trunc
                lengths[step] = merge_final(info, "routine_length", done)
                step_rewards[step] = merge_final(info, "routine_rewards", done).T
                if args.mode == "rapl" and max_len > 1:
                    inner = merge_final(info, "routine_observations", done)
                    inner_obs[step] = np.swapaxes(inner[:, : max_len - 1], 0, 1)
            if args.reward_scale != 1.0:
                step_rewards[step] *= args.reward_scale
            if ended and trunc.any():  # bootstrap a cut episode from its last obs's value
                final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
                with torch.no_grad():
                    v = agent.get_value(torch.as_tensor(final_obs, device=device))
                final_values[step, trunc] = v.cpu().numpy()

            ran = e if args.mode == "a2c" else int(lengths[step].sum())
            global_step += ran
            decisions += e
            if ended and "episode" in info["final_info"]:
                final = info["final_info"]
                for i in np.flatnonzero(final["_episode"]):
                    ret, length = float(final["episode"]["r"][i]), int(final["episode"]["l"][i])
                    recent_returns.append(ret)
                    writer.add_scalar("charts/episodic_return", ret, global_step)
                    writer.add_scalar("charts/episodic_length", length, global_step)
            # Rounded to the nearest vector step, and against the run's whole count, so that
            # U updates have seen U·N·num_envs primitive steps (± half a vector step).
            if steps_sized and global_step + ran / 2 >= iteration * n * e:
                break

        # The rollout's d decisions per env (n unless --rollout-unit steps ended it early).
        d = step + 1
        acts, rews, lens = actions[:d], step_rewards[:d], lengths[:d]
        terms, truncs, finals = terminated[:d], truncated[:d], final_values[:d]
        chosen = np.bincount(acts.reshape(-1), minlength=num_actions)  # the rollout's choices
        routine_counts += chosen
        counts.add_counts(chosen, int(lens.sum()))

        # Returns. RAPL: discounted routine reward and γ^ℓ; MacroAction: summed reward and one γ
        # per decision; A2C: a decision's one reward and γ (both others' numbers, with ℓ = 1).
        if args.mode == "a2c":
            rewards, discounts = rews[:, 0], a2c_discounts[:d]
        elif args.mode == "rapl":
            rewards, discounts = routine_reward_and_discount(rews, lens, args.gamma)
            if args.routine_discount == "authors":
                discounts = routine_discount_minus_one(lens, acts >= num_primitives, args.gamma)
        else:
            rewards, discounts = macro_reward_and_discount(rews, lens, args.gamma)
        if keep_graph:  # the acting passes' outputs, and the values of the states after
            logprobs, entropies, values = (torch.cat(x) for x in zip(*acting_outputs, strict=True))
            with torch.no_grad():
                bootstrap = agent.get_value(torch.as_tensor(next_obs, device=device))
            bootstrap = bootstrap.cpu().numpy()
        else:
            # One forward pass over the rollout's d·e decision states and the e states after
            # it, whose values (detached) bootstrap the returns. Batched, each output is the
            # acting pass's bit for bit (tests/test_rapl_a2c_update.py).
            rollout_obs[d] = next_obs
            logprobs, entropies, all_values = agent.evaluate(
                torch.as_tensor(rollout_obs[: d + 1].reshape(-1, *obs_shape), device=device),
                torch.as_tensor(acts.reshape(-1), device=device))
            values = all_values[: d * e]
            bootstrap = all_values[d * e:].detach().cpu().numpy()
        returns = decision_returns(rewards, discounts, terms, truncs, finals, bootstrap)
        b_returns = torch.as_tensor(returns, dtype=torch.float32, device=device)
        advantages = b_returns - values.view(d, e)  # A_routine, [d, e]
        pg_loss = -(logprobs.view(d, e) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = entropies.view(d, e).mean()

        prim_loss = torch.zeros((), device=device)
        if first_n:
            # The authors' A_prim: the first N primitive steps of each env's rollout, N-step TD.
            where, inside = first_steps(lengths, n)
            env_of = np.broadcast_to(np.arange(e), where.shape)
            states = inner_obs[np.minimum(where, n - 1), np.maximum(inside - 1, 0), env_of]
            at_decision = (inside == 0) & (where < n)  # a decision's own state
            states[at_decision] = decision_obs[where[at_decision], env_of[at_decision]]
            after = where == n  # the state after the rollout's last decision
            states[after] = next_obs[env_of[after]]
            state_values = agent.get_value(
                torch.as_tensor(states.reshape(-1, *obs_shape), device=device)).view(n + 1, e)
            targets = window_returns(step_rewards, lengths, terminated, truncated, final_values,
                                     where, inside, state_values[n].detach().cpu().numpy(),
                                     args.gamma)
            targets = torch.as_tensor(targets, dtype=torch.float32, device=device)
            prim_loss = (targets - state_values[:n]).pow(2).mean()
        elif args.mode == "rapl" and max_len > 1:
            # A_prim at the primitive states inside routines (step j ≥ 1 of a decision).
            prim = primitive_returns(rews, lens, terms, truncs, finals, bootstrap, args.gamma)
            inner_states, prim_targets = inner_states_and_targets(inner_obs[:d], prim, lens)
            if len(prim_targets):
                states = torch.as_tensor(inner_states, device=device)
                targets = torch.as_tensor(prim_targets, dtype=torch.float32, device=device)
                prim_loss = (targets - agent.get_value(states)).pow(2).mean()

        loss = pg_loss - args.ent_coef * entropy_loss \
            + args.vf_coef * critic_loss(v_loss, prim_loss, args.critic_loss, args.prim_coef)
        optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        check_update(global_step, loss, grad_norm, parts={
            "value loss": v_loss, "policy loss": pg_loss, "primitive value loss": prim_loss,
            "entropy": entropy_loss})  # stop before a non-finite update is applied
        optimizer.step()

        elapsed = max(time.time() - start_time, 1e-9)
        spent = budget_spent(args.budget_unit, global_step, decisions)
        if scalars_due(iteration, args.scalars_every, last=spent >= args.total_timesteps):
            writer.add_scalar("charts/learning_rate", optimizer.param_groups[0]["lr"], global_step)
            writer.add_scalar("losses/value_loss", v_loss.item(), global_step)
            writer.add_scalar("losses/prim_value_loss", prim_loss.item(), global_step)
            writer.add_scalar("losses/policy_loss", pg_loss.item(), global_step)
            writer.add_scalar("losses/entropy", entropy_loss.item(), global_step)
            writer.add_scalar("charts/SPS", int((global_step - start_step) / elapsed), global_step)
            writer.add_scalar("charts/decisions_per_second",
                              int((decisions - start_decisions) / elapsed), global_step)
            counts.log(global_step, decisions, iteration)
            if num_routines:
                usage = routine_counts / max(routine_counts.sum(), 1)
                writer.add_scalar("routines/primitive_usage", usage[:num_primitives].sum(),
                                  global_step)
                for k in range(num_routines):
                    writer.add_scalar(f"routines/usage_{k}", usage[num_primitives + k], global_step)

        if logs.due(spent) or spent >= args.total_timesteps:
            mean_ret = f"{np.mean(recent_returns[-20:]):.1f}" if recent_returns else "n/a"
            usage = routine_counts[num_primitives:].sum() / max(routine_counts.sum(), 1)
            progress = budget_progress(args.budget_unit, global_step, decisions,
                                       args.total_timesteps)
            print(f"{progress}  "
                  f"SPS {int((global_step - start_step) / elapsed):>5d}  "
                  f"return(last 20) {mean_ret:>8s}  episodes {len(recent_returns):>5d}  "
                  f"routine use {usage:5.1%}", flush=True)
        run.checkpoint_if_due(global_step=global_step, iteration=iteration, decisions=decisions)

    envs.close()

    def policy(obs):
        with torch.no_grad():
            action, _, _, _ = agent.get_action_and_value(
                torch.as_tensor(np.asarray(obs)[None], device=device))
        return int(action[0])

    # Full games on the evaluation view (Procgen: unseen levels), aligned with the demo the
    # routines came from when there is one; then --extra-evals and --record-demo.
    run.finish(policy, model=agent, method=args.mode, demo=demo, routines=library,
               env_kwargs=eval_env_kwargs(args), global_step=global_step, iteration=iteration,
               decisions=decisions)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args, renamed={"--routines": "--routine-library"})
