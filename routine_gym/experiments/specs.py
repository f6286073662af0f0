"""The runs of an experiment and the budgets they are sized by (SPEC §6, §8).

An experiment (`routine_gym.experiments.experiment.Experiment`) adds its runs to a `Builder` at a
budget. A run is one process of a script in `algos/` with its flags
(`RunSpec`); its key is a hash of the script and the flags, so the same run in two experiments
(A2C on Breakout is in `rl`, `curves` and `scalability`) is one run, trained once. Each entry of
an experiment adds the labels the report groups by (method, env, seed, variant).

Budgets:

- `smoke`: seconds a run, one seed, one game (the tests).
- `cpu`: what a 2-core machine finishes in hours: MinAtar's five games (and MiniQbert for
  imitation and RL, CoinRun for its own experiment) at 10^6 agent steps, 3 seeds.
- `paper`: the paper's settings: 10^7 agent steps, 5 seeds, the authors' 30 Atari games, each
  game's demo from an A2C expert trained first (the shipped demo where there is one).
- `long`: the rl experiment alone at the paper's 10^7 agent steps on MinAtar's five games,
  3 seeds, with RAPL-A2C as the authors' code has it beside A2C and RAPL-A2C (14.5 run-hours
  as measured on a 2-core CPU, so a checkpoint every tenth of a run); the other experiments
  have no runs there.

The rl experiment also runs PPO, RAPL-PPO and MacroAction-PPO (`algos/rapl_ppo.py`, issue 29)
where a budget opts in (`rl_ppo`: smoke and cpu): added beside the A2C runs, whose keys and
flags stay as they were, so a sweep folder from before runs only the PPO runs.

Demos: a game with a shipped demo (`routine_gym.demo.DEMO_SUITE`, MiniQbert's scripted one) uses
it; any other game first trains an A2C expert with `--record-demo` (a run of role `expert`) and
every run of that game reads the demo it recorded. The ablation's ID variant always reads a
demo recorded by an expert trained a tenth as long as the one behind the full model's demo.
A flag value `@run:KEY/FILE` names a file in the folder of run KEY, `@self/FILE` one in the
run's own folder; the sweep resolves both, and they keep keys independent of `--out`.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "BUDGETS",
    "COINRUN",
    "MINATAR",
    "PAPER_GAMES",
    "Budget",
    "Builder",
    "Entry",
    "RunSpec",
    "expert",
    "has_shipped_demo",
    "shipped_demo_has_routine",
]

MINATAR = tuple(f"MinAtar/{game}-v1" for game in
                ("Asterix", "Breakout", "Freeway", "Seaquest", "SpaceInvaders"))
#: The authors' 30 Atari games (their `launch.py`, SPEC §8).
PAPER_GAMES = tuple(f"ALE/{game}-v5" for game in (
    "Amidar Hero Alien Qbert MsPacman Atlantis BankHeist BattleZone BeamRider Bowling Boxing "
    "Breakout Centipede Seaquest DemonAttack DoubleDunk Freeway Gopher Gravitar Pitfall "
    "PrivateEye Pong RoadRunner Robotank StarGunner Phoenix Frostbite Jamesbond TimePilot "
    "WizardOfWor").split())
COINRUN = "procgen/CoinRun-v0"
#: Envs whose demo ships with routine-gym (besides `DEMO_SUITE`).
BUILT_IN_DEMOS = ("MiniQbert-v0",)


@dataclass(frozen=True)
class RunSpec:
    """One process of `algos/{script}.py` with `flags` (without the sweep's own: run folder,
    checkpoints, threads, CUDA). `steps` is its budget in agent steps (progress and ETA);
    `needs` are keys of runs that must finish first.

    `pinned` are flags the command line gets but the key leaves out: what a script's default
    was when runs of these flags were first made, named now that the default changed (the
    `first` demo set's file as `--demo` where the current demo replaced it), so the committed
    runs keep their keys and the sweep still reruns them as they were."""

    script: str
    flags: tuple[tuple[str, Any], ...]
    steps: int
    needs: tuple[str, ...] = ()
    pinned: tuple[tuple[str, Any], ...] = ()
    #: Flags decided from other runs' results when the sweep starts it
    #: (`routine_gym.experiments.derived`): `(rule, params)` pairs; their runs are in `needs`.
    derived: tuple[tuple[str, Any], ...] = ()

    @property
    def key(self) -> str:
        """12 hex digits of the SHA-256 of the script and its flags (and its derived flags'
        rules, where it has any)."""
        described: dict[str, Any] = {"script": self.script, "flags": dict(self.flags)}
        if self.derived:
            described["derived"] = _jsonable(self.derived)
        blob = json.dumps(described, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def config(self) -> dict[str, Any]:
        config = {"key": self.key, "script": self.script, "flags": dict(self.flags),
                  "needs": list(self.needs), "steps": self.steps}
        if self.pinned:
            config["pinned"] = dict(self.pinned)
        if self.derived:
            config["derived"] = _jsonable(self.derived)
        return config


def _jsonable(value: Any) -> Any:
    """Tuples as lists, all the way down (a config's JSON, and the key's)."""
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    return value


@dataclass(frozen=True)
class Entry:
    """A run of an experiment and the labels the report groups it by."""

    run: RunSpec
    method: str
    env_id: str
    seed: int
    variant: dict[str, Any] = field(default_factory=dict)
    role: str = "main"

    def manifest(self) -> dict[str, Any]:
        return {"key": self.run.key, "script": self.run.script, "method": self.method,
                "env_id": self.env_id, "seed": self.seed, "variant": dict(self.variant),
                "role": self.role, "steps": self.run.steps}


@dataclass(frozen=True)
class Budget:
    """The sizes of one budget; every experiment reads the fields it needs."""

    name: str
    description: str
    seeds: int
    games: tuple[str, ...]  # the RL experiments (rl adds MiniQbert where listed)
    rl_games: tuple[str, ...]
    imitation_games: tuple[str, ...]
    steps: int  # agent steps of an RL run
    coinrun_steps: int
    sqil_steps: int
    gail_steps: int
    bc_steps: int  # gradient steps
    expert_steps: int  # an expert for a game without a shipped demo
    shipped_expert_steps: int  # what the shipped demos' experts trained for (ID: a tenth)
    eval_episodes: int
    scalability_k: tuple[int, ...]
    scalability_lengths: tuple[int, ...]
    demo_episodes: int = 10
    num_envs: int | None = None  # None: each script's default (16)
    compile_flags: tuple[tuple[str, Any], ...] = ()  # CompILE's own training, when not default
    ablation_games: tuple[str, ...] | None = None  # None: `games`
    checkpoints: int = 5  # a run saves a checkpoint every `steps // checkpoints` steps
    experiments: tuple[str, ...] | None = None  # the experiments with runs here; None: all
    rl_authors: bool = False  # rl adds RAPL-A2C as the authors' code has it (diagnosis's run)
    rl_ppo: bool = False  # rl adds PPO, RAPL-PPO and MacroAction-PPO (`rapl_ppo.py`)
    #: The shipped demos (`routine_gym.demo.DEMO_SETS`) its runs mine and its scores are
    #: normalised by: `first` for the budgets whose sweeps were made with them.
    demo_set: str = "current"
    #: Episodes of the uniformly random policy behind a demo-normalised score.
    reference_episodes: int = 10
    #: `--seed-stride` of the A2C and PPO runs (`routine_gym.plumbing.seeds`; 1: the old seeds).
    seed_stride: int = 1
    #: The `--seed` of the tune runs (disjoint from the evaluation seeds 1..`seeds`); empty: the
    #: budget has no tuning, and its runs keep the scripts' learning rates and schedules.
    tune_seeds: tuple[int, ...] = ()
    #: How many points of each family's grid (`TUNE_GRIDS`, from the first) it tunes over:
    #: all but in the tests' budget.
    tune_points: int | None = None
    #: The families (`"A2C"`, `"PPO"`) whose leave-one-out arms (all mechanisms but one)
    #: equal-frames adds: a diagnosis of which mechanisms carry the combination (issue 49).
    leave_one_out: tuple[str, ...] = ()

    def checkpoint_every(self, steps: int) -> int:
        """The `--checkpoint-every` of a run of `steps`: a `checkpoints`-th of it (at least 1).

        Example:
            >>> BUDGETS["cpu"].checkpoint_every(10**6), BUDGETS["long"].checkpoint_every(10**7)
            (200000, 1000000)
        """
        return max(steps // self.checkpoints, 1)

    def has(self, experiment: str) -> bool:
        """Whether `experiment` has runs at this budget (tune and equal-frames: only where the
        budget has tuning seeds)."""
        if experiment in ("tune", "equal-frames") and not self.tune_seeds:
            return False
        return self.experiments is None or experiment in self.experiments


BUDGETS: dict[str, Budget] = {
    "smoke": Budget(
        name="smoke", description="seconds a run, 1 seed, 1 game (the tests)", seeds=1,
        games=("MinAtar/Breakout-v1",), rl_games=("MinAtar/Breakout-v1",),
        imitation_games=("MiniQbert-v0",), steps=1_000, coinrun_steps=160, sqil_steps=500,
        gail_steps=512, bc_steps=50, expert_steps=1_000, shipped_expert_steps=5_000,
        eval_episodes=1, scalability_k=(1, 3), scalability_lengths=(2, 4), demo_episodes=1,
        num_envs=4, compile_flags=(("compile-iterations", 20), ("compile-option-steps", 20)),
        # Freeway's episodes last 2,500 steps: even a barely trained expert's demo has routines.
        ablation_games=("MinAtar/Freeway-v1",), rl_ppo=True),
    "cpu": Budget(
        name="cpu",
        description="MinAtar's five games (and MiniQbert, CoinRun) at 10^6 agent steps, "
                    "3 seeds: hours on a 2-core CPU",
        seeds=3, games=MINATAR, rl_games=(*MINATAR, "MiniQbert-v0"),
        imitation_games=(*MINATAR, "MiniQbert-v0"), steps=1_000_000, coinrun_steps=500_000,
        sqil_steps=100_000, gail_steps=500_000, bc_steps=10_000, expert_steps=5_000_000,
        shipped_expert_steps=5_000_000, eval_episodes=30, scalability_k=(1, 3, 6),
        scalability_lengths=(2, 5), rl_ppo=True, demo_set="first"),
    "paper": Budget(
        name="paper",
        description="the paper's settings: 30 Atari games, 10^7 agent steps, 5 seeds "
                    "(a cluster)",
        seeds=5, games=PAPER_GAMES, rl_games=PAPER_GAMES, imitation_games=PAPER_GAMES,
        steps=10_000_000, coinrun_steps=10_000_000, sqil_steps=1_000_000,
        gail_steps=10_000_000, bc_steps=100_000, expert_steps=10_000_000,
        shipped_expert_steps=10_000_000, eval_episodes=100, scalability_k=(1, 3, 5, 10),
        scalability_lengths=(2, 4, 6, 8)),
    # The rl experiment's runs of the cpu budget at the paper's steps (the same flags but the
    # steps and the checkpoint interval); the sizes only other experiments read are the cpu
    # budget's, so a field read by mistake is a sane one.
    "long": Budget(
        name="long",
        description="the paper's 10^7 agent steps on MinAtar's five games, rl only (with "
                    "RAPL-A2C as the authors' code), 3 seeds: 15 run-hours, 8 h on a 2-core CPU",
        seeds=3, games=MINATAR, rl_games=MINATAR, imitation_games=MINATAR,
        steps=10_000_000, coinrun_steps=500_000, sqil_steps=100_000, gail_steps=500_000,
        bc_steps=10_000, expert_steps=5_000_000, shipped_expert_steps=5_000_000,
        eval_episodes=30, scalability_k=(1, 3, 6), scalability_lengths=(2, 5), checkpoints=10,
        experiments=("rl",), rl_authors=True, demo_set="first"),
    # The fair protocol's tests: two grid points (the default learning rate, annealed and
    # constant), one tuning seed, two evaluation seeds (Welch's test needs two a side).
    "smoke-fair": Budget(
        name="smoke-fair", description="the fair protocol in seconds a run (the tests)",
        seeds=2, games=("MinAtar/Breakout-v1",), rl_games=("MinAtar/Breakout-v1",),
        imitation_games=("MiniQbert-v0",), steps=1_000, coinrun_steps=160, sqil_steps=500,
        gail_steps=512, bc_steps=50, expert_steps=1_000, shipped_expert_steps=5_000,
        eval_episodes=1, scalability_k=(1, 3), scalability_lengths=(2, 4), demo_episodes=1,
        num_envs=4, experiments=("tune", "rl", "diagnosis", "equal-frames"), reference_episodes=100,
        seed_stride=1000, tune_seeds=(101,), tune_points=2, leave_one_out=("A2C",)),
    # The fair protocol (issue 47): the current demos (10M-step experts), every method's
    # learning rate and schedule tuned on seeds of its own (the tune experiment), 5 seeds whose
    # env seeds do not overlap, references from 100 random episodes.
    "fair": Budget(
        name="fair",
        description="the fair protocol at 10^6 agent steps: MinAtar's five games, tuned "
                    "learning rates and schedules, 5 independent seeds",
        seeds=5, games=MINATAR, rl_games=MINATAR, imitation_games=MINATAR,
        steps=1_000_000, coinrun_steps=500_000, sqil_steps=100_000, gail_steps=500_000,
        bc_steps=10_000, expert_steps=10_000_000, shipped_expert_steps=10_000_000,
        eval_episodes=30, scalability_k=(1, 3, 6), scalability_lengths=(2, 5), rl_ppo=True,
        experiments=("tune", "rl", "diagnosis", "equal-frames"), reference_episodes=100,
        seed_stride=1000, tune_seeds=(101, 102), leave_one_out=("A2C", "PPO")),
    "fair-long": Budget(
        name="fair-long",
        description="the fair protocol at the paper's 10^7 agent steps: MinAtar's five games, "
                    "A2C and RAPL-A2C tuned at 10^7 (the authors' code at A2C's constant rate), "
                    "5 independent seeds",
        seeds=5, games=MINATAR, rl_games=MINATAR, imitation_games=MINATAR,
        steps=10_000_000, coinrun_steps=500_000, sqil_steps=100_000, gail_steps=500_000,
        bc_steps=10_000, expert_steps=10_000_000, shipped_expert_steps=10_000_000,
        eval_episodes=30, scalability_k=(1, 3, 6), scalability_lengths=(2, 5), checkpoints=10,
        experiments=("tune", "rl", "equal-frames"), rl_authors=True, reference_episodes=100,
        seed_stride=1000, tune_seeds=(101, 102)),
}

#: The tuning grid of each method family (`--learning-rate`, `--anneal-lr`), the scripts'
#: default first (a tie keeps it): the default learning rate, half, twice, four and eight
#: times it, each annealed to 0 and constant. Why these: the schedule is what the first
#: protocol's results turned on (A2C at 10^6 on Asterix: 3.2 annealed, 10.1 constant); factors
#: of 2 bracket each default (A2C's RMSprop 7e-4, as in CleanRL and SB3; PPO's Adam 5e-4 of
#: gymnax-blines' MinAtar configs). The top grew twice, for every method alike, by the rule of
#: docs/fair-protocol.md: `bench/probe_lr_cap.py` runs twice the top, and where that beats the
#: grid in more than 4 of 20 method-game cells, it joins the grid. The grid's first form stopped
#: at twice (the probe at 4x won 14 of 20 cells, `bench/results/lr_cap_probe.md`), its second at
#: four times (the probe at 8x won 9 of 20, `bench/results/lr_cap_probe_8x.md`); ten points. The
#: probe at 16x won 4 of 20 (`bench/results/lr_cap_probe_16x.md`): the grid stops at 8x.
TUNE_FACTORS = (1.0, 0.5, 2.0, 4.0, 8.0)
TUNE_GRIDS: dict[str, tuple[tuple[tuple[str, Any], ...], ...]] = {
    family: tuple((("learning-rate", base * factor), ("anneal-lr", anneal))
                  for factor in TUNE_FACTORS for anneal in (True, False))
    for family, base in (("a2c", 7e-4), ("ppo", 5e-4))}
#: A grid point: its flags, `(flag, value)` pairs.
Point = tuple[tuple[str, Any], ...]
#: Each tuned method's script mode and grid family.
TUNED_METHODS: dict[str, tuple[str, str]] = {
    "A2C": ("rapl_a2c", "a2c"), "RAPL-A2C": ("rapl_a2c", "a2c"),
    "MacroAction": ("rapl_a2c", "a2c"), "PPO": ("rapl_ppo", "ppo"),
    "RAPL-PPO": ("rapl_ppo", "ppo"), "MacroAction-PPO": ("rapl_ppo", "ppo")}


def has_shipped_demo(env_id: str) -> bool:
    """Whether `env_id`'s demo ships with routine-gym (no expert needs training for it)."""
    from routine_gym.demo import DEMO_SUITE

    return env_id in DEMO_SUITE or env_id in BUILT_IN_DEMOS


@functools.cache
def shipped_demo_has_routine(env_id: str, min_length: int, demo_set: str = "current") -> bool:
    """Whether the miner finds a routine of ≥ `min_length` actions in `env_id`'s shipped demo
    of `demo_set` (true for a game without one: its expert's demo is recorded by the sweep, and
    a run that finds none fails naming the reason)."""
    import warnings

    from routine_gym.demo import shipped_demo_path
    from routine_gym.plumbing.loading import load_demo, load_routines

    if not has_shipped_demo(env_id):
        return True
    demo, path = load_demo(env_id, shipped_demo_path(env_id, demo_set),
                           purpose="the scalability experiment")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_routines(env_id, 1, demo=demo, min_length=min_length,
                             source={"path": path}) is not None


#: Scripts that step several envs (`--num-envs`), and BC's budget flag.
VECTOR_SCRIPTS = ("rapl_a2c", "rapl_ppo", "option_critic", "compile_a2c", "gail")
STEPS_FLAG = {"bc": "gradient-steps"}


#: The reward scale the A2C-family scripts learn with on a game whose rewards are large
#: (`--reward-scale`; every method of an experiment the same): MiniQbert's 25 and 100 points
#: swamp the value loss at 1 (`bench/results/learning_miniqbert_scaled.md`).
REWARD_SCALES = {"MiniQbert-v0": 0.01}
#: The scripts with `--reward-scale`.
SCALED_SCRIPTS = ("rapl_a2c", "rapl_ppo", "option_critic", "compile_a2c")


#: The scripts with `--seed-stride`.
STRIDED_SCRIPTS = ("rapl_a2c", "rapl_ppo")


def _common(budget: Budget, script: str, env_id: str, seed: int,
            steps: int) -> list[tuple[str, Any]]:
    flags: list[tuple[str, Any]] = [("env-id", env_id), ("seed", seed),
                                    (STEPS_FLAG.get(script, "total-timesteps"), steps),
                                    ("eval-episodes", budget.eval_episodes)]
    if budget.seed_stride != 1 and script in STRIDED_SCRIPTS:
        flags.append(("seed-stride", budget.seed_stride))
    if env_id in REWARD_SCALES and script in SCALED_SCRIPTS:
        flags.append(("reward-scale", REWARD_SCALES[env_id]))
    if budget.num_envs is not None and script in VECTOR_SCRIPTS:
        flags.append(("num-envs", budget.num_envs))
    return flags


def expert(budget: Budget, env_id: str, steps: int) -> Entry:
    """An A2C expert of `env_id` trained for `steps` that records a demo (`demo.npz` in its
    folder) of the best of the budget's demo episodes."""
    flags = [*_common(budget, "rapl_a2c", env_id, 1, steps), ("mode", "a2c"),
             ("record-demo", "@self/demo.npz"), ("demo-episodes", budget.demo_episodes),
             ("checkpoint-every", budget.checkpoint_every(steps))]
    return Entry(RunSpec("rapl_a2c", tuple(flags), steps), "A2C expert", env_id, 1,
                 {"expert_steps": steps}, role="expert")


class Builder:
    """Collects an experiment's entries at a budget; the experts behind demos are added once
    each. An experiment's `add_runs` calls `run` (any script), `a2c` (`rapl_a2c.py`) or `ppo`
    (`rapl_ppo.py`)."""

    def __init__(self, budget: Budget) -> None:
        self.budget = budget
        self.entries: dict[tuple[str, str, int, str], Entry] = {}
        #: Settings of the experiment that have no runs, and why (the manifest lists them).
        self.left_out: list[dict[str, Any]] = []

    def add(self, entry: Entry) -> Entry:
        label = (entry.run.key, entry.method, entry.seed, json.dumps(entry.variant, sort_keys=True))
        self.entries.setdefault(label, entry)
        return entry

    def demo(self, env_id: str, expert_steps: int | None = None) -> tuple[list, tuple[str, ...]]:
        """The `--demo` flag and the needed run for `env_id`: none for a shipped demo (the
        scripts' default; `pinned_demo` names an older set's), else an expert trained for
        `expert_steps` (the budget's)."""
        if expert_steps is None and has_shipped_demo(env_id):
            return [], ()
        steps = expert_steps if expert_steps is not None else self.budget.expert_steps
        run = self.add(expert(self.budget, env_id, steps)).run
        return [("demo", f"@run:{run.key}/demo.npz")], (run.key,)

    def run(self, script: str, method: str, env_id: str, seed: int, steps: int,
            extra: Sequence[tuple[str, Any]] = (), variant: dict | None = None,
            demo: bool = True, expert_steps: int | None = None,
            derived: tuple[tuple[str, Any], ...] = (), seed_flag: int | None = None,
            role: str = "main") -> Entry:
        """A run of `script`; `seed` labels it in the report, `seed_flag` (default `seed`)
        is its `--seed`; `derived` are flags decided from other runs (`RunSpec.derived`)."""
        from routine_gym.experiments.derived import derived_keys

        flags = _common(self.budget, script, env_id, seed if seed_flag is None else seed_flag,
                        steps) + list(extra)
        needs: tuple[str, ...] = derived_keys(derived)
        pinned: tuple[tuple[str, Any], ...] = ()
        if demo:
            demo_flags, demo_needs = self.demo(env_id, expert_steps)
            needs += demo_needs
            flags += demo_flags
            if not demo_flags:
                pinned = self.pinned_demo(env_id)
        flags.append(("checkpoint-every", self.budget.checkpoint_every(steps)))
        spec = RunSpec(script, tuple(flags), steps, needs, pinned, derived)
        return self.add(Entry(spec, method, env_id, seed, dict(variant or {}), role))

    def tune_runs(self, method: str, env_id: str, role: str = "tune",
                  steps: int | None = None) -> list[tuple[Point, list[Entry]]]:
        """The tune runs of `method` on `env_id`: every point of its family's grid
        (`TUNE_GRIDS`) on each of the budget's tuning seeds (labelled 1, 2, …), as
        `[(point, entries)]` in grid order; `role` is theirs in the experiment adding them."""
        script, family = TUNED_METHODS[method]
        add = self.a2c if script == "rapl_a2c" else self.ppo
        points = []
        for point in TUNE_GRIDS[family][: self.budget.tune_points]:
            variant = {"learning_rate": point[0][1], "anneal_lr": point[1][1]}
            entries = [add(method, env_id, i, variant, steps=steps, extra=point, tune=False,
                           seed_flag=seed_flag, role=role)
                       for i, seed_flag in enumerate(self.budget.tune_seeds, start=1)]
            points.append((point, entries))
        return points

    def tuned(self, method: str, env_id: str, steps: int | None = None,
              constant_lr: bool = False) -> tuple[tuple[str, Any], ...]:
        """The derived flags of a run of `method` on `env_id` at the budget's tuned settings:
        the grid point its tune runs score best with (`constant_lr`: the best constant-lr
        point, for an arm whose schedule is fixed). Adds the tune runs (role `tune`)."""
        points = self.tune_runs(method, env_id, steps=steps)
        if constant_lr:
            points = [(p, es) for p, es in points if dict(p)["anneal-lr"] is False]
        return (("tuned", tuple((p, tuple(e.run.key for e in es)) for p, es in points)),)

    def pinned_demo(self, env_id: str) -> tuple[tuple[str, Any], ...]:
        """`(("demo", "@demos/first/…"),)` where the budget's demo set holds its own file for
        `env_id` (the run was made when that file was the default), else nothing."""
        from routine_gym.demo import demo_set_file

        relative = demo_set_file(env_id, self.budget.demo_set)
        return (("demo", f"@demos/{relative}"),) if relative is not None else ()

    def a2c(self, method: str, env_id: str, seed: int, variant: dict | None = None,
            k: int = 3, min_length: int = 2, proposer: str = "full",
            expert_steps: int | None = None, steps: int | None = None,
            extra: Sequence[tuple[str, Any]] = (), tune: bool = True,
            derived: tuple[tuple[str, Any], ...] = (), seed_flag: int | None = None,
            role: str = "main", tuned_as: str | None = None, constant_lr: bool = False
            ) -> Entry:
        """A `rapl_a2c.py` run; flags at their defaults are left out, so the same run made by
        two experiments has one key. On a budget with tuning (`tune_seeds`) it learns with the
        tuned settings of `tuned_as` (default `method`; `constant_lr`: the best constant-lr
        point) unless `tune` is False (the tune runs themselves)."""
        mode = {"A2C": "a2c", "RAPL-A2C": "rapl", "MacroAction": "macro"}[method]
        flags: list[tuple[str, Any]] = [("mode", mode), *extra]
        if k != 3:
            flags.append(("num-routines", k))
        if min_length != 2:
            flags.append(("min-routine-length", min_length))
        if proposer != "full":
            flags.append(("proposer", proposer))
        steps = steps if steps is not None else self.budget.steps
        if tune and self.budget.tune_seeds:
            derived = self.tuned(tuned_as or method, env_id, steps, constant_lr) + derived
        return self.run("rapl_a2c", method, env_id, seed, steps, flags, variant,
                        demo=mode != "a2c", expert_steps=expert_steps, derived=derived,
                        seed_flag=seed_flag, role=role)

    def ppo(self, method: str, env_id: str, seed: int, variant: dict | None = None,
            steps: int | None = None, extra: Sequence[tuple[str, Any]] = (),
            tune: bool = True, seed_flag: int | None = None, role: str = "main") -> Entry:
        """A `rapl_ppo.py` run of `method` (PPO, RAPL-PPO or MacroAction-PPO), its demo handled
        as `a2c`'s (RAPL-PPO and MacroAction-PPO mine the same demo as RAPL-A2C: shipped, or
        recorded by the same expert); the env family's PPO defaults, so flags left unset."""
        mode = {"PPO": "ppo", "RAPL-PPO": "rapl", "MacroAction-PPO": "macro"}[method]
        flags: list[tuple[str, Any]] = [("mode", mode), *extra]
        if mode == "rapl":
            # Named although it is the default: the script trained the states inside routines
            # in every epoch before 2026-12-05, and those runs (the same flags without it) must
            # not count as these.
            flags.append(("prim-epochs", 1))
        steps = steps if steps is not None else self.budget.steps
        derived = self.tuned(method, env_id, steps) if tune and self.budget.tune_seeds else ()
        return self.run("rapl_ppo", method, env_id, seed, steps, flags, variant,
                        demo=mode != "ppo", derived=derived, seed_flag=seed_flag, role=role)

    def seeds(self) -> range:
        return range(1, self.budget.seeds + 1)
