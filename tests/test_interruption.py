"""Interruption (issue 49, mechanism 3): the stop test, the executors that ask it before each
inner step j ≥ 1, and `--interrupt` of `rapl_a2c.py` and `rapl_ppo.py`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from one_line import assert_one_line_error
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

import routine_gym  # noqa: F401  (registers the MinAtar and MiniQbert ids)
from routine_gym import _native
from routine_gym.envs.factory import make_env, make_vector_env
from routine_gym.envs.minatar_vector import MinAtarVectorEnv
from routine_gym.interruption import PolicyStopRule, set_stop_rule, should_interrupt

REPO = Path(__file__).resolve().parent.parent
A2C = str(REPO / "algos" / "rapl_a2c.py")
HAS_CORE = _native.core("minatar_core") is not None
ENGINES = [pytest.param(True, marks=pytest.mark.skipif(not HAS_CORE, reason="no minatar_core")),
           False]


# -- the stop test -------------------------------------------------------------------------

def test_should_interrupt_compares_the_best_logit_with_the_next_primitives_by_the_margin():
    # |A| = 3 primitives and K = 1 routine. Row 0: best 1 (3.0), next 0 (1.0): 2.0 nats behind.
    # Row 1: next 1 is the best: a gap of 0, never a stop. Row 2: the routine (4.0) is the best,
    # next 2 (0.5) is 3.5 behind.
    z = np.array([[1.0, 3.0, 0.5, 2.0], [1.0, 3.0, 0.5, 2.0], [0.0, 1.0, 0.5, 4.0]])
    nxt = np.array([0, 1, 2])
    assert should_interrupt(z, nxt, 1.9).tolist() == [True, False, True]
    assert should_interrupt(z, nxt, 2.0).tolist() == [False, False, True]  # strict: 2.0 ≯ 2.0
    assert should_interrupt(z, nxt, 3.5).tolist() == [False, False, False]
    assert should_interrupt(z, nxt, 0.0).tolist() == [True, False, True]
    # The same test on log-probabilities: log-softmax shifts a row by one constant.
    logp = torch.log_softmax(torch.as_tensor(z), -1).numpy()
    for margin in (0.0, 1.0, 1.9, 2.1, 3.4, 3.6):
        assert (should_interrupt(logp, nxt, margin) == should_interrupt(z, nxt, margin)).all()
    # A torch tensor goes in as it is.
    assert should_interrupt(torch.as_tensor(z), nxt, 1.9).tolist() == [True, False, True]
    with pytest.raises(ValueError, match="margin needs to be ≥ 0"):
        should_interrupt(z, nxt, -0.1)


def test_the_policy_stop_rule_asks_the_logits_once_per_batch_and_counts_its_stops():
    calls = []

    def logits(obs):  # a policy whose logits are the observation itself
        calls.append(tuple(obs.shape))
        return obs

    rule = PolicyStopRule(logits, margin=1.0, device="cpu")
    obs = np.array([[0.0, 2.5, 0.0], [1.0, 0.5, 0.0]], dtype=np.float32)
    assert rule(obs, np.array([0, 0])).tolist() == [True, False]  # gaps 2.5 and 0
    assert calls == [(2, 3)] and rule.interruptions == 1 and rule.asked == 2


# -- the wrapper (one env) ------------------------------------------------------------------

class StopAt:
    """A stop rule that stops a routine before inner step `j` (it counts its calls; `start`
    starts a routine)."""

    def __init__(self, j):
        self.j, self.asked = j, []

    def start(self):
        self.calls = 0

    def __call__(self, obs, next_actions):
        self.calls += 1
        self.asked.append((np.array(obs), np.array(next_actions)))
        return np.full(len(next_actions), self.calls == self.j)


@pytest.mark.parametrize("j", [1, 2, 3])
def test_the_wrapper_stops_a_routine_at_the_inner_step_the_rule_says(j):
    # MiniQbert from its seeded start, routine RIGHT DOWN RIGHT DOWN: 25, 25, 25, 0 in full.
    routine = [3, 5, 3, 5]
    full = make_env("MiniQbert-v0", routines=[routine], record_observations=True)()
    cut = make_env("MiniQbert-v0", routines=[routine], record_observations=True)()
    rule = StopAt(j)
    cut.set_stop_rule(rule)
    full.reset(seed=1)
    cut.reset(seed=1)
    rule.start()
    _, reward_f, _, _, info_f = full.step(6)
    obs_c, reward_c, term_c, trunc_c, info_c = cut.step(6)
    assert info_f["routine_length"] == 4 and info_f["routine_rewards"].tolist() == [25] * 3 + [0]
    assert info_c["routine_length"] == j and info_c["routine_interrupted"] is True
    assert info_c["routine_rewards"].tolist() == [25.0] * j + [0.0] * (4 - j)
    assert reward_c == 25.0 * j and not (term_c or trunc_c)
    assert info_c["routine_actions"].tolist() == routine[:j] + [-1] * (4 - j)
    assert np.array_equal(info_c["routine_observations"][:j], info_f["routine_observations"][:j])
    assert not info_c["routine_observations"][j:].any()  # zero padding, as at an episode end
    assert np.array_equal(obs_c, info_f["routine_observations"][j - 1])
    # The rule saw the state each inner step reached and the primitive due next.
    assert len(rule.asked) == j
    for step, (obs, nxt) in enumerate(rule.asked, start=1):
        assert np.array_equal(obs[0], info_f["routine_observations"][step - 1])
        assert nxt.tolist() == [routine[step]]
    # A primitive is never asked about and never interrupted.
    rule.start()
    _, _, _, _, info = cut.step(0)
    assert info["routine_length"] == 1 and info["routine_interrupted"] is False
    assert len(rule.asked) == j


def test_the_wrapper_with_a_rule_that_never_stops_returns_what_it_returns_without():
    never = make_env("MiniQbert-v0", routines=[[3, 5, 3], [0, 0]], record_observations=True)()
    plain = make_env("MiniQbert-v0", routines=[[3, 5, 3], [0, 0]], record_observations=True)()
    never.set_stop_rule(lambda obs, nxt: np.zeros(len(nxt), dtype=bool))
    never.reset(seed=4)
    plain.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(200):
        action = int(rng.integers(0, 8))
        out_n, out_p = never.step(action), plain.step(action)
        for a, b in zip(out_n[:4], out_p[:4], strict=True):
            assert np.array_equal(a, b)
        info_n, info_p = out_n[4], out_p[4]
        assert info_n.pop("routine_interrupted") is False and "routine_interrupted" not in info_p
        assert info_n.keys() == info_p.keys()
        for key in info_n:
            if key == "episode":  # its wall time `t` differs, of course
                assert info_n[key]["r"] == info_p[key]["r"] and info_n[key]["l"] == info_p[key]["l"]
            else:
                assert np.array_equal(info_n[key], info_p[key]), key
        if out_n[2] or out_n[3]:
            never.reset()
            plain.reset()


# -- MinAtarVectorEnv (all games together) --------------------------------------------------

def _flat(info, prefix=""):
    out = {}
    for key, value in info.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}/"))
        elif f"{prefix}{key}" not in ("final_info/episode/t", "final_info/episode/_t"):
            out[f"{prefix}{key}"] = value  # (an episode's wall time differs, of course)
    return out


def _assert_same(out_a, out_b, t, skip=()):
    for name, a, b in zip(("obs", "reward", "terminated", "truncated"), out_a, out_b,
                          strict=False):
        assert a.dtype == b.dtype and np.array_equal(a, b), (t, name)
    flat_a = {k: v for k, v in _flat(out_a[4]).items() if k.split("/")[-1] not in skip}
    flat_b = {k: v for k, v in _flat(out_b[4]).items() if k.split("/")[-1] not in skip}
    assert flat_a.keys() == flat_b.keys(), (t, sorted(flat_a.keys() ^ flat_b.keys()))
    for key, a in flat_a.items():
        if key == "final_obs":
            for x, y in zip(a, flat_b[key], strict=True):
                assert (x is None) == (y is None) and (x is None or np.array_equal(x, y)), t
        else:
            assert a.dtype == flat_b[key].dtype and np.array_equal(a, flat_b[key]), (t, key)


ROUTINES = [[1, 1, 2, 2, 1], [0, 0, 0], [2, 1]]
KWARGS = {"max_episode_steps": 40}  # truncations inside routines too


def _steps(envs, steps, seed=3):
    envs.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        yield envs.step(rng.integers(0, envs.single_action_space.n, envs.num_envs))


@pytest.mark.parametrize("compiled", ENGINES)
def test_a_rule_that_never_stops_gives_what_no_rule_gives(compiled):
    plain = MinAtarVectorEnv("MinAtar/Breakout-v1", 6, routines=ROUTINES,
                             record_observations=True, env_kwargs=KWARGS, compiled=compiled)
    never = MinAtarVectorEnv("MinAtar/Breakout-v1", 6, routines=ROUTINES,
                             record_observations=True, env_kwargs=KWARGS, compiled=compiled)
    asked = []

    def rule(obs, nxt):
        asked.append(len(nxt))
        return np.zeros(len(nxt), dtype=bool)

    never.set_stop_rule(rule)
    ends = truncations = 0
    for t, (out_p, out_n) in enumerate(zip(_steps(plain, 300), _steps(never, 300),
                                           strict=True)):
        assert "routine_interrupted" not in out_p[4]
        assert not out_n[4]["routine_interrupted"].any()
        _assert_same(out_n, out_p, t, skip=("routine_interrupted", "_routine_interrupted"))
        ends += int((out_p[2] | out_p[3]).sum())
        truncations += int(out_p[3].sum())
    assert ends > 0 and truncations > 0 and asked
    assert max(asked) <= 6  # one call per inner step, for all the envs inside a routine


@pytest.mark.parametrize("compiled", ENGINES)
@pytest.mark.parametrize("j", [1, 2, 4])
def test_the_vector_env_stops_every_routine_at_the_inner_step_the_rule_says(compiled, j):
    # Step 0 of each env: routine 0 (5 steps), routine 1 (3), a primitive, routine 2 (2).
    actions = np.array([3, 4, 1, 5])
    full = MinAtarVectorEnv("MinAtar/Breakout-v1", 4, routines=ROUTINES,
                            record_observations=True, compiled=compiled)
    cut = MinAtarVectorEnv("MinAtar/Breakout-v1", 4, routines=ROUTINES,
                           record_observations=True, compiled=compiled)
    calls = []

    def stop_at_j(obs, nxt):  # asked before inner step len(calls) + 1 of every routine left
        calls.append((np.array(obs), np.array(nxt)))
        return np.full(len(nxt), len(calls) == j)

    cut.set_stop_rule(stop_at_j)
    full.reset(seed=0)
    cut.reset(seed=0)
    _, reward_f, _, _, info_f = full.step(actions)
    obs_c, reward_c, term_c, trunc_c, info_c = cut.step(actions)
    assert "final_info" not in info_f and not (term_c.any() or trunc_c.any())
    lengths = np.minimum([5, 3, 1, 2], j)
    assert info_c["routine_length"].tolist() == lengths.tolist()
    assert info_c["routine_interrupted"].tolist() == [bool(n > j) for n in (5, 3, 1, 2)]
    for i, n in enumerate(lengths):
        assert np.array_equal(info_c["routine_rewards"][i, :n], info_f["routine_rewards"][i, :n])
        assert not info_c["routine_rewards"][i, n:].any()
        assert reward_c[i] == info_f["routine_rewards"][i, :n].sum()
        assert np.array_equal(info_c["routine_actions"][i, :n], info_f["routine_actions"][i, :n])
        assert (info_c["routine_actions"][i, n:] == -1).all()
        assert np.array_equal(info_c["routine_observations"][i, :n],
                              info_f["routine_observations"][i, :n])
        assert not info_c["routine_observations"][i, n:].any()
        assert np.array_equal(obs_c[i], info_f["routine_observations"][i, n - 1])
    # Inner step 1 asks the three routines at once, with the states they reached.
    obs, nxt = calls[0]
    assert len(calls) == min(j, 4) and len(nxt) == 3
    assert np.array_equal(obs, info_f["routine_observations"][[0, 1, 3], 0])
    assert nxt.tolist() == [1, 0, 1]  # the routines' second primitives


@pytest.mark.parametrize("env_id", ["MinAtar/Breakout-v1", "MinAtar/Seaquest-v1"])
def test_the_compiled_core_the_python_loop_and_the_wrappers_stop_alike(env_id):
    # A rule that is a function of (state, next primitive): the three executors see the same
    # states, so they stop the same routines; episode ends and truncations included.
    if not HAS_CORE:
        pytest.skip("no minatar_core")
    routines = [[1, 1, 2, 2, 1], [0, 0, 0], [2, 1]]

    def rule(obs, nxt):
        return (np.asarray(obs).reshape(len(nxt), -1).sum(1).round() % 3 == 0) & (nxt != 2)

    made = [MinAtarVectorEnv(env_id, 5, routines=routines, record_observations=True,
                             env_kwargs=KWARGS, compiled=c) for c in (True, False)]
    made.append(make_vector_env(env_id, 5, routines=routines, record_observations=True,
                                env_kwargs=KWARGS, batched=False))
    assert isinstance(made[2], gym.vector.SyncVectorEnv)
    for envs in made:
        set_stop_rule(envs, rule)
    stops = 0
    for t, (a, b, c) in enumerate(zip(*(_steps(envs, 250) for envs in made), strict=True)):
        _assert_same(a, b, t)
        _assert_same(a, c, t)
        stops += int(a[4].get("routine_interrupted", np.zeros(1, bool)).sum())
    assert stops > 0


def test_an_async_vector_env_cannot_take_a_stop_rule():
    envs = make_vector_env("MinAtar/Breakout-v1", 1, routines=[[0, 0]], async_envs=True)
    try:
        with pytest.raises(ValueError, match="subprocesses"):
            set_stop_rule(envs, lambda obs, nxt: np.zeros(len(nxt), dtype=bool))
    finally:
        envs.close()


# -- rapl_a2c.py and rapl_ppo.py --interrupt ---------------------------------------------

SCRIPTS = {"a2c": A2C, "ppo": str(REPO / "algos" / "rapl_ppo.py")}


def _run(script, tmp_path, *flags, timeout=300):
    return subprocess.run([sys.executable, SCRIPTS[script], "--env-id", "MinAtar/Breakout-v1",
                           "--demo", str(REPO / "demos" / "MinAtar-Breakout-v1.npz"),
                           "--run-dir", str(tmp_path / "runs"), *map(str, flags)],
                          cwd=tmp_path, capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


@pytest.mark.parametrize("script, mode", [("a2c", "rapl"), ("ppo", "rapl"), ("ppo", "macro")])
def test_interrupt_trains_and_logs_its_interruptions(tmp_path, script, mode):
    batch = ["--num-steps", 32] if script == "ppo" else []
    proc = _run(script, tmp_path, "--mode", mode, "--interrupt", 1.0, "--num-envs", 4, *batch,
                "--total-timesteps", 3000, "--eval-episodes", 1, "--checkpoint-every", 0,
                "--torch-threads", 1, "--scalars-every", 10)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    assert (run / "eval.json").exists()
    events = EventAccumulator(str(run))
    events.Reload()
    stops = [e.value for e in events.Scalars("counters/interruptions")]
    shares = [e.value for e in events.Scalars("counters/interrupted_share")]
    assert stops == sorted(stops) and stops[-1] > 0  # a total, and some routines stopped
    assert all(0 <= s <= 1 for s in shares)
    # The evaluation acts under the rule it was trained under, and counts its own stops.
    evaluation = json.loads((run / "eval.json").read_text())
    assert isinstance(evaluation["interruptions"], int) and evaluation["interruptions"] >= 0


def _always_stop(num_actions):
    """A PolicyStopRule whose logits put the last action 5 nats above every other: a routine
    whose next primitive is not that action stops before it, whatever the margin below 5."""
    z = torch.zeros(num_actions)
    z[-1] = 5.0
    return PolicyStopRule(lambda obs: z.expand(len(obs), num_actions), margin=1.0,
                          device="cpu")


def test_the_evaluation_acts_under_the_stop_rule_and_counts_its_stops():
    """A policy that always calls routine 0 (NOOP NOOP NOOP on Breakout, |A| = 3): without a
    rule each call runs 3 steps (fewer only where the episode ends inside it); with a rule that
    stops before every inner step, each call runs 1 step, so the policy is asked once per
    primitive step, and every call but the one that ends an episode is stopped: the count is
    the calls less the episodes."""
    from routine_gym.plumbing.evaluation import evaluate_policy

    def counting(calls):
        def policy(obs):
            calls.append(1)
            return 3
        return policy

    routines, free_calls, cut_calls = [[0, 0, 0]], [], []
    free = evaluate_policy("MinAtar/Breakout-v1", counting(free_calls), 2, seed=7,
                           routines=routines)
    rule = _always_stop(4)
    cut = evaluate_policy("MinAtar/Breakout-v1", counting(cut_calls), 2, seed=7,
                          routines=routines, stop_rule=rule)
    assert "interruptions" not in free
    steps = sum(free["lengths"])
    assert steps / 3 <= len(free_calls) <= steps / 3 + 2  # one short call per episode at most
    assert len(cut_calls) == sum(cut["lengths"])
    assert cut["interruptions"] == len(cut_calls) - 2 == rule.interruptions
    with pytest.raises(ValueError, match="give the routines too"):
        evaluate_policy("MinAtar/Breakout-v1", lambda obs: 0, 1, seed=7, stop_rule=rule)


@pytest.mark.parametrize("script", ["a2c", "ppo"])
def test_a_resumed_run_counts_its_interruptions_on_from_its_checkpoint(tmp_path, script):
    import torch

    batch = ["--num-steps", 32] if script == "ppo" else []
    common = ["--interrupt", 0.2, "--num-envs", 4, *batch, "--eval-episodes", 0,
              "--torch-threads", 1, "--scalars-every", 10]
    proc = _run(script, tmp_path, "--mode", "rapl", "--total-timesteps", 1500,
                "--checkpoint-every", 500, *common)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (run,) = (tmp_path / "runs").iterdir()
    saved = torch.load(run / "checkpoint.pt", weights_only=True)["interruptions"]
    assert saved["interruptions"] > 0 and saved["asked"] >= saved["interruptions"]
    first_file = set(run.glob("events.out.tfevents.*"))
    resumed = subprocess.run([sys.executable, SCRIPTS[script], "--resume", str(run),
                              "--total-timesteps", "3000"], cwd=tmp_path, capture_output=True,
                             text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    (second,) = set(run.glob("events.out.tfevents.*")) - first_file
    events = EventAccumulator(str(second))
    events.Reload()
    stops = [e.value for e in events.Scalars("counters/interruptions")]
    assert stops[0] >= saved["interruptions"] and stops == sorted(stops)  # a whole-run total


@pytest.mark.parametrize("script, flags, names", [
    ("a2c", ("--interrupt", -1), ("--interrupt", "≥ 0", "-1")),
    ("a2c", ("--interrupt", 1.0, "--mode", "a2c"), ("--interrupt", "--mode a2c")),
    ("a2c", ("--interrupt", 1.0, "--async-envs"), ("--interrupt", "--async-envs")),
    ("ppo", ("--interrupt", -0.5), ("--interrupt", "≥ 0", "-0.5")),
    ("ppo", ("--interrupt", 1.0, "--mode", "ppo"), ("--interrupt", "--mode ppo")),
    ("ppo", ("--interrupt", 1.0, "--async-envs"), ("--interrupt", "--async-envs")),
])
def test_a_bad_interrupt_is_a_one_line_error(tmp_path, script, flags, names):
    proc = _run(script, tmp_path, "--total-timesteps", 20000, *flags, timeout=120)
    assert_one_line_error(proc, *names, prefix=f"rapl_{script}.py: error:")
