"""RAPL-PPO, plain PPO and the MacroAction baseline in one CleanRL-style file (SPEC §5).

    python algos/rapl_ppo.py --env-id ALE/Qbert-v5                  # RAPL-PPO, shipped demo
    python algos/rapl_ppo.py --env-id ALE/Qbert-v5 --mode ppo       # plain PPO (ppo_atari.py)
    python algos/rapl_ppo.py --env-id ALE/Qbert-v5 --mode macro     # routines as black boxes

CleanRL's PPO (`ppo_atari.py`: clipped surrogate, clipped value loss, entropy bonus, minibatch
epochs, advantage normalisation, learning-rate annealing, gradient clipping, Adam) over the
action space `Discrete(|A| + K)` of `rapl_a2c.py`: the primitive actions plus K routines mined
from one demonstration. A rollout holds N decisions per env (`--rollout-unit steps`: the
d ≤ N decisions that ran about N primitive steps per env, so that RAPL and MacroAction make
PPO's updates on PPO's frames); decision i at primitive time t_i runs a routine of executed
length ℓ_i, and RAPL uses (`routine_gym.ppo`)

    R_i = Σ_{τ=t_i}^{t_i+ℓ_i-1} γ^{τ-t_i} r_τ,   Γ_i = γ^{ℓ_i}                  (routine reward)
    δ_i = R_i + Γ_i V(s_{t_{i+1}}) − V(s_{t_i}),  A_i = δ_i + Γ_i λ^{ℓ_i} A_{i+1}   (SMDP GAE)
    G_{i,j} = Σ_{m≥j} γ^{m-j} r_m + γ^k [(1 − λ^k) V(s_{t_{i+1}}) + λ^k G_{i+1}]   (A_prim)
    L = L_clip + λ_value (L_V + λ_prim L_V,prim) − λ_entropy H

λ decays per primitive step, as γ does: across a routine of ℓ steps the trace falls by
(γλ)^ℓ, not γ^ℓ·λ. That is the primitive-level λ-return in which the bootstraps that would
fall inside a routine (where no decision is made) are carried on to its end, so the
advantage's bias-variance trade-off spans the same game time however long the routines are;
with one λ per decision an agent using routines would get ever more Monte-Carlo advantages.
With every ℓ = 1 this is CleanRL's GAE exactly. A_prim trains the critic at every primitive
state *inside* a routine (k = ℓ_i − j steps before its end) on the λ-return from there, the
same mixture at the routine's end as the decision's own target; with λ = 1 these are
RAPL-A2C's targets (`routine_gym.returns.primitive_returns`). Its loss is clipped like the
value loss, against the values of those states before the update, and each such state is
trained in `--prim-epochs` (default 1) of the update's epochs, once a rollout as in RAPL-A2C,
where the decisions are trained in every epoch (`routine_gym.ppo.inner_state_shares`).
`--mode macro` treats routines as black boxes (summed reward, one γ and one λ per decision,
no A_prim); `--mode ppo` has no routines.

Defaults per env family (flags left unset): Atari as CleanRL's `ppo_atari.py`, Procgen as its
`ppo_procgen.py` (IMPALA CNN), MinAtar as gymnax-blines' MinAtar PPO (with γ 0.99, the
MinAtar paper's and `rapl_a2c.py`'s), any other env as CleanRL's `ppo.py` (`FAMILY_DEFAULTS`).
Logged steps count primitive agent steps; the run's decisions, updates, steps per decision and
routine shares are logged under `counters/` and `--budget-unit decisions` counts the budget in
decisions, as in `rapl_a2c.py`, whose run set-up, checkpoints, `--resume` and evaluation this
script shares.
"""

from __future__ import annotations

from routine_gym.plumbing.openmp import shorten_spin

shorten_spin()  # before torch loads OpenMP: a shorter spin of its idle threads (see there)

import dataclasses
import json
import os
import warnings
from dataclasses import dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

