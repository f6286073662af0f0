"""RAPL-PPO with rollouts sized in primitive steps (`algos/rapl_ppo.py --rollout-unit steps`,
issue 49's first mechanism): the rule that ends such a rollout, on hand-worked numbers; a run
that makes PPO's number of updates on PPO's frames, its updates built from the rollout's d
decisions only; the one-line errors.

That the flag's default leaves every seeded scalar as it was is checked against a copy of the
script from before the flag (see the commit that added it), not here: a test has no such copy.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from one_line import assert_one_line_error
from script_loader import load_script
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from routine_gym.plumbing.counters import rollout_filled

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
PPO = str(REPO / "algos" / "rapl_ppo.py")
DEMO = str(REPO / "demos" / "MinAtar-Breakout-v1.npz")


def user(*words, cwd, timeout=300):
    env = {"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(cwd), "LANG": "C.UTF-8",
           **{k: os.environ[k] for k in ("PYTHONPATH",) if k in os.environ}}
    return subprocess.run([sys.executable, *map(str, words)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


# -- the rule ----------------------------------------------------------------------------------

def test_a_rollout_ends_at_the_vector_step_nearest_its_target_by_hand():
    # N = 5 steps, E = 4 envs: update u's rollout aims at u·20 primitive steps of the run.
    assert not rollout_filled(15, 6, 1, 5, 4)  # 15 + 3 = 18 < 20: a step of 6 more ends at 21
    assert rollout_filled(16, 8, 1, 5, 4)  # 16 + 4 = 20: a tie ends it
    assert rollout_filled(22, 6, 1, 5, 4)  # past the target
    # Every env one step a decision (PPO): 16 + 2 < 20, 20 + 2 ≥ 20, the 5th vector step.
    assert not rollout_filled(16, 4, 1, 5, 4) and rollout_filled(20, 4, 1, 5, 4)
    # The target counts the run: after a first rollout that ran to 22, update 2 ends at 38.
    assert not rollout_filled(34, 4, 2, 5, 4) and rollout_filled(38, 4, 2, 5, 4)


def test_the_updates_follow_the_steps_whatever_the_routines_by_hand():
    # Vector steps of 4 envs running 1 to 3 steps each (4 to 12 in all), N = 5, E = 4. A
    # rollout that ends at G after a step of r stops short by at most r/2 ≤ 6 (G + r/2 ≥ T);
    # it runs over by less than r − r'/2 ≤ 12 − 2 = 10, where r' is the step before (which did
    # not end it: G − r + r'/2 < T). So after U rollouts the run has seen U·20 steps, −6 to
    # +9, however many rollouts: the target counts the run, the errors do not add up.
    rng = np.random.default_rng(0)
    global_step, update, worst = 0, 0, [0, 0]
    for _ in range(1000):
        update += 1
        for _ in range(5):  # at most N decisions per env
            ran = int(rng.integers(1, 4, size=4).sum())
            global_step += ran
            if rollout_filled(global_step, ran, update, 5, 4):
                break
        off = global_step - update * 20
        assert -6 <= off < 10
        worst = [min(worst[0], off), max(worst[1], off)]
    assert worst[0] < 0 < worst[1]


# -- a run -------------------------------------------------------------------------------------

def _last(run_dir: Path) -> dict[str, tuple[int, float]]:
    (folder,) = [p for p in run_dir.iterdir() if p.is_dir()]
    ea = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    ea.Reload()
    return {tag: (ea.Scalars(tag)[-1].step, ea.Scalars(tag)[-1].value)
            for tag in ea.Tags()["scalars"]}


def test_rapl_ppo_sized_in_steps_makes_the_updates_of_ppo(tmp_path):
    """4 envs × 16 steps: PPO updates every 64 primitive steps, so 3,000 steps are
    ceil(3000 / 64) = 47 updates; RAPL with --rollout-unit steps makes as many (± the last
    rollout), with fewer decisions than steps (its routines run several steps a decision)."""
    proc = user(PPO, "--mode", "rapl", "--rollout-unit", "steps", "--env-id",
                "MinAtar/Breakout-v1", "--demo", DEMO, "--num-envs", "4", "--num-steps", "16",
                "--total-timesteps", "3000", "--eval-episodes", "1", "--checkpoint-every", "0",
                "--torch-threads", "1", "--seed", "2", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    last = _last(tmp_path / "runs")
    steps, updates = last["counters/updates"][0], last["counters/updates"][1]
    decisions = last["counters/decisions"][1]
    assert abs(updates - math.ceil(3000 / 64)) <= 1
    assert abs(updates - steps / 64) <= 1
    assert decisions < steps  # routines ran: the rollouts held fewer than 16 decisions per env
    (evaluation,) = (tmp_path / "runs").glob("*/eval.json")
    assert json.loads(evaluation.read_text())["global_step"] == steps


def test_each_update_learns_from_its_rollouts_d_decisions_only(tmp_path, monkeypatch):
    # In-process, each update's rollout as `optimise` gets it: d ≤ N decisions per env, their
    # primitive steps, the states inside their routines (ℓ − 1 each), all the run counted.
    rapl_ppo = load_script("rapl_ppo", "rapl_ppo")
    try:
        seen = []
        optimise = rapl_ppo.optimise

        def recording(agent, optimizer, args, rollout, advantages, returns, inner, *rest):
            d = rollout.actions.shape[0]
            assert advantages.shape == returns.shape == rollout.values.shape == (d, 2)
            assert inner[0] == int((rollout.lengths - 1).sum())
            seen.append((d, int(rollout.lengths.sum())))
            return optimise(agent, optimizer, args, rollout, advantages, returns, inner, *rest)

        monkeypatch.setattr(rapl_ppo, "optimise", recording)
        rapl_ppo.main(rapl_ppo.Args(
            env_id="MiniQbert-v0", mode="rapl", rollout_unit="steps", num_envs=2, num_steps=8,
            num_minibatches=4, update_epochs=2, total_timesteps=400, eval_episodes=0,
            log_every=10**9, torch_threads=1, seed=1, run_dir=str(tmp_path)))
    finally:
        sys.modules.pop("rapl_ppo", None)
    last = _last(tmp_path)
    assert all(1 <= d <= 8 for d, _ in seen) and min(d for d, _ in seen) < 8
    assert sum(steps for _, steps in seen) == last["counters/updates"][0]
    assert sum(2 * d for d, _ in seen) == last["counters/decisions"][1]
    assert abs(len(seen) - sum(steps for _, steps in seen) / 16) <= 1


# -- errors ------------------------------------------------------------------------------------

@pytest.mark.parametrize("flags, message", [
    (["--rollout-unit", "steps", "--budget-unit", "decisions"],
     "--rollout-unit needs to be decisions with --budget-unit decisions"),
    (["--rollout-unit", "frames"], "invalid choice 'frames' for argument '--rollout-unit'"),
])
def test_bad_rollout_units_are_one_line_errors(tmp_path, flags, message):
    proc = user(PPO, "--env-id", "MinAtar/Breakout-v1", "--num-steps", "16",
                "--total-timesteps", "100", *flags, cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
