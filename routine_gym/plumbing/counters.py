"""What a run with temporally extended actions counts, so that it explains itself (SPEC §5).

A RAPL-A2C run and an A2C run at the same budget of primitive agent steps make different
numbers of decisions and of gradient updates: a decision that runs a routine of ℓ steps
advances the step counter by ℓ. Every script with temporally extended actions (`rapl_a2c.py`,
`option_critic.py`, `compile_a2c.py`) logs, every `--scalars-every` updates and at the last
(`scalars_due`), with the primitive step count as TensorBoard's step:

    counters/decisions            decisions so far (agent calls that chose an action, a routine
                                  or an option; all envs together)
    counters/updates              gradient updates so far
    counters/steps_per_decision   primitive steps per decision since the previous log
    counters/primitive_share      share of those decisions that chose a primitive action
    counters/share_k              share of those decisions that chose routine (option) k
    counters/interruptions        routines stopped early so far by the run's stop rule (with one,
                                  `--interrupt`; over the whole run, a resumed run counting
                                  on from its checkpoint)
    counters/interrupted_share    share of the routine decisions since the previous log that
                                  were stopped early

and `charts/episodic_length` per episode, as CleanRL does. `--budget-unit decisions` makes
`--total-timesteps`, the learning-rate schedule and `--checkpoint-every` count decisions
instead of primitive steps (`budget_spent`). The sweep reads these tags back into each run's
`result.json` (`routine_gym.experiments.run_counters`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["COUNTER_TAGS", "Counters", "budget_progress", "budget_spent", "rollout_filled",
           "scalars_due"]

#: The tags `Counters.log` writes (the per-routine shares are `counters/share_{k}`).
COUNTER_TAGS = ("counters/decisions", "counters/updates", "counters/steps_per_decision",
                "counters/primitive_share")


def scalars_due(update: int, every: int, last: bool) -> bool:
    """Whether update number `update` (from 1) writes its per-update scalars: every `every`-th
    update (`--scalars-every`) and the run's last one.

    The scripts logged a dozen scalars after every update: on MinAtar, ~375 events a second,
    about 2 % of a run even with a compiled event writer. SB3's A2C logs every 100 updates.

    Example:
        >>> [u for u in range(1, 251) if scalars_due(u, 100, last=u == 250)]
        [100, 200, 250]
        >>> [u for u in range(1, 4) if scalars_due(u, 1, last=False)]
        [1, 2, 3]
    """
    return last or update % every == 0


def budget_spent(unit: str, global_step: int, decisions: int) -> int:
    """What `--total-timesteps` counts: primitive agent steps, or decisions.

    Example:
        >>> budget_spent("steps", 120, 80), budget_spent("decisions", 120, 80)
        (120, 80)
    """
    if unit == "steps":
        return global_step
    if unit == "decisions":
        return decisions
    raise ValueError(f"unknown budget unit {unit!r} (steps or decisions)")


def rollout_filled(global_step: int, ran: int, update: int, num_steps: int,
                   num_envs: int) -> bool:
    """Whether a rollout sized in primitive steps (`--rollout-unit steps`) ends after the
    vector step that just ran `ran` primitive steps (all envs together), bringing the run's
    count to `global_step`, in the rollout of update number `update` (from 1).

    The rollout ends at the vector step nearest to the run's target `T = update · N · E`
    (N `--num-steps`, E `--num-envs`), guessing that the next vector step would run as many
    steps as this one (`ran`): it ends once stopping here is no further from T than going on,

        T − global_step ≤ global_step + ran − T   ⟺   global_step + ran / 2 ≥ T.

    The target counts the whole run, not this rollout, so a rollout that ran over leaves the
    next one less to run: U updates have seen U·N·E primitive steps give or take about half
    a vector step (less than one), however large U, as many as U updates of A2C or PPO,
    whose rollouts hold N·E steps.

    Example:
        >>> # N = 5, E = 4: T = 20 for the first update. At 15 steps after a vector step of 6,
        >>> # 15 + 3 < 20 (the next step, if of 6, ends at 21: nearer); at 16 after one of 8,
        >>> # 16 + 4 = 20 (a tie ends it).
        >>> rollout_filled(15, 6, 1, 5, 4), rollout_filled(16, 8, 1, 5, 4)
        (False, True)
        >>> # The first rollout ran over, to 22; the second (T = 40) ends at 38, 16 steps on.
        >>> rollout_filled(34, 4, 2, 5, 4), rollout_filled(38, 4, 2, 5, 4)
        (False, True)
    """
    return global_step + ran / 2 >= update * num_steps * num_envs


def budget_progress(unit: str, global_step: int, decisions: int, total: int) -> str:
    """The start of a progress line: where the run is in its budget (the sweep reads
    `step N/` or `decision N/` from it).

    Example:
        >>> budget_progress("steps", 1200, 800, 5000)
        'step      1,200/5,000'
        >>> budget_progress("decisions", 1200, 800, 5000)
        'decision        800/5,000  step 1,200'
    """
    if unit == "decisions":
        return f"decision {decisions:>10,d}/{total:,d}  step {global_step:,d}"
    return f"step {global_step:>10,d}/{total:,d}"


class Counters:
    """The decisions a run made since its last `log`, logged with its totals (every
    `--scalars-every` updates).

    Args:
        writer: the run's TensorBoard writer.
        num_primitives: the primitive actions, choices `0 … num_primitives − 1`.
        num_extended: the routines (options), choices `num_primitives …` on.

    Example:
        >>> counts = Counters(None, num_primitives=2, num_extended=1)
        >>> counts.add(np.array([0, 2, 2, 1]), steps=1 + 3 + 3 + 1)
        >>> counts.window()
        {'steps_per_decision': 2.0, 'primitive_share': 0.5, 'shares': [0.5]}
    """

    def __init__(self, writer: Any, num_primitives: int, num_extended: int) -> None:
        self.writer = writer
        self.num_primitives = int(num_primitives)
        self.num_extended = int(num_extended)
        self._choices = np.zeros(self.num_primitives + self.num_extended, dtype=np.int64)
        self._steps = 0
        self._stop_rule: Any = None
        self._stops_logged = 0

    def watch_interruptions(self, stop_rule: Any) -> None:
        """Log `counters/interruptions` and `counters/interrupted_share` from `stop_rule`'s
        count of the routines it stopped (`routine_gym.interruption.PolicyStopRule`); None:
        nothing to log."""
        self._stop_rule = stop_rule
        self._stops_logged = stop_rule.interruptions if stop_rule is not None else 0

    def add(self, choices: np.ndarray, steps: int) -> None:
        """Count decisions (`choices`, each an index of the action space) and the primitive
        steps that ran since the last call."""
        self.add_counts(np.bincount(np.asarray(choices, dtype=np.int64),
                                    minlength=len(self._choices)), steps)

    def add_counts(self, counts: np.ndarray, steps: int) -> None:
        """Count decisions already counted per choice (`counts[c]`: how many chose `c`, e.g.
        `np.bincount` of a rollout's actions) and the primitive steps they ran: the same as
        `add` with those choices.

        Example:
            >>> counts = Counters(None, num_primitives=2, num_extended=1)
            >>> counts.add_counts(np.bincount([0, 2, 2, 1], minlength=3), steps=1 + 3 + 3 + 1)
            >>> counts.window()
            {'steps_per_decision': 2.0, 'primitive_share': 0.5, 'shares': [0.5]}
        """
        self._choices += counts
        self._steps += int(steps)

    def add_steps(self, steps: int) -> None:
        """Count primitive steps that ran with no new decision (an option that went on)."""
        self._steps += int(steps)

    def window(self) -> dict[str, Any]:
        """Steps per decision and the shares of the decisions since the last `log`."""
        made = int(self._choices.sum())
        shares = self._choices / made if made else np.zeros(len(self._choices))
        return {"steps_per_decision": self._steps / made if made else float("nan"),
                "primitive_share": float(shares[: self.num_primitives].sum()),
                "shares": [float(s) for s in shares[self.num_primitives:]]}

    def log(self, global_step: int, decisions: int, updates: int) -> None:
        """Write the totals and the window's rates at `global_step`, and start a new window."""
        window = self.window()
        w = self.writer
        w.add_scalar("counters/decisions", decisions, global_step)
        w.add_scalar("counters/updates", updates, global_step)
        if self._choices.sum():
            w.add_scalar("counters/steps_per_decision", window["steps_per_decision"],
                         global_step)
            w.add_scalar("counters/primitive_share", window["primitive_share"], global_step)
            for k, share in enumerate(window["shares"]):
                w.add_scalar(f"counters/share_{k}", share, global_step)
        if self._stop_rule is not None:
            stops = self._stop_rule.interruptions
            w.add_scalar("counters/interruptions", stops, global_step)
            calls = int(self._choices[self.num_primitives:].sum())
            if calls:
                w.add_scalar("counters/interrupted_share", (stops - self._stops_logged) / calls,
                             global_step)
            self._stops_logged = stops
        self._choices[:] = 0
        self._steps = 0
