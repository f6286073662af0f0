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
from routine_gym.interruption import interrupt_routines, policy_stop_rule
from routine_gym.intra_routine import (
    RoutineLogits,
    inner_actions,
    intra_routine_loss,
    routine_table,
)
from routine_gym.networks import (
    ObservationEncoder,
    categorical_policy,
    layer_init,
    sample_categorical,
)
from routine_gym.plumbing.arguments import given_flags
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
    interrupt: float | None = None
    """stop a routine before an inner step where the policy's best action beats the routine's
    next primitive by more than this margin in nats, log π(a*|s) − log π(next|s) > MARGIN
    (`routine_gym.interruption`; the agent then decides again there); unset: every routine runs
    to its end (the paper). --mode rapl or macro"""

    # Beyond the paper (issue 49, `routine_gym.intra_routine`); off by default
    intra_coef: float = 0.0
    """λ_intra: every state inside a routine also trains the policy toward the action the
    routine took there (an off-policy term weighted by min(1, π(a|s)) and the step's primitive
    advantage); 0: off (the paper). RAPL only"""
    routine_logit: Literal["free", "first-action"] = "free"
    """a routine's logit: the actor's own output (the paper), or its first primitive's logit
    plus that output (a learned offset), so a routine is chosen with its first action"""

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
    """The policy and the value over one torso (`routine_gym.networks.ObservationEncoder`).

    `keep_graph` is `--update-forward`'s choice, hidden behind `decide` and `update_forward`:
    acting keeps each pass's graph for the update (no second pass: fastest for the large Atari
    and Procgen CNNs), or builds none, and the update runs the network once more over the
    whole rollout in one batch (fewer, larger calls: fastest for MinAtar's and the MLP's small
    networks). The same numbers up to float rounding (tests/test_rapl_a2c_update.py).
    """

    def __init__(self, env_id: str, obs_space: gym.spaces.Box, num_actions: int,
                 keep_graph: bool = False, first_actions: list[int] | None = None) -> None:
        super().__init__()
        self.encoder = ObservationEncoder(env_id, obs_space.shape, obs_space.dtype)
        self.actor = layer_init(nn.Linear(self.encoder.num_features, num_actions), std=0.01)
        self.critic = layer_init(nn.Linear(self.encoder.num_features, 1), std=1.0)
        self.keep_graph = keep_graph
        self._acting: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        # --routine-logit first-action: routine k's logit is its first primitive's plus the
        # actor's output (`routine_gym.intra_routine.RoutineLogits`); None: the actor's output.
        self.routine_logits = RoutineLogits(num_actions, first_actions)

    def logits(self, hidden: torch.Tensor) -> torch.Tensor:
        """The policy's logits over the primitives and the routines."""
        return self.routine_logits(self.actor(hidden))

    def get_value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.critic(self.encoder(obs)).squeeze(-1)

    def get_action_and_value(self, obs: torch.Tensor, action: torch.Tensor | None = None):
        # A categorical policy: `Categorical(logits=...)`'s numbers and draws, computed without
        # building the distribution object (`routine_gym.networks`), on the hot path.
        hidden = self.encoder(obs)
        action, logprob, entropy = categorical_policy(self.logits(hidden), action)
        return action, logprob, entropy, self.critic(hidden).squeeze(-1)

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """Sample actions (the same draws as `get_action_and_value`, nothing else computed)."""
        return sample_categorical(self.logits(self.encoder(obs)))

    def evaluate(self, obs: torch.Tensor, action: torch.Tensor):
        """One pass over a rollout: log-probabilities and entropies of the `len(action)` first
        states' actions, and the values of all `len(obs)` states (the rest: bootstraps)."""
        hidden = self.encoder(obs)
        _, logprob, entropy = categorical_policy(self.logits(hidden[: len(action)]),
                                                           action)
        return logprob, entropy, self.critic(hidden).squeeze(-1)

    def inner_pass(self, obs: torch.Tensor, action: torch.Tensor):
        """Values of states inside routines and the log-probabilities of the actions the
        routines took there (--intra-coef), in one pass."""
        hidden = self.encoder(obs)
        _, logprob, _ = categorical_policy(self.logits(hidden), action)
        return self.critic(hidden).squeeze(-1), logprob

    def decide(self, obs: torch.Tensor) -> torch.Tensor:
        """The actions of one acting step; with `keep_graph`, the pass's log-probabilities,
        entropies and values are kept, with their graph, for `update_forward`."""
        if self.keep_graph:
            action, logprob, entropy, value = self.get_action_and_value(obs)
            self._acting.append((logprob, entropy, value))
            return action
        with torch.inference_mode():
            return self.act(obs)

    def update_forward(self, rollout_obs: np.ndarray, next_obs: np.ndarray,
                       actions: np.ndarray):
        """The update's forward pass over a rollout of d decisions per env: the log-probability
        and entropy of each decision's action and its state's value (with their graph, [d·e]),
        and the values of the e states `next_obs` after it (detached, numpy), which bootstrap
        the returns. `rollout_obs` [d + 1, e, ...] holds the decision states, then `next_obs`.

        With `keep_graph`, from the acting passes' kept outputs; otherwise one pass over the
        d·e + e states, each output the acting pass's bit for bit."""
        device = self.actor.weight.device
        if self.keep_graph:
            logprobs, entropies, values = (torch.cat(x) for x in zip(*self._acting, strict=True))
            self._acting = []
            with torch.no_grad():
                bootstrap = self.get_value(torch.as_tensor(next_obs, device=device))
            return logprobs, entropies, values, bootstrap.cpu().numpy()
        logprobs, entropies, all_values = self.evaluate(
            torch.as_tensor(rollout_obs.reshape(-1, *rollout_obs.shape[2:]), device=device),
            torch.as_tensor(actions.reshape(-1), device=device))
        num = actions.size
        return logprobs, entropies, all_values[:num], all_values[num:].detach().cpu().numpy()


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
    given = given_flags(args)
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
            *mechanism_rules(args, "a2c"),
            ("intra_coef", args.intra_coef == 0.0 or args.prim_states == "inside",
             "0 with --prim-states first-n (it trains at the states inside routines)"),
            # A routine flag a run would not read: every one with --mode a2c, the mining
            # flags and --demo with --routine-library.
            *unused_routine_flags(args, "--mode a2c" if args.mode == "a2c" else None)]


