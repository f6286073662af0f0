"""`TrainingLog`: what an on-policy script with routines records as it trains (SPEC §5).

`rapl_a2c.py` and `rapl_ppo.py` keep the same record of a run, so their `main` holds the
algorithm only:

    charts/episodic_return, charts/episodic_length   each episode, as it ends (`episodes`)
    charts/learning_rate, losses/*, charts/SPS,       every --scalars-every updates and at the
    charts/decisions_per_second, counters/*,          last (`update`), with the primitive step
    routines/primitive_usage, routines/usage_k        count as TensorBoard's step
    a progress line on stdout                         every --log-every steps (decisions with
                                                      --budget-unit decisions) and at the end

`counters/*` are `routine_gym.plumbing.counters.Counters`'; `routines/*` are the shares of all the
run's decisions (since this process started) that chose each primitive action or routine.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from routine_gym.plumbing.counters import Counters, budget_progress, budget_spent, scalars_due
from routine_gym.plumbing.run import Every

__all__ = ["TrainingLog"]


class TrainingLog:
    """A training run's episode returns, per-update scalars and progress lines.

    Args:
        writer: the run's TensorBoard writer.
        args: the script's settings (`log_every`, `budget_unit`, `total_timesteps`,
            `scalars_every` are read).
        num_primitives: the primitive actions, choices `0 … num_primitives − 1`.
        num_routines: the routines, choices `num_primitives …` on.
        global_step, decisions: where the run starts (a resumed run: its checkpoint's counts);
            SPS and the progress lines count from there.
    """

    def __init__(self, writer: Any, args: Any, num_primitives: int, num_routines: int,
                 global_step: int, decisions: int) -> None:
        self.writer, self.args = writer, args
        self.num_primitives, self.num_routines = num_primitives, num_routines
        self.start_time, self.start_step, self.start_decisions = (time.time(), global_step,
                                                                  decisions)
        self.logs = Every(args.log_every,
                          start=budget_spent(args.budget_unit, global_step, decisions))
        self.routine_counts = np.zeros(num_primitives + num_routines, dtype=np.int64)
        self.counts = Counters(writer, num_primitives, num_routines)
        self.recent_returns: list[float] = []

    def episodes(self, info: dict[str, Any], global_step: int) -> None:
        """Write the return and length of each episode that ended at this vector step (the
        `final_info` of a same-step autoreset; nothing when none ended)."""
        final = info.get("final_info", {})
        if "episode" not in final:
            return
        for i in np.flatnonzero(final["_episode"]):
            ret, length = float(final["episode"]["r"][i]), int(final["episode"]["l"][i])
            self.recent_returns.append(ret)
            self.writer.add_scalar("charts/episodic_return", ret, global_step)
            self.writer.add_scalar("charts/episodic_length", length, global_step)

    def rollout(self, actions: np.ndarray, steps: int) -> None:
        """Count a rollout's decisions (`actions`, indices of the action space) and the
        primitive steps they ran."""
        chosen = np.bincount(actions.reshape(-1), minlength=len(self.routine_counts))
        self.routine_counts += chosen
        self.counts.add_counts(chosen, steps)

    def update(self, global_step: int, decisions: int, iteration: int, learning_rate: float,
               losses: Mapping[str, Any]) -> int:
        """After update number `iteration`: write `charts/learning_rate`, the `losses` (tag →
        a number or a 0-d tensor, read only when written), SPS, the counters and the routine
        shares when they are due, and the progress line when it is. Returns the budget spent."""
        args, writer = self.args, self.writer
        elapsed = max(time.time() - self.start_time, 1e-9)
        spent = budget_spent(args.budget_unit, global_step, decisions)
        last = spent >= args.total_timesteps
        sps = int((global_step - self.start_step) / elapsed)
        if scalars_due(iteration, args.scalars_every, last=last):
            writer.add_scalar("charts/learning_rate", learning_rate, global_step)
            for tag, value in losses.items():
                # `.item()`: a tensor's (or numpy number's) value, read only now it is written
                writer.add_scalar(tag, value.item() if hasattr(value, "item") else value,
                                  global_step)
            writer.add_scalar("charts/SPS", sps, global_step)
            writer.add_scalar("charts/decisions_per_second",
                              int((decisions - self.start_decisions) / elapsed), global_step)
            self.counts.log(global_step, decisions, iteration)
            if self.num_routines:
                usage = self.routine_counts / max(self.routine_counts.sum(), 1)
                writer.add_scalar("routines/primitive_usage", usage[: self.num_primitives].sum(),
                                  global_step)
                for k in range(self.num_routines):
                    writer.add_scalar(f"routines/usage_{k}", usage[self.num_primitives + k],
                                      global_step)
        if self.logs.due(spent) or last:
            returns = self.recent_returns
            mean_ret = f"{np.mean(returns[-20:]):.1f}" if returns else "n/a"
            usage = (self.routine_counts[self.num_primitives:].sum()
                     / max(self.routine_counts.sum(), 1))
            progress = budget_progress(args.budget_unit, global_step, decisions,
                                       args.total_timesteps)
            print(f"{progress}  SPS {sps:>5d}  return(last 20) {mean_ret:>8s}  "
                  f"episodes {len(returns):>5d}  routine use {usage:5.1%}", flush=True)
        return spent
