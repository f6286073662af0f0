"""Smoke runs of algos/rapl_sqil.py, algos/bc.py and algos/gail.py with tiny budgets, their
shared evaluation, and every kind of bad input the imitation scripts must name."""

from __future__ import annotations

import json
import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
from script_loader import load_script

import routine_gym  # noqa: F401  (registers MiniQbert-v0 and procgen/CoinRun-v0)
from routine_gym.demo import Demo, record_agent_demo, shipped_demo_path
from routine_gym.envs.factory import default_env_kwargs, preprocess
from routine_gym.errors import UsageError
from routine_gym.library import RoutineLibrary
from routine_gym.plumbing.evaluation import evaluate_policy
from routine_gym.plumbing.loading import check_demo_env, load_routines

SQIL, BC, GAIL = (load_script(n) for n in ("rapl_sqil", "bc", "gail"))

# Tiny budgets: each smoke run is about a second on MiniQbert and CartPole.
TINY = {
    "rapl_sqil": dict(total_timesteps=300, learning_starts=100, batch_size=8, log_every=1000),
    "bc": dict(gradient_steps=20, batch_size=8, log_every=1000),
    "gail": dict(total_timesteps=64, num_envs=2, num_steps=16, num_minibatches=2,
                 disc_minibatches=2, log_every=1000),
}
SCRIPTS = {"rapl_sqil": SQIL, "bc": BC, "gail": GAIL}


def run(script: str, tmp_path, **kwargs) -> dict | None:
    """Run a script's `main` in-process and return its eval.json (None without evaluation)."""
    module = SCRIPTS[script]
    args = module.Args(**{**TINY[script], "run_dir": str(tmp_path / "runs"), "eval_episodes": 2,
                          "eval_max_steps": 60, **kwargs})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        summary = module.main(args)
    (run_dir,) = os.listdir(tmp_path / "runs")
    env_name, exp_name, seed, _ = run_dir.split("__")
    assert (env_name, exp_name, seed) == (args.env_id.replace("/", "-"), script, str(args.seed))
    if args.eval_episodes == 0:
        return summary
    with open(tmp_path / "runs" / run_dir / "eval.json") as f:
        saved = json.load(f)
    assert saved == json.loads(json.dumps(summary))
    return saved


def check_summary(summary: dict, episodes: int = 2, cap: int = 60) -> None:
    assert summary["episodes"] == episodes == len(summary["returns"]) == len(summary["alignments"])
    assert all(0.0 <= a <= 1.0 for a in summary["alignments"])
    assert all(1 <= n <= cap for n in summary["lengths"])
    assert summary["mean_alignment"] == pytest.approx(np.mean(summary["alignments"]))
    assert summary["mean_return"] == pytest.approx(np.mean(summary["returns"]))


@pytest.fixture(scope="module")
def cartpole_demo(tmp_path_factory) -> str:
    demo = record_agent_demo("CartPole-v1", lambda obs: int(obs[2] > 0), num_episodes=1, seed=0,
                             max_steps=60, progress=False)
    path = str(tmp_path_factory.mktemp("demos") / "cartpole.npz")
    demo.save(path)
    return path


# -- smoke runs --------------------------------------------------------------------------------


@pytest.mark.parametrize("script", ["rapl_sqil", "bc", "gail"])
def test_every_script_imitates_the_shipped_miniqbert_demo(script, tmp_path):
    summary = run(script, tmp_path, env_id="MiniQbert-v0")
    check_summary(summary)
    assert summary["demo_length"] == 39 and summary["demo_score"] == 1050.0
    assert "human_normalized_score" not in summary  # not an Atari game
    if script == "rapl_sqil":
        # K = 3 asks for more routines than the demo yields: the run uses the 2 there are.
        assert summary["method"] == "rapl-sqil" and summary["num_routines"] == 2
        (run_dir,) = os.listdir(tmp_path / "runs")
        assert len(RoutineLibrary.load(tmp_path / "runs" / run_dir / "routines.json")) == 2