def action_meanings(args: Args) -> list[str] | None:
    """The primitive actions' names of the training env (None when it has none)."""
    probe = make_primitive_env(args.env_id, **train_env_kwargs(args))
    meanings = getattr(probe.unwrapped, "get_action_meanings", lambda: None)()
    probe.close()
    return meanings


def load_routines(run, args: Args):
    """The demo and the routine library of a run with routines (None, None with --mode a2c):
    mined from the demo (or loaded), printed with action names, saved with the run; loaded on
    --resume too (the library is the checkpoint's), so that the evaluation aligns with it."""
    if args.mode == "a2c":
        return None, None
    demo = run.routine_demo(f"--mode {args.mode}")
    library = run.routines(demo, meanings=lambda: action_meanings(args),
                           env_kwargs=train_env_kwargs(args), required=f"--mode {args.mode}")
    return demo, library


def make_envs(run, args: Args, library):
    """The training envs: same-step autoreset, so the step that ends an episode returns the
    reset obs (MinAtar: all games stepped in one call, `routine_gym.envs.minatar_vector`)."""
    envs = make_vector_env(args.env_id, args.num_envs, args.seed, routines=library,
                           training=True, record_observations=args.mode == "rapl",
                           env_kwargs=train_env_kwargs(args), capture_video=args.capture_video,
                           run_name=run.name, first_video_episode=run.first_video_episode,
                           async_envs=args.async_envs)
    assert isinstance(envs.single_action_space, gym.spaces.Discrete), "only discrete actions"
    return envs


def make_agent(args: Args, envs, device: torch.device, library):
    """The agent, with `--update-forward`'s and `--routine-logit`'s choices, and its RMSprop
    optimizer."""
    # --update-forward auto: the acting passes' graphs for the large CNNs (a second pass over
    # the rollout would cost about a fifth of their time), one batched pass for the others.
    keep_graph = args.update_forward == "acting" or (
        args.update_forward == "auto"
        and profile_for(args.env_id).network in ("nature_cnn", "impala_cnn"))
    first_actions = ([routine[0] for routine in library]
                     if args.routine_logit == "first-action" else None)
    agent = Agent(args.env_id, envs.single_observation_space, int(envs.single_action_space.n),
                  keep_graph=keep_graph, first_actions=first_actions).to(device)
    # foreach: one kernel per step for all tensors instead of a loop (same arithmetic)
    optimizer = torch.optim.RMSprop(agent.parameters(), lr=args.learning_rate,
                                    alpha=args.rmsprop_alpha, eps=args.rmsprop_eps, foreach=True)
    return agent, optimizer