import routine_gym
from routine_gym.envs import profile_for
from routine_gym.envs.factory import make_primitive_env, make_vector_env
from routine_gym.interruption import interrupt_routines, policy_stop_rule
from routine_gym.intra_routine import (
    RoutineLogits,
    inner_actions,
    intra_routine_ppo_loss,
    routine_table,
)
from routine_gym.networks import ObservationEncoder, categorical_policy, layer_init
from routine_gym.plumbing.counters import budget_spent, rollout_filled
from routine_gym.plumbing.divergence import check_update
from routine_gym.plumbing.loading import mechanism_rules, unused_routine_flags
from routine_gym.plumbing.memory import check_rollout_memory
from routine_gym.plumbing.run import (
    eval_env_kwargs,
    level_env_kwargs,
    run_script,
    start_run,
    train_env_kwargs,
)
from routine_gym.plumbing.seeds import train_seed
from routine_gym.plumbing.training_log import TrainingLog
from routine_gym.ppo import (
    clipped_policy_loss,
    clipped_value_loss,
    inner_lambda_returns,
    inner_state_shares,
    normalize_advantages,
    routine_trace_decay,
    smdp_gae,
)
from routine_gym.returns import (
    critic_loss,
    macro_reward_and_discount,
    routine_reward_and_discount,
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
    S > 1 gives each seed its own block [seed·S, (seed+1)·S) of env seeds, S at least 4,
    2 × --num-envs, 4 × --eval-episodes and 4 × --demo-episodes (`routine_gym.plumbing.seeds`);
    the fair budgets use 1000"""
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

    # Algorithm (None: the env family's default, FAMILY_DEFAULTS)
    env_id: str = "ALE/Qbert-v5"
    """the env id: `ALE/*-v5`, `*NoFrameskip-v4`, `procgen/CoinRun-v0`, `MinAtar/*` or any
    discrete env"""
    mode: Literal["rapl", "ppo", "macro"] = "rapl"
    """rapl: RAPL-PPO; ppo: plain PPO on primitives; macro: the MacroAction baseline"""
    total_timesteps: int = 10_000_000
    """total primitive agent steps of the experiment (decisions with --budget-unit decisions)"""
    budget_unit: Literal["steps", "decisions"] = "steps"
    """what --total-timesteps, the learning-rate schedule and --checkpoint-every count:
    primitive agent steps, or decisions (agent calls)"""
    learning_rate: float | None = None
    """the learning rate of the Adam optimizer (None: the env family's, Atari 2.5e-4, Procgen
    5e-4, MinAtar 5e-4, others 2.5e-4)"""
    anneal_lr: bool = True
    """linear decay of the learning rate to 0 (CleanRL's ppo_procgen.py keeps it constant:
    --no-anneal-lr)"""
    num_envs: int | None = None
    """the number of parallel environments (None: the env family's, Atari 8, Procgen 64,
    MinAtar 64, others 4)"""
    num_steps: int | None = None
    """decisions per environment per rollout, N (None: the env family's, Atari 128, Procgen
    256, MinAtar 128, others 128); with --rollout-unit steps, primitive steps"""
    rollout_unit: Literal["decisions", "steps"] = "decisions"
    """what --num-steps counts: decisions (the paper: a rollout holds N decisions per env, each
    running 1 to ℓ primitive steps), or primitive steps (a rollout ends as soon as its decisions
    ran N·num_envs primitive steps in all (to the nearest vector step, counted over the whole
    run), so RAPL and MacroAction make as many updates as PPO on as many frames)"""
    gamma: float | None = None
    """the discount factor γ per primitive step (None: the env family's, Procgen 0.999, others
    0.99)"""
    gae_lambda: float = 0.95
    """the λ of generalised advantage estimation, per primitive step"""
    num_minibatches: int | None = None
    """the number of minibatches per epoch (None: the env family's, Atari 4, Procgen 8,
    MinAtar 8, others 4)"""
    update_epochs: int | None = None
    """the number of epochs over each rollout (None: the env family's, Atari 4, Procgen 3,
    MinAtar 4, others 4)"""
    norm_adv: bool = True
    """normalise the advantages in each minibatch"""
    clip_coef: float | None = None
    """the surrogate clipping coefficient ε, also the value clipping range (None: the env
    family's, Atari 0.1, others 0.2)"""
    clip_vloss: bool = True
    """clip the value losses (decision states and, RAPL, the states inside routines)"""
    ent_coef: float = 0.01
    """coefficient of the entropy bonus (λ_entropy)"""
    vf_coef: float = 0.5
    """coefficient of the value loss (λ_value)"""
    prim_coef: float = 1.0
    """coefficient of the primitive-level value loss (λ_prim), RAPL only"""
    prim_epochs: int | None = None
    """RAPL: in how many of a rollout's --update-epochs each state inside a routine is trained
    (None: 1, each such state once a rollout, as RAPL-A2C trains it; --update-epochs: in every
    epoch, as the decisions are, and as this script did before 2026-12-05, 1.2-1.5× slower on
    MinAtar Breakout; a run resumed from a checkpoint of before then keeps doing so)"""
    max_grad_norm: float = 0.5
    """the maximum norm for gradient clipping"""
    target_kl: float | None = None
    """stop a rollout's epochs early once the approximate KL exceeds this (None: never)"""
    reward_scale: float | None = None
    """multiply each reward by this for learning (after Atari's sign clipping); the logged
    returns stay the game's score. Unset: the env profile's scale (MiniQbert 0.01, its 25- and
    100-point rewards swamp the value loss at 1; every other env 1)"""
    async_envs: bool = False
    """step the environments in subprocesses (AsyncVectorEnv) instead of in this process"""

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
    """ignore routine candidates shorter than this"""
    max_routine_length: int = 64
    """ignore routine candidates longer than this (the wrapper pads every step to the longest)"""
    selection: Literal["paper", "authors"] = "paper"
    """the routine score and pruning: f + λ·len and Levenshtein pruning (paper), or the
    authors' code's (SPEC §5b)"""
    interrupt: float | None = None
    """stop a routine before an inner step where the policy's best action beats the routine's
    next primitive by more than this margin in nats, log π(a*|s) − log π(next|s) > MARGIN
    (`routine_gym.interruption`; the agent then decides again there); unset: every routine runs
    to its end (the paper). --mode rapl or macro"""

    # Beyond the paper (issue 49, `routine_gym.intra_routine`); off by default
    intra_coef: float = 0.0
    """λ_intra: every state inside a routine also trains the policy toward the action the
    routine took there (PPO's clipped surrogate with the advantage min(1, π_old(a|s)) times the
    step's primitive advantage); 0: off (the paper). RAPL only"""
    routine_logit: Literal["free", "first-action"] = "free"
    """a routine's logit: the actor's own output (the paper), or its first primitive's logit
    plus that output (a learned offset), so a routine is chosen with its first action"""

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
    scalars_every: int = 1
    """write the per-update TensorBoard scalars (losses, learning rate, SPS, counters) every this
    many updates and at the last one, like SB3's `log_interval` (PPO: 1); episode returns are
    written at every episode end"""
    log_every: int = 10_000
    """print a progress line every this many primitive steps (decisions with --budget-unit
    decisions)"""
    run_dir: str = "runs"
    """where run folders go"""
    torch_threads: int = 0
    """torch CPU threads (0: torch's default, fastest on an idle machine); 1 is faster when
    other jobs share the CPU"""


#: The defaults of the flags left unset (None), by env family: CleanRL's `ppo_atari.py`,
#: `ppo_procgen.py` and `ppo.py` (every other family: MiniQbert, CartPole, a user's env), and
#: for MinAtar gymnax-blines' MinAtar PPO configs (64 envs × 128 steps, 8 minibatches, 4
#: epochs, Adam 5e-4, ε 0.2) with γ 0.99 instead of their 0.999.
FAMILY_DEFAULTS: dict[str, dict[str, float | int]] = {
    "atari": dict(num_envs=8, num_steps=128, num_minibatches=4, update_epochs=4,
                  learning_rate=2.5e-4, clip_coef=0.1, gamma=0.99),
    "procgen": dict(num_envs=64, num_steps=256, num_minibatches=8, update_epochs=3,
                    learning_rate=5e-4, clip_coef=0.2, gamma=0.999),
    "minatar": dict(num_envs=64, num_steps=128, num_minibatches=8, update_epochs=4,
                    learning_rate=5e-4, clip_coef=0.2, gamma=0.99),
    "other": dict(num_envs=4, num_steps=128, num_minibatches=4, update_epochs=4,
                  learning_rate=2.5e-4, clip_coef=0.2, gamma=0.99),
}

#: What `eval.json` calls each mode's method.
METHODS = {"rapl": "rapl-ppo", "ppo": "ppo", "macro": "macro-ppo"}


def family_defaults(args: Args) -> None:
    """Fill the flags left unset (None) with the env family's defaults (a new run's; a resumed
    run keeps the values it was saved with). An env id whose module cannot be imported is left
    to the run's env check, which names it."""
    try:
        family = profile_for(args.env_id).family
    except ImportError:
        return
    for field, value in FAMILY_DEFAULTS.get(family, FAMILY_DEFAULTS["other"]).items():
        if getattr(args, field) is None:
            setattr(args, field, value)
    if args.prim_epochs is None:
        args.prim_epochs = 1


def extra_checks(args: Args) -> list[tuple[str, bool, str]]:
    """The rules between flags (each flag's own domain is in `plumbing.arguments.DOMAINS`)."""
    batch = (args.num_envs or 1) * (args.num_steps or 1)
    return [("min_routine_length", args.min_routine_length <= args.max_routine_length,
             f"≤ --max-routine-length ({args.max_routine_length})"),
            # K = 0 left the routine env without its routine-length info: a KeyError mid-run.
            ("num_routines", args.mode == "ppo" or args.num_routines >= 1,
             "≥ 1 with --mode {rapl,macro} (--mode ppo has no routines)"),
            ("num_minibatches", args.num_minibatches is None or args.num_minibatches <= batch,
             f"≤ --num-envs × --num-steps ({batch})"),
            ("target_kl", args.target_kl is None or args.target_kl > 0, "> 0"),
            ("rollout_unit", args.rollout_unit == "decisions" or args.budget_unit == "steps",
             "decisions with --budget-unit decisions (steps sizes rollouts in primitive steps)"),
            ("prim_epochs", args.prim_epochs is None or args.update_epochs is None
             or args.prim_epochs <= args.update_epochs,
             f"≤ --update-epochs ({args.update_epochs})"),
            ("prim_coef", args.mode == "rapl" or args.prim_coef == 1.0,
             "1.0 unless --mode rapl"),
            # RAPL's inner states only; 1 is what a new run of any mode is given.
            ("prim_epochs", args.mode == "rapl" or args.prim_epochs in (None, 1),
             "1 (unset) unless --mode rapl"),
            *mechanism_rules(args, "ppo"),
            # A routine flag a run would not read: every one with --mode ppo, the mining
            # flags and --demo with --routine-library.
            *unused_routine_flags(args, "--mode ppo" if args.mode == "ppo" else None)]


class Agent(nn.Module):
    """The policy and the value over one torso for images (CleanRL's `ppo_atari.py` and
    `ppo_procgen.py` share their CNN), over two for flat observations (its `ppo.py` gives the
    actor and the critic an MLP each: on CartPole a shared one learns several times slower)."""

    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int,
                 first_actions: list[int] | None = None) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.critic_encoder = (ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
                               if len(obs_space.shape) == 1 else None)
        self.actor = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)
        self.critic = layer_init(nn.Linear(self.encoder.num_features, 1), std=1.0)
        # --routine-logit first-action: routine k's logit is its first primitive's plus the
        # actor's output (`routine_gym.intra_routine.RoutineLogits`); None: the actor's output.
        self.routine_logits = RoutineLogits(num_actions, first_actions)

    def logits(self, actor_hidden: torch.Tensor) -> torch.Tensor:
        """The policy's logits over the primitives and the routines."""
        return self.routine_logits(self.actor(actor_hidden))

    def features(self, obs: torch.Tensor, num_actor: int | None = None):
        """The actor's features of the first `num_actor` states (default: all) and the critic's
        of all of them."""
        if self.critic_encoder is None:
            hidden = self.encoder(obs)
            return hidden[:num_actor], hidden
        actor_obs = obs if num_actor is None else obs[:num_actor]
        return self.encoder(actor_obs), self.critic_encoder(obs)

    def get_value(self, obs: torch.Tensor) -> torch.Tensor:
        encoder = self.encoder if self.critic_encoder is None else self.critic_encoder
        return self.critic(encoder(obs)).squeeze(-1)

    def get_action_and_value(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        # A categorical policy: `Categorical(logits=...)`'s numbers and draws, computed without
        # building the distribution object (`routine_gym.networks`), on the hot path.
        actor_hidden, critic_hidden = self.features(obs)
        action, logprob, entropy = categorical_policy(self.logits(actor_hidden), action)
        return action, logprob, entropy, self.critic(critic_hidden).squeeze(-1)

    def act(self, obs: torch.Tensor):
        """Sampled actions, their log-probabilities and the states' values (no entropy)."""
        actor_hidden, critic_hidden = self.features(obs)
        action, logprob, _ = categorical_policy(self.logits(actor_hidden))
        return action, logprob, self.critic(critic_hidden).squeeze(-1)

    def evaluate(self, obs: torch.Tensor, action: torch.Tensor,
                 inner_action: torch.Tensor | None = None):
        """One pass over a minibatch: log-probabilities and entropies of the `len(action)`
        first states' actions, and the values of all `len(obs)` states (the rest: states
        inside routines); with `inner_action` (--intra-coef), also the log-probabilities of
        the actions the routines took at those states (else None)."""
        if inner_action is None:
            actor_hidden, critic_hidden = self.features(obs, len(action))
            _, logprob, entropy = categorical_policy(self.logits(actor_hidden), action)
            return logprob, entropy, self.critic(critic_hidden).squeeze(-1), None
        actor_hidden, critic_hidden = self.features(obs)
        logits = self.logits(actor_hidden)
        _, logprob, entropy = categorical_policy(logits[: len(action)], action)
        _, inner_logprob, _ = categorical_policy(logits[len(action):], inner_action)
        return logprob, entropy, self.critic(critic_hidden).squeeze(-1), inner_logprob


#: What a checkpoint of this script holds (`--resume` checks for each).
CHECKPOINT_KEYS = ("model", "optimizer", "global_step", "iteration", "decisions", "rng", "args",
                   "library")


def action_meanings(args: Args) -> list[str] | None:
    """The primitive actions' names of the training env (None when it has none)."""
    probe = make_primitive_env(args.env_id, **train_env_kwargs(args))
    meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
    probe.close()
    return meanings


def values_of(agent: Agent, states: np.ndarray, device: torch.device,
              actions: np.ndarray | None = None, chunk: int = 4096):
    """V(s) of many states without a graph, in chunks (the inner states of a long rollout), and
    with `actions` (--intra-coef's π_old) log π(a|s) of them from the same pass (else None)."""
    values, logprobs = [], []
    with torch.inference_mode():
        for start in range(0, len(states), chunk):
            batch = torch.as_tensor(states[start : start + chunk], device=device)
            if actions is None:
                values.append(agent.get_value(batch).cpu().numpy())
                continue
            taken = torch.as_tensor(actions[start : start + chunk], device=device)
            _, logprob, _, value = agent.get_action_and_value(batch, taken)
            values.append(value.cpu().numpy())
            logprobs.append(logprob.cpu().numpy())

    def joined(parts: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(parts) if parts else np.zeros(0, dtype=np.float32)

    return joined(values), (joined(logprobs) if actions is not None else None)


def load_routines(run, args: Args):
    """The demo and the routine library of a run with routines (None, None with --mode ppo):
    mined from the demo (or loaded), printed with action names, saved with the run; loaded on
    --resume too (the library is the checkpoint's), so that the evaluation aligns with it."""
    if args.mode == "ppo":
        return None, None
    demo = run.routine_demo(f"--mode {args.mode}")
    library = run.routines(demo, meanings=lambda: action_meanings(args),
                           env_kwargs=train_env_kwargs(args), required=f"--mode {args.mode}")
    return demo, library


def make_envs(run, args: Args, library):
    """The training envs: same-step autoreset, so the step that ends an episode returns the
    reset obs."""
    envs = make_vector_env(args.env_id, args.num_envs, args.seed, routines=library,
                           training=True, record_observations=args.mode == "rapl",
                           env_kwargs=train_env_kwargs(args), capture_video=args.capture_video,
                           run_name=run.name, first_video_episode=run.first_video_episode,
                           async_envs=args.async_envs)
    assert isinstance(envs.single_action_space, gym.spaces.Discrete), "only discrete actions"
    return envs


@dataclass
class Rollout:
    """A rollout's storage, time-major: [decision, env] and [decision, step in routine, env]."""

    obs: np.ndarray
    actions: np.ndarray
    logprobs: np.ndarray
    values: np.ndarray
    step_rewards: np.ndarray  # [N, L, E]: the primitive rewards of each decision's routine
    lengths: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    final_values: np.ndarray  # V(last obs) of an episode cut at that decision
    #: Step j ≥ 1 of a routine starts from the observation after step j − 1: [L − 1, 1].
    inner_steps: np.ndarray
    #: RAPL: per decision step, the states inside routines, [step, env] pairs in the order
    #: of `inner_steps < lengths` (a list: their number varies).
    inner_obs: list[np.ndarray]

    def first(self, d: int) -> Rollout:
        """The rollout's first `d` decisions per env (views; `--rollout-unit steps` ends a
        rollout before its N); the states inside routines are those the d decisions stored."""
        return dataclasses.replace(
            self, obs=self.obs[:d], actions=self.actions[:d], logprobs=self.logprobs[:d],
            values=self.values[:d], step_rewards=self.step_rewards[:d],
            lengths=self.lengths[:d], terminated=self.terminated[:d],
            truncated=self.truncated[:d], final_values=self.final_values[:d])


def allocate_rollout(space: gym.spaces.Box, n: int, e: int, max_len: int) -> Rollout:
    """The storage of rollouts of `n` decisions of `e` envs with routines up to `max_len` long,
    refused first (with its flattened copy for the minibatches and the routines' inner states)
    when it cannot fit (--num-steps, --num-envs, the routines)."""
    check_rollout_memory(space, n, e, observations=2 * max_len, numbers=8 + max_len)
    return Rollout(obs=np.zeros((n, e, *space.shape), dtype=space.dtype),
                   actions=np.zeros((n, e), dtype=np.int64),
                   logprobs=np.zeros((n, e), dtype=np.float32),
                   values=np.zeros((n, e), dtype=np.float32),
                   step_rewards=np.zeros((n, max_len, e), dtype=np.float64),
                   lengths=np.ones((n, e), dtype=np.int64),
                   terminated=np.zeros((n, e), dtype=bool),
                   truncated=np.zeros((n, e), dtype=bool),
                   final_values=np.zeros((n, e), dtype=np.float64),
                   inner_steps=np.arange(1, max_len)[:, None], inner_obs=[])


def store_step(rollout: Rollout, step: int, args: Args, max_len: int, reward: np.ndarray,
               term: np.ndarray, trunc: np.ndarray, info: dict) -> None:
    """Store what decision `step` of each env ran: its routine's length, primitive rewards
    (scaled) and, RAPL, the states inside it (ppo: one step, its reward)."""
    done = term | trunc
    rollout.terminated[step], rollout.truncated[step] = term, trunc
    if args.mode == "ppo":
        rollout.step_rewards[step, 0] = reward
    else:
        rollout.lengths[step] = merge_final(info, "routine_length", done)
        rollout.step_rewards[step] = merge_final(info, "routine_rewards", done).T
        if args.mode == "rapl" and max_len > 1:
            inner = merge_final(info, "routine_observations", done)
            inside_now = rollout.inner_steps < rollout.lengths[step][None, :]  # [L-1, E]
            if inside_now.any():
                rollout.inner_obs.append(np.swapaxes(inner[:, : max_len - 1], 0, 1)[inside_now])
    if args.reward_scale != 1.0:
        rollout.step_rewards[step] *= args.reward_scale


def cut_episode_values(agent: Agent, info: dict, trunc: np.ndarray,
                       device: torch.device) -> np.ndarray:
    """V of the last observation of each episode cut (truncated) at this step: its bootstrap."""
    final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
    with torch.inference_mode():
        return agent.get_value(torch.as_tensor(final_obs, device=device)).cpu().numpy()


def decision_rewards(args: Args, rollout: Rollout):
    """Each decision's reward, discount and trace decay. RAPL: discounted routine reward, γ^ℓ
    and λ^ℓ; PPO and MacroAction: summed reward, one γ and one λ per decision (PPO's
    routines: length 1)."""
    if args.mode == "rapl":
        rewards, discounts = routine_reward_and_discount(rollout.step_rewards, rollout.lengths,
                                                         args.gamma)
        return rewards, discounts, routine_trace_decay(rollout.lengths, args.gae_lambda)
    rewards, discounts = macro_reward_and_discount(rollout.step_rewards, rollout.lengths,
                                                   args.gamma)
    return rewards, discounts, np.full(rollout.lengths.shape, args.gae_lambda)


def inner_targets(agent: Agent, args: Args, rollout: Rollout, returns: np.ndarray,
                  bootstrap: np.ndarray, device: torch.device, routines: np.ndarray | None):
    """A_prim (RAPL): how many states inside routines the rollout visited, and (when any)
    those states, their λ-returns and their values now, as tensors (else None); with
    --intra-coef (`routines`: the `routine_table`), also the actions the routines took there
    and their log-probabilities now (else None)."""
    if not rollout.inner_obs:
        return 0, None, None, None, None, None
    inner_states = np.concatenate(rollout.inner_obs)
    prim = inner_lambda_returns(rollout.step_rewards, rollout.lengths, rollout.terminated,
                                rollout.truncated, rollout.final_values, rollout.values,
                                returns, bootstrap, args.gamma, args.gae_lambda)
    inside = rollout.inner_steps[None] < rollout.lengths[:, None, :]  # [N, L-1, E]
    i_states = torch.as_tensor(inner_states, device=device)
    i_returns = torch.as_tensor(prim[:, 1:][inside], dtype=torch.float32, device=device)
    # |A|: the actor's outputs less the routines (the table's rows)
    taken = None if routines is None else inner_actions(
        rollout.actions, rollout.lengths, routines, agent.actor.out_features - len(routines))
    values, logprobs = values_of(agent, inner_states, device, taken)
    i_values = torch.as_tensor(values, device=device)
    if taken is None:
        return len(inner_states), i_states, i_returns, i_values, None, None
    return (len(inner_states), i_states, i_returns, i_values,
            torch.as_tensor(taken, device=device), torch.as_tensor(logprobs, device=device))


def optimise(agent: Agent, optimizer: torch.optim.Optimizer, args: Args, rollout: Rollout,
             advantages: np.ndarray, returns: np.ndarray, inner: tuple, prim_epochs: int,
             global_step: int, device: torch.device) -> dict[str, Any]:
    """PPO's update on a rollout of d decisions per env (`inner`: `inner_targets`' states
    inside routines, their λ-returns and values): --update-epochs of --num-minibatches
    shuffled minibatches of the d·e decisions. Returns the last minibatch's losses and the
    update's KL and clip fraction, by TensorBoard tag."""
    num_inner, i_states, i_returns, i_values, i_actions, i_logprobs = inner
    # Flatten the batch.
    b_obs = torch.as_tensor(rollout.obs.reshape(-1, *rollout.obs.shape[2:]), device=device)
    b_actions = torch.as_tensor(rollout.actions.reshape(-1), device=device)
    b_logprobs = torch.as_tensor(rollout.logprobs.reshape(-1), device=device)
    b_advantages = torch.as_tensor(advantages.reshape(-1), dtype=torch.float32,
                                   device=device)
    b_returns = torch.as_tensor(returns.reshape(-1), dtype=torch.float32, device=device)
    b_values = torch.as_tensor(rollout.values.reshape(-1), device=device)

    # Optimise the policy and the value network: epochs of shuffled minibatches; each
    # minibatch also takes its share of the states inside routines (RAPL) that its epoch
    # trains: each of them in --prim-epochs of the epochs, the epochs' shares dealt from
    # shuffled decks (`inner_state_shares`).
    b_inds = np.arange(rollout.actions.size)
    # A rollout sized in primitive steps may hold fewer decisions than --num-minibatches
    # (d·e of them, d = 1 at the worst): then one decision a minibatch, none empty.
    num_minibatches = min(args.num_minibatches, len(b_inds))
    clipfracs = []
    prim_loss = intra_loss = torch.zeros((), device=device)
    shares = inner_state_shares(num_inner, args.update_epochs, prim_epochs)
    for _ in range(args.update_epochs):
        np.random.shuffle(b_inds)
        # CleanRL's consecutive slices of the shuffled indices (sizes differing by at most
        # one where the batch does not divide), and as many slices of the epoch's share.
        inner_parts = np.array_split(next(shares), num_minibatches)
        for part, inner_part in zip(np.array_split(b_inds, num_minibatches),
                                    inner_parts, strict=True):
            mb_inds = torch.as_tensor(part, device=device)
            mb_obs = b_obs[mb_inds]
            mb_inner = None
            if len(inner_part):
                mb_inner = torch.as_tensor(inner_part, device=device)
                mb_obs = torch.cat([mb_obs, i_states[mb_inner]])
            intra = args.intra_coef > 0 and mb_inner is not None
            newlogprob, entropy, all_values, inner_logprob = agent.evaluate(
                mb_obs, b_actions[mb_inds], i_actions[mb_inner] if intra else None)
            newvalue = all_values[: len(mb_inds)]
            logratio = newlogprob - b_logprobs[mb_inds]
            with torch.no_grad():
                ratio = logratio.exp()
                old_approx_kl = (-logratio).mean()
                approx_kl = ((ratio - 1) - logratio).mean()
                clipfracs.append(((ratio - 1.0).abs() > args.clip_coef).float().mean().item())

            mb_advantages = b_advantages[mb_inds]
            if args.norm_adv and len(mb_inds) > 1:
                mb_advantages = normalize_advantages(mb_advantages)
            pg_loss = clipped_policy_loss(mb_advantages, newlogprob, b_logprobs[mb_inds],
                                          args.clip_coef)
            v_loss = clipped_value_loss(newvalue, b_values[mb_inds], b_returns[mb_inds],
                                        args.clip_coef, args.clip_vloss)
            if mb_inner is not None:
                prim_loss = clipped_value_loss(all_values[len(mb_inds):], i_values[mb_inner],
                                               i_returns[mb_inner], args.clip_coef,
                                               args.clip_vloss)
            else:
                prim_loss = torch.zeros((), device=device)
            entropy_loss = entropy.mean()
            loss = pg_loss - args.ent_coef * entropy_loss \
                + args.vf_coef * critic_loss(v_loss, prim_loss, "paper", args.prim_coef)
            if intra:  # L_intra: the routines' own actions, at A_prim's advantage
                intra_loss = intra_loss_of(args, inner_logprob, i_logprobs[mb_inner],
                                           i_returns[mb_inner] - i_values[mb_inner])
                loss = loss + args.intra_coef * intra_loss
            else:  # logged as the last minibatch's: none here, not the one before's
                intra_loss = torch.zeros((), device=device)

            optimizer.zero_grad()
            loss.backward()
            grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
            check_update(global_step, loss, grad_norm, parts={
                "value loss": v_loss, "policy loss": pg_loss,
                "primitive value loss": prim_loss, "entropy": entropy_loss})
            optimizer.step()
        if args.target_kl is not None and approx_kl > args.target_kl:
            break

    return {"losses/value_loss": v_loss, "losses/prim_value_loss": prim_loss,
            "losses/policy_loss": pg_loss, "losses/entropy": entropy_loss,
            "losses/old_approx_kl": old_approx_kl, "losses/approx_kl": approx_kl,
            "losses/clipfrac": np.mean(clipfracs),
            **({"losses/intra_loss": intra_loss} if args.intra_coef else {})}


def intra_loss_of(args: Args, logprobs: torch.Tensor, old_logprobs: torch.Tensor,
                  advantages: torch.Tensor) -> torch.Tensor:
    """--intra-coef's L_intra over a minibatch's states inside routines: the clipped surrogate
    of `intra_routine_ppo_loss` on their primitive advantages G_prim − V_old (normalised over
    them with --norm-adv, as the decisions' are)."""
    if args.norm_adv and len(advantages) > 1:
        advantages = normalize_advantages(advantages)
    return intra_routine_ppo_loss(logprobs, old_logprobs, advantages, args.clip_coef)


def explained_variance(values: np.ndarray, returns: np.ndarray) -> float:
    """1 − Var(returns − values) / Var(returns) over a rollout (NaN when the returns are
    constant), CleanRL's `losses/explained_variance`."""
    y_pred, y_true = values.reshape(-1), returns.reshape(-1)
    var_y = np.var(y_true)
    return np.nan if var_y == 0 else 1 - np.var(y_true - y_pred) / var_y


def stop_logits(agent: Agent):
    """The logits `--interrupt`'s stop rule reads at an inner state: the acting policy's."""
    return lambda obs: agent.logits(agent.features(obs)[0])


def evaluate_agent(run, agent: Agent, args: Args, demo, library, device: torch.device,
                   **counters: int) -> None:
    """Full games on the evaluation view (Procgen: unseen levels), aligned with the demo the
    routines came from when there is one; then --extra-evals and --record-demo. With
    --interrupt they act under the stop rule they were trained under (a rule of their own, so
    the training rule's counts stay the training's)."""
    eval_stop_rule = policy_stop_rule(stop_logits(agent), args.interrupt, device)

    def policy(observation):
        with torch.no_grad():
            action, _, _, _ = agent.get_action_and_value(
                torch.as_tensor(np.asarray(observation)[None], device=device))
        return int(action[0])

    run.finish(policy, model=agent, method=METHODS[args.mode], demo=demo, routines=library,
               env_kwargs=eval_env_kwargs(args), stop_rule=eval_stop_rule, **counters)


def main(args: Args) -> None:
    # An explicit --total-timesteps on --resume sets a new budget: higher to train on, or at
    # most the steps done to go straight to evaluation and demo recording.
    run = start_run(args, "rapl_ppo.py", CHECKPOINT_KEYS, lower_budget=True,
                    extra_checks=extra_checks, preset=family_defaults)
    args, device, writer = run.args, run.device, run.writer
    for levels in args.extra_evals:
        level_env_kwargs(args, levels)  # refused now, not after training
    demo, library = load_routines(run, args)
    envs = make_envs(run, args, library)
    num_actions = int(envs.single_action_space.n)
    num_routines = len(library) if library is not None else 0
    max_len = max(library.lengths) if library is not None else 1
    # None only in a run resumed from a checkpoint made before --prim-epochs: every epoch.
    prim_epochs = args.prim_epochs if args.prim_epochs is not None else args.update_epochs
    first_actions = ([routine[0] for routine in library]
                     if args.routine_logit == "first-action" else None)
    agent = Agent(args.env_id, envs.single_observation_space, num_actions,
                  first_actions).to(device)
    # --interrupt: a stop rule on the acting policy's logits (None: off)
    stop_rule = interrupt_routines(envs, stop_logits(agent), args.interrupt, device)
    routines = routine_table(library.routines) if args.intra_coef else None
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5,
                                 foreach=True)
    n, e = args.num_steps, args.num_envs
    rollout = allocate_rollout(envs.single_observation_space, n, e, max_len)
    steps_sized = args.rollout_unit == "steps" and args.mode != "ppo"  # PPO: the same rollout

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    # With --interrupt, the stop rule's counts too: counters/interruptions counts the whole run.
    state = {"model": agent, "optimizer": optimizer,
             **({"interruptions": stop_rule} if stop_rule is not None else {})}
    global_step, iteration, decisions = run.resume(
        state, global_step=0, iteration=0, decisions=0,
        count="decisions" if args.budget_unit == "decisions" else "global_step", filmed=envs,
        extra={"library": json.dumps(library.to_dict()) if library is not None else ""})
    # The env is reset with a seed that depends on where the run is, so a resumed run does not
    # replay the episodes it already saw.
    next_obs, _ = envs.reset(seed=train_seed(args.seed, args.seed_stride, global_step))
    log = TrainingLog(writer, args, num_actions - num_routines, num_routines, global_step,
                      decisions)
    log.counts.watch_interruptions(stop_rule)

    while (spent := budget_spent(args.budget_unit, global_step, decisions)) \
            < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - spent / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        rollout.inner_obs = []
        for step in range(n):
            rollout.obs[step] = next_obs
            with torch.inference_mode():
                action_t, logprob_t, value_t = agent.act(torch.as_tensor(next_obs, device=device))
            action = action_t.cpu().numpy()
            rollout.actions[step], rollout.logprobs[step] = action, logprob_t.cpu().numpy()
            rollout.values[step] = value_t.cpu().numpy()
            next_obs, reward, term, trunc, info = envs.step(action)
            store_step(rollout, step, args, max_len, reward, term, trunc, info)
            if trunc.any():  # bootstrap a cut episode from the value of its last observation
                rollout.final_values[step, trunc] = cut_episode_values(agent, info, trunc, device)
            ran = e if args.mode == "ppo" else int(rollout.lengths[step].sum())
            global_step += ran
            decisions += e
            if (term | trunc).any():
                log.episodes(info, global_step)
            if steps_sized and rollout_filled(global_step, ran, iteration, n, e):
                break
        # The rollout's d decisions per env (n unless --rollout-unit steps ended it early).
        first = rollout.first(step + 1)
        log.rollout(first.actions, int(first.lengths.sum()))

        # Advantages: SMDP GAE over the decisions (`decision_rewards`), and (RAPL) the
        # λ-returns of the states inside routines, with their values before the update.
        with torch.inference_mode():
            bootstrap = agent.get_value(torch.as_tensor(next_obs, device=device)).cpu().numpy()
        rewards, discounts, traces = decision_rewards(args, first)
        advantages, returns = smdp_gae(rewards, discounts, traces, first.values,
                                       first.terminated, first.truncated,
                                       first.final_values, bootstrap)
        inner = inner_targets(agent, args, first, returns, bootstrap, device, routines)

        losses = optimise(agent, optimizer, args, first, advantages, returns, inner,
                          prim_epochs, global_step, device)
        log.update(global_step, decisions, iteration, optimizer.param_groups[0]["lr"], {
            **losses, "losses/explained_variance": explained_variance(first.values, returns)})
        run.checkpoint_if_due(global_step=global_step, iteration=iteration, decisions=decisions)

    envs.close()
    evaluate_agent(run, agent, args, demo, library, device, global_step=global_step,
                   iteration=iteration, decisions=decisions)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args, renamed={"--routines": "--routine-library"})