@pytest.mark.parametrize("script", ["rapl_sqil", "bc", "gail"])
def test_every_script_runs_on_any_discrete_env_with_a_demo_path(script, tmp_path, cartpole_demo):
    kwargs = {"num_routines": 0} if script == "rapl_sqil" else {}
    summary = run(script, tmp_path, env_id="CartPole-v1", demo=cartpole_demo, **kwargs)
    check_summary(summary)
    if script == "rapl_sqil":
        assert summary["method"] == "sqil" and summary["num_routines"] == 0


def test_sqil_checkpoint_resumes_where_it_stopped(tmp_path, capsys):
    first = run("rapl_sqil", tmp_path, env_id="MiniQbert-v0", checkpoint_every=100,
                eval_episodes=1)
    assert 300 <= first["global_step"] < 310
    (run_dir,) = os.listdir(tmp_path / "runs")
    path = tmp_path / "runs" / run_dir
    assert (path / "checkpoint.pt").exists()
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # The run goes on as configured; the budget is raised and, a setting of how the run is
        # reported, the number of evaluation episodes may change.
        SQIL.main(SQIL.Args(resume=str(path), total_timesteps=500, eval_episodes=7))
    out = capsys.readouterr().out
    assert "resumed" in out and "at step 30" in out  # 300 steps (a routine may overshoot)
    with open(path / "eval.json") as f:
        resumed = json.load(f)
    assert resumed["global_step"] >= 500 and resumed["episodes"] == 7


# -- the shared evaluation ---------------------------------------------------------------------


def test_evaluation_aligns_the_primitive_actions_a_routine_executed():
    actions = iter([5, 2, 5, 2, 3, 3, 0, 0])
    demo = record_agent_demo("MiniQbert-v0", lambda obs: next(actions), num_episodes=1,
                             max_steps=8, progress=False)
    assert demo.actions.tolist() == [5, 2, 5, 2, 3, 3, 0, 0]
    # Always routine 0 = DOWN UP: the primitive trajectory is [5 2 5 2 5 2 5 2], 4 substitutions.
    summary = evaluate_policy("MiniQbert-v0", lambda obs: 6, episodes=2, seed=0, demo=demo,
                              routines=[(5, 2)], max_steps=8)
    assert summary["alignments"] == [0.5, 0.5]
    assert summary["lengths"] == [8, 8]
    # The demo itself, replayed as a policy, aligns perfectly.
    replayed = iter([5, 2, 5, 2, 3, 3, 0, 0])
    summary = evaluate_policy("MiniQbert-v0", lambda obs: next(replayed), episodes=1, seed=0,
                              demo=demo, max_steps=8)
    assert summary["alignments"] == [1.0] and summary["returns"] == [float(demo.score)]