@dataclass
class Rollout:
    """A rollout's storage, time-major: [decision, env] and [decision, step in routine, env]."""

    obs: np.ndarray  # [N + 1, E, ...]: the decision states and the states after the rollout
    actions: np.ndarray
    step_rewards: np.ndarray  # [N, L, E]: the primitive rewards of each decision's routine
    lengths: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    final_values: np.ndarray  # V(last obs) of an episode cut at that decision
    inner_obs: np.ndarray  # [N, L − 1, E, ...]: the states inside routines (RAPL)
    a2c_discounts: np.ndarray


def allocate_rollout(space: gym.spaces.Box, n: int, e: int, max_len: int, gamma: float):
    """The storage of rollouts of `n` decisions of `e` envs with routines up to `max_len` long,
    refused first when it cannot fit (--num-steps, --num-envs, the routines)."""
    check_rollout_memory(space, n, e, observations=1 + max(max_len - 1, 1), numbers=5 + max_len)
    return Rollout(obs=np.zeros((n + 1, e, *space.shape), dtype=space.dtype),
                   actions=np.zeros((n, e), dtype=np.int64),
                   step_rewards=np.zeros((n, max_len, e), dtype=np.float64),
                   lengths=np.ones((n, e), dtype=np.int64),
                   terminated=np.zeros((n, e), dtype=bool),
                   truncated=np.zeros((n, e), dtype=bool),
                   final_values=np.zeros((n, e), dtype=np.float64),
                   inner_obs=np.zeros((n, max(max_len - 1, 1), e, *space.shape),
                                      dtype=space.dtype),
                   a2c_discounts=np.full((n, e), gamma))


def store_step(rollout: Rollout, step: int, args: Args, max_len: int, reward: np.ndarray,
               term: np.ndarray, trunc: np.ndarray, info: dict) -> None:
    """Store what decision `step` of each env ran: its routine's length, primitive rewards
    (scaled) and, RAPL, the states inside it (a2c: one step, its reward)."""
    rollout.terminated[step], rollout.truncated[step] = term, trunc
    if args.mode == "a2c":  # lengths: all 1 (as allocated)
        rollout.step_rewards[step, 0] = reward
    else:
        done = term | trunc
        rollout.lengths[step] = merge_final(info, "routine_length", done)
        rollout.step_rewards[step] = merge_final(info, "routine_rewards", done).T
        if args.mode == "rapl" and max_len > 1:
            inner = merge_final(info, "routine_observations", done)
            rollout.inner_obs[step] = np.swapaxes(inner[:, : max_len - 1], 0, 1)
    if args.reward_scale != 1.0:
        rollout.step_rewards[step] *= args.reward_scale


def cut_episode_values(agent: Agent, info: dict, trunc: np.ndarray,
                       device: torch.device) -> np.ndarray:
    """V of the last observation of each episode cut (truncated) at this step: its bootstrap."""
    final_obs = np.stack([info["final_obs"][i] for i in np.flatnonzero(trunc)])
    with torch.no_grad():
        return agent.get_value(torch.as_tensor(final_obs, device=device)).cpu().numpy()


def decision_rewards(args: Args, rews: np.ndarray, lens: np.ndarray, acts: np.ndarray,
                     num_primitives: int, a2c_discounts: np.ndarray):
    """Each decision's reward and discount. RAPL: discounted routine reward and γ^ℓ (the
    authors' code: γ^(ℓ−1) for a routine); MacroAction: summed reward and one γ per decision;
    A2C: a decision's one reward and γ (both others' numbers, with ℓ = 1)."""
    if args.mode == "a2c":
        return rews[:, 0], a2c_discounts
    if args.mode == "macro":
        return macro_reward_and_discount(rews, lens, args.gamma)
    rewards, discounts = routine_reward_and_discount(rews, lens, args.gamma)
    if args.routine_discount == "authors":
        discounts = routine_discount_minus_one(lens, acts >= num_primitives, args.gamma)
    return rewards, discounts


