"""`routine_gym.plumbing.training_log.TrainingLog`: what rapl_a2c.py and rapl_ppo.py record as
they train (episode returns, per-update scalars every --scalars-every updates, progress lines),
on hand-worked numbers."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

from routine_gym.plumbing.training_log import TrainingLog


class Writer:
    """A TensorBoard writer that keeps what it is given."""

    def __init__(self) -> None:
        self.scalars: list[tuple[str, float, int]] = []

    def add_scalar(self, tag, value, step):
        self.scalars.append((tag, value, step))

    def tags(self, step):
        return {tag: value for tag, value, s in self.scalars if s == step}


def _log(**settings):
    args = SimpleNamespace(**{"log_every": 100, "budget_unit": "steps", "total_timesteps": 300,
                              "scalars_every": 2, **settings})
    writer = Writer()
    # 2 primitive actions and 1 routine.
    return writer, TrainingLog(writer, args, num_primitives=2, num_routines=1, global_step=0,
                               decisions=0)


def test_an_episode_that_ended_is_written_with_its_return_and_length():
    writer, log = _log()
    log.episodes({}, 10)  # no episode ended
    info = {"final_info": {"episode": {"r": np.array([1.5, 9.0]), "l": np.array([3, 7])},
                           "_episode": np.array([False, True])}}
    log.episodes(info, 12)
    assert writer.scalars == [("charts/episodic_return", 9.0, 12),
                              ("charts/episodic_length", 7, 12)]
    assert log.recent_returns == [9.0]


def test_scalars_come_every_scalars_every_updates_and_at_the_last(capsys):
    writer, log = _log()
    # One rollout: decisions 0, 2, 2, 1 (two routine calls of 3 steps): 8 steps, 4 decisions.
    log.rollout(np.array([[0, 2], [2, 1]]), steps=8)
    losses = {"losses/value_loss": torch.tensor(0.25), "losses/clipfrac": np.float64(0.5)}
    assert log.update(80, 40, 1, 1e-3, losses) == 80  # update 1: not due, under --log-every
    assert writer.scalars == [] and capsys.readouterr().out == ""
    log.update(160, 80, 2, 1e-3, losses)  # update 2: due, and past step 100: a progress line
    written = writer.tags(160)
    assert written["charts/learning_rate"] == 1e-3
    assert written["losses/value_loss"] == 0.25 and written["losses/clipfrac"] == 0.5
    assert written["counters/decisions"] == 80 and written["counters/updates"] == 2
    assert written["counters/steps_per_decision"] == 8 / 4
    # Of the 4 decisions, 2 chose a primitive action and 2 the routine.
    assert written["routines/primitive_usage"] == 0.5 and written["routines/usage_0"] == 0.5
    assert {"charts/SPS", "charts/decisions_per_second"} <= set(written)
    line = capsys.readouterr().out
    assert line.startswith("step        160/300") and "episodes     0" in line
    assert "routine use 50.0%" in line
    log.update(240, 120, 3, 1e-3, losses)  # update 3: not due; past step 200: a line
    assert writer.tags(240) == {}
    assert capsys.readouterr().out.startswith("step        240/300")
    log.update(300, 150, 4 + 1, 1e-3, losses)  # update 5, odd, but the last: written
    assert writer.tags(300)["counters/updates"] == 5
    assert capsys.readouterr().out.startswith("step        300/300")