# -- bad input ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("script", "setting", "message"), [
    ("rapl_sqil", {"temperature": 0.0}, "--temperature needs to be > 0, actual value: 0.0"),
    ("rapl_sqil", {"batch_size": 1}, "--batch-size needs to be ≥ 2"),
    ("rapl_sqil", {"num_routines": -1}, "--num-routines needs to be ≥ 0, actual value: -1"),
    ("bc", {"batch_size": 0}, "--batch-size needs to be ≥ 1, actual value: 0"),
    ("gail", {"num_envs": 0}, "--num-envs needs to be ≥ 1, actual value: 0"),
])
def test_bad_settings_are_named(script, setting, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        SCRIPTS[script].main(SCRIPTS[script].Args(env_id="MiniQbert-v0",
                                                  run_dir=str(tmp_path), **setting))
    assert os.listdir(tmp_path) == []  # rejected before a run folder is made


def test_no_demo_exits_saying_how_to_record_one(tmp_path):
    with pytest.raises(UsageError, match="no demo of CartPole-v1 ships in demos/: record one"):
        run("rapl_sqil", tmp_path, env_id="CartPole-v1")


def test_a_demo_of_another_env_is_rejected(tmp_path, cartpole_demo):
    with pytest.raises(ValueError, match="recorded on CartPole-v1, not MiniQbert-v0"):
        run("bc", tmp_path, env_id="MiniQbert-v0", demo=cartpole_demo)


def test_a_demo_whose_action_space_does_not_match_the_env_is_rejected(tmp_path):
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"))
    meta = {**demo.meta, "num_actions": 7, "action_meanings": [*demo.action_meanings, "EXTRA"]}
    wrong = Demo(demo.actions, demo.rewards, demo.terminated, demo.truncated,
                 demo.episode_lengths, meta=meta)
    path = str(tmp_path / "wrong.npz")
    wrong.save(path)
    with pytest.raises(ValueError, match=r"Discrete\(7\) does not match .* Discrete\(6\)"):
        run("gail", tmp_path, env_id="MiniQbert-v0", demo=path)
    renamed = Demo(demo.actions, demo.rewards, demo.terminated, demo.truncated,
                   demo.episode_lengths, meta={**demo.meta, "action_meanings": list("ABCDEF")})
    with pytest.raises(ValueError, match="are not MiniQbert-v0's actions"):
        check_demo_env(renamed, "MiniQbert-v0")


def test_a_routine_library_of_another_env_is_rejected(tmp_path):
    other = RoutineLibrary(routines=((0, 1, 0),), source={"env_id": "CartPole-v1"})
    other.save(tmp_path / "cartpole.json")
    with pytest.raises(ValueError, match="mined from a demo of CartPole-v1, not MiniQbert-v0"):
        run("rapl_sqil", tmp_path, env_id="MiniQbert-v0",
            routine_library=str(tmp_path / "cartpole.json"))
    unnamed = RoutineLibrary(routines=((5, 9),))  # no env id, but action 9 is not MiniQbert's
    unnamed.save(tmp_path / "unnamed.json")
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"))
    with pytest.raises(ValueError, match=r"outside MiniQbert-v0's Discrete\(6\)"):
        load_routines("MiniQbert-v0", 3, demo=demo, library_path=str(tmp_path / "unnamed.json"))


def test_more_routines_than_the_library_holds_warns_and_uses_all_of_them(tmp_path):
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"))
    with pytest.warns(UserWarning, match="yields 2 routine.*fewer than --num-routines 5"):
        library = load_routines("MiniQbert-v0", 5, demo=demo)
    assert len(library) == 2
    path = str(tmp_path / "lib.json")
    library.save(path)
    with pytest.warns(UserWarning, match="holds 2 routine.*fewer than the 4 asked for"):
        loaded = load_routines("MiniQbert-v0", 4, demo=demo, library_path=path)
    assert loaded.routines == library.routines
    best = load_routines("MiniQbert-v0", 1, demo=demo, library_path=path)
    assert best.routines == library.routines[:1]
    assert load_routines("MiniQbert-v0", 0, demo=demo) is None
    with pytest.raises(ValueError, match="--num-routines needs to be ≥ 0"):
        load_routines("MiniQbert-v0", -1, demo=demo)


def test_no_routine_of_the_asked_minimum_length_is_a_one_line_error_naming_it():
    # MiniQbert's shipped demo yields two routines, both shorter than 20 actions.
    demo = Demo.load(shipped_demo_path("MiniQbert-v0"))
    library = load_routines("MiniQbert-v0", 2, demo=demo)
    assert max(len(r) for r in library.routines) < 20
    with pytest.raises(ValueError, match="^--mode rapl found no routine of ≥ 20 actions in "
                                         "the demo; use a smaller --min-routine-length") as err:
        load_routines("MiniQbert-v0", 3, demo=demo, min_length=20, required="--mode rapl")
    assert "\n" not in str(err.value)


# -- Atari and CoinRun ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def atari_demo(tmp_path_factory) -> str:
    """A short random Qbert demo, recorded under the agent's preprocessing as the expert's is."""
    env_id = "ALE/Qbert-v5"
    rng = np.random.default_rng(0)
    demo = record_agent_demo(
        env_id, lambda obs: int(rng.integers(6)), num_episodes=1, seed=0,
        env_kwargs=default_env_kwargs(env_id), max_steps=120, progress=False,
        wrap_env=lambda env: preprocess(gym.wrappers.RecordEpisodeStatistics(env), env_id,
                                        training=False),
    )
    path = str(tmp_path_factory.mktemp("demos") / "qbert.npz")
    demo.save(path, include_observations=False)
    return path


@pytest.mark.slow
def test_demo_states_are_the_stacks_the_agent_sees_on_atari():
    """The replayed demo's state before each decision is exactly the agent's observation then,
    across the no-op start, FIRE and the NOOP/FIRE served after each lost life, which the frame
    stack never sees; injected steps get no state of their own."""
    from routine_gym.imitation import agent_view_states

    env_id, seen = "ALE/Qbert-v5", []
    rng = np.random.default_rng(2)

    def policy(obs):
        seen.append(np.array(obs))
        return int(rng.integers(6))

    demo = record_agent_demo(
        env_id, policy, num_episodes=1, seed=3, env_kwargs=default_env_kwargs(env_id),
        max_steps=400, progress=False,
        wrap_env=lambda env: preprocess(env, env_id, training=False),
    )
    first = int(np.argmax(demo.decisions))
    served = np.flatnonzero(~demo.decisions[first:])  # injected after the first decision
    assert first >= 2 and set(demo.actions[: first - 1].tolist()) == {0}  # no-ops, then FIRE
    assert demo.actions[first - 1] == 1
    assert served.size >= 2 and served.size % 2 == 0  # NOOP, FIRE per lost life
    assert demo.num_decisions == len(seen)
    states = agent_view_states(demo, env_id)
    assert states.shape == (len(seen) + 1, 4, 84, 84) and states.dtype == np.uint8
    for k, obs in enumerate(seen):
        np.testing.assert_array_equal(states[k], obs, err_msg=f"decision {k}")


@pytest.mark.slow
@pytest.mark.parametrize("script", ["rapl_sqil", "bc", "gail"])
def test_every_script_runs_on_atari_qbert(script, tmp_path, atari_demo):
    kwargs = {"eval_episodes": 1, "eval_max_steps": 80}
    if script == "rapl_sqil":
        kwargs.update(total_timesteps=200, learning_starts=60, train_frequency=8)
    summary = run(script, tmp_path, env_id="ALE/Qbert-v5", demo=atari_demo, **kwargs)
    check_summary(summary, episodes=1, cap=80)
    assert "human_normalized_score" in summary


@pytest.fixture(scope="module")
def coinrun_demo(tmp_path_factory) -> str:
    rng = np.random.default_rng(0)
    demo = record_agent_demo(
        "procgen/CoinRun-v0", lambda obs: int(rng.integers(5)), num_episodes=1, seed=0,
        env_kwargs={"num_levels": 1, "start_level": 0}, max_steps=40, progress=False,
    )
    path = str(tmp_path_factory.mktemp("demos") / "coinrun.npz")
    demo.save(path, include_observations=False)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("script", ["rapl_sqil", "bc", "gail"])
def test_every_script_runs_on_coinrun(script, tmp_path, coinrun_demo):
    kwargs = {"eval_episodes": 1, "eval_max_steps": 40}
    if script == "rapl_sqil":
        kwargs.update(total_timesteps=120, learning_starts=40, train_frequency=8)
    summary = run(script, tmp_path, env_id="procgen/CoinRun-v0", demo=coinrun_demo, **kwargs)
    check_summary(summary, episodes=1, cap=40)