def inner_state_losses(agent: Agent, args: Args, rollout: Rollout, d: int, next_obs,
                       bootstrap: np.ndarray, max_len: int, device: torch.device,
                       routines: np.ndarray | None, num_primitives: int):
    """RAPL's critic loss at primitive states, ‖A_prim‖² (0 elsewhere): at every state inside
    a routine (step j ≥ 1 of a decision), on the return to the rollout's end (the paper), or
    at the first N primitive steps of each env's rollout, N-step TD (the authors' code); and
    with --intra-coef, L_intra at the states inside routines toward the actions the routines
    (`routines`, their `routine_table`) took there (`intra_routine_loss`; 0 otherwise)."""
    zero = torch.zeros((), device=device)
    n, e = args.num_steps, args.num_envs
    obs_shape = rollout.obs.shape[2:]
    lens, finals = rollout.lengths[:d], rollout.final_values[:d]
    if args.mode == "rapl" and args.prim_states == "first-n":
        where, inside = first_steps(rollout.lengths, n)
        env_of = np.broadcast_to(np.arange(e), where.shape)
        states = rollout.inner_obs[np.minimum(where, n - 1), np.maximum(inside - 1, 0), env_of]
        at_decision = (inside == 0) & (where < n)  # a decision's own state
        states[at_decision] = rollout.obs[where[at_decision], env_of[at_decision]]
        after = where == n  # the state after the rollout's last decision
        states[after] = next_obs[env_of[after]]
        state_values = agent.get_value(
            torch.as_tensor(states.reshape(-1, *obs_shape), device=device)).view(n + 1, e)
        targets = window_returns(rollout.step_rewards, rollout.lengths, rollout.terminated,
                                 rollout.truncated, rollout.final_values, where, inside,
                                 state_values[n].detach().cpu().numpy(), args.gamma)
        targets = torch.as_tensor(targets, dtype=torch.float32, device=device)
        return (targets - state_values[:n]).pow(2).mean(), zero
    if args.mode == "rapl" and max_len > 1:
        prim = primitive_returns(rollout.step_rewards[:d], lens, rollout.terminated[:d],
                                 rollout.truncated[:d], finals, bootstrap, args.gamma)
        inner_states, prim_targets = inner_states_and_targets(rollout.inner_obs[:d], prim, lens)
        if len(prim_targets):
            states = torch.as_tensor(inner_states, device=device)
            targets = torch.as_tensor(prim_targets, dtype=torch.float32, device=device)
            if routines is None:
                return (targets - agent.get_value(states)).pow(2).mean(), zero
            taken = inner_actions(rollout.actions[:d], lens, routines, num_primitives)
            values, logprobs = agent.inner_pass(states, torch.as_tensor(taken, device=device))
            advantages = targets - values  # A_prim
            return advantages.pow(2).mean(), intra_routine_loss(logprobs, advantages)
    return zero, zero


def stop_logits(agent: Agent):
    """The logits `--interrupt`'s stop rule reads at an inner state: the acting policy's."""
    return lambda obs: agent.logits(agent.encoder(obs))


def evaluate_agent(run, agent: Agent, args: Args, demo, library, device: torch.device,
                   **counters: int) -> None:
    """Full games on the evaluation view (Procgen: unseen levels), aligned with the demo the
    routines came from when there is one; then --extra-evals and --record-demo. With
    --interrupt they act under the stop rule they were trained under (a rule of their own, so
    the training rule's counts stay the training's)."""
    eval_stop_rule = policy_stop_rule(stop_logits(agent), args.interrupt, device)

    def policy(obs):
        with torch.no_grad():
            action, _, _, _ = agent.get_action_and_value(
                torch.as_tensor(np.asarray(obs)[None], device=device))
        return int(action[0])

    run.finish(policy, model=agent, method=args.mode, demo=demo, routines=library,
               env_kwargs=eval_env_kwargs(args), stop_rule=eval_stop_rule, **counters)


def main(args: Args) -> None:
    # An explicit --total-timesteps on --resume sets a new budget: higher to train on, or at
    # most the steps done to go straight to evaluation and demo recording.
    run = start_run(args, "rapl_a2c.py", CHECKPOINT_KEYS, lower_budget=True,
                    extra_checks=extra_checks, preset=authors_preset)
    args, device, writer = run.args, run.device, run.writer
    for levels in args.extra_evals:
        level_env_kwargs(args, levels)  # refused now, not after training
    demo, library = load_routines(run, args)
    envs = make_envs(run, args, library)
    agent, optimizer = make_agent(args, envs, device, library)
    # --interrupt: a stop rule on the acting policy's logits (None: off)
    stop_rule = interrupt_routines(envs, stop_logits(agent), args.interrupt, device)
    num_routines = len(library) if library is not None else 0
    num_primitives = int(envs.single_action_space.n) - num_routines
    max_len = max(library.lengths) if library is not None else 1
    n, e = args.num_steps, args.num_envs
    rollout = allocate_rollout(envs.single_observation_space, n, e, max_len, args.gamma)
    steps_sized = args.rollout_unit == "steps" and args.mode != "a2c"  # A2C: the same rollout
    routines = routine_table(library.routines) if args.intra_coef else None

    # What a checkpoint holds; a resumed run starts where its checkpoint left off.
    # --budget-unit decisions: the budget, the schedule and --checkpoint-every count decisions.
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
    log = TrainingLog(writer, args, num_primitives, num_routines, global_step, decisions)
    log.counts.watch_interruptions(stop_rule)

    while (spent := budget_spent(args.budget_unit, global_step, decisions)) \
            < args.total_timesteps:
        iteration += 1
        if args.anneal_lr:
            frac = max(1.0 - spent / args.total_timesteps, 0.0)
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        for step in range(n):
            action = agent.decide(torch.as_tensor(next_obs, device=device)).cpu().numpy()
            rollout.actions[step], rollout.obs[step] = action, next_obs
            next_obs, reward, term, trunc, info = envs.step(action)
            store_step(rollout, step, args, max_len, reward, term, trunc, info)
            # Same-step autoreset: `final_obs` and `final_info` come when an episode ended.
            if "final_obs" in info and trunc.any():  # bootstrap a cut episode from V(last obs)
                rollout.final_values[step, trunc] = cut_episode_values(agent, info, trunc, device)
            ran = e if args.mode == "a2c" else int(rollout.lengths[step].sum())
            global_step += ran
            decisions += e
            if "final_obs" in info:
                log.episodes(info, global_step)
            # Rounded to the nearest vector step, and against the run's whole count, so that
            # U updates have seen U·N·num_envs primitive steps (about ± half a vector step).
            if steps_sized and rollout_filled(global_step, ran, iteration, n, e):
                break

        # The rollout's d decisions per env (n unless --rollout-unit steps ended it early).
        d = step + 1
        acts, rews, lens = rollout.actions[:d], rollout.step_rewards[:d], rollout.lengths[:d]
        log.rollout(acts, int(lens.sum()))
        rewards, discounts = decision_rewards(args, rews, lens, acts, num_primitives,
                                              rollout.a2c_discounts[:d])
        # The update's forward pass: log π(a_i|s_i), H and V(s_i) of the d·e decisions, with
        # their graph, and V of the states after the rollout, which bootstrap the returns.
        rollout.obs[d] = next_obs
        logprobs, entropies, values, bootstrap = agent.update_forward(rollout.obs[: d + 1],
                                                                      next_obs, acts)
        returns = decision_returns(rewards, discounts, rollout.terminated[:d],
                                   rollout.truncated[:d], rollout.final_values[:d], bootstrap)
        b_returns = torch.as_tensor(returns, dtype=torch.float32, device=device)
        advantages = b_returns - values.view(d, e)  # A_routine, [d, e]
        pg_loss = -(logprobs.view(d, e) * advantages.detach()).mean()
        v_loss = advantages.pow(2).mean()
        entropy_loss = entropies.view(d, e).mean()
        prim_loss, intra_loss = inner_state_losses(agent, args, rollout, d, next_obs, bootstrap,
                                                   max_len, device, routines, num_primitives)
        loss = pg_loss - args.ent_coef * entropy_loss \
            + args.vf_coef * critic_loss(v_loss, prim_loss, args.critic_loss, args.prim_coef)
        if args.intra_coef:
            loss = loss + args.intra_coef * intra_loss

        optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
        check_update(global_step, loss, grad_norm, parts={
            "value loss": v_loss, "policy loss": pg_loss, "primitive value loss": prim_loss,
            "entropy": entropy_loss})  # stop before a non-finite update is applied
        optimizer.step()

        log.update(global_step, decisions, iteration, optimizer.param_groups[0]["lr"], {
            "losses/value_loss": v_loss, "losses/prim_value_loss": prim_loss,
            "losses/policy_loss": pg_loss, "losses/entropy": entropy_loss,
            **({"losses/intra_loss": intra_loss} if args.intra_coef else {})})
        run.checkpoint_if_due(global_step=global_step, iteration=iteration, decisions=decisions)

    envs.close()
    evaluate_agent(run, agent, args, demo, library, device, global_step=global_step,
                   iteration=iteration, decisions=decisions)


if __name__ == "__main__":
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    routine_gym.register_envs()
    run_script(main, Args, renamed={"--routines": "--routine-library"})
