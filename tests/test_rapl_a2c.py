"""Smoke tests of `algos/rapl_a2c.py` (SPEC §5): every mode on every kind of env, the run
folder it writes, checkpoint/resume after a kill, `--record-demo` and the TensorBoard log.

The script is imported from its path and `main(Args(...))` is called in-process with tiny
budgets (2 envs, a few hundred primitive steps); only the kill test starts a subprocess.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from resume_checks import kill_after_first_checkpoint
from script_loader import load_script

import routine_gym  # noqa: F401  (registers MiniQbert, CoinRun and the ALE envs)
from routine_gym.demo import DEMO_SUITE, Demo, record_agent_demo, replay, shipped_demo_path
from routine_gym.envs.factory import default_env_kwargs
from routine_gym.errors import UsageError
from routine_gym.library import RoutineLibrary
from routine_gym.plumbing.loading import load_routines

pytestmark = pytest.mark.filterwarnings(
    "ignore:only .* routine\\(s\\) survive:UserWarning",  # MiniQbert's demo gives 2 of 3
    "ignore::DeprecationWarning",
)

MODES = ("a2c", "rapl", "macro")
F, T = False, True


@pytest.fixture(scope="module")
def rapl_a2c():
    """The script as a module."""
    yield load_script("rapl_a2c", "rapl_a2c")
    sys.modules.pop("rapl_a2c", None)


def random_policy(num_actions: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    return lambda obs: int(rng.integers(num_actions))


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("demos")


def record_random_demo(env_id: str, num_actions: int, path: Path, **kwargs) -> str:
    demo = record_agent_demo(
        env_id, random_policy(num_actions), num_episodes=kwargs.pop("num_episodes", 1),
        env_kwargs=default_env_kwargs(env_id), progress=False, **kwargs,
    )
    demo.save(path, include_observations=False)
    return str(path)


@pytest.fixture(scope="module")
def cartpole_demo(demo_dir) -> str:
    return record_random_demo("CartPole-v1", 2, demo_dir / "cartpole.npz", num_episodes=3)


@pytest.fixture(scope="module")
def qbert_demo(demo_dir) -> str:
    return record_random_demo("ALE/Qbert-v5", 6, demo_dir / "qbert.npz", max_steps=200)


@pytest.fixture(scope="module")
def coinrun_demo(demo_dir) -> str:
    return record_random_demo("procgen/CoinRun-v0", 5, demo_dir / "coinrun.npz", max_steps=200)


def run(module, run_dir: Path, **kwargs) -> Path:
    """`main(Args(...))` with tiny defaults; returns the run folder it created."""
    settings = dict(num_envs=2, total_timesteps=200, eval_episodes=0, log_every=10**9,
                    run_dir=str(run_dir))
    settings.update(kwargs)
    before = set(run_dir.iterdir()) if run_dir.exists() else set()
    module.main(module.Args(**settings))
    (folder,) = set(run_dir.iterdir()) - before
    return folder


def check_run_folder(folder: Path, mode: str, eval_episodes: int) -> RoutineLibrary | None:
    """The files every run leaves: TensorBoard events, routines.json (with routines), eval.json."""
    assert list(folder.glob("events.out.tfevents.*")), "no TensorBoard event file"
    library = None
    if mode == "a2c":
        assert not (folder / "routines.json").exists()
    else:
        library = RoutineLibrary.load(folder / "routines.json")
        assert 1 <= len(library) <= 3
    if eval_episodes:
        summary = json.loads((folder / "eval.json").read_text())
        assert summary["method"] == mode
        assert summary["episodes"] == eval_episodes
        assert len(summary["returns"]) == len(summary["lengths"]) == eval_episodes
        assert summary["mean_return"] == pytest.approx(np.mean(summary["returns"]))
    else:
        assert not (folder / "eval.json").exists()
    return library


def scalars(folder: Path) -> dict[str, list[float]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [e.value for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


# -- every mode, every kind of env ----------------------------------------------------------


@pytest.mark.parametrize("mode", MODES)
def test_every_mode_runs_on_cartpole_with_a_recorded_demo(rapl_a2c, tmp_path, cartpole_demo, mode):
    demo = None if mode == "a2c" else cartpole_demo  # --mode a2c reads no demo (refuses one)
    folder = run(rapl_a2c, tmp_path, env_id="CartPole-v1", mode=mode, demo=demo,
                 eval_episodes=1)
    library = check_run_folder(folder, mode, eval_episodes=1)
    if library is not None:
        assert library.source["path"] == cartpole_demo


@pytest.mark.parametrize("mode", MODES)
def test_every_mode_on_miniqbert_logs_the_standard_scalars(rapl_a2c, tmp_path, mode):
    # MiniQbert's shipped demo (demos/MiniQbert-v0.npz) is used without --demo.
    folder = run(rapl_a2c, tmp_path, env_id="MiniQbert-v0", mode=mode, total_timesteps=400,
                 eval_episodes=2)
    library = check_run_folder(folder, mode, eval_episodes=2)
    if library is not None:
        assert library.source["path"].endswith("demos/MiniQbert-v0.npz")
    logged = scalars(folder)
    for tag in ("charts/SPS", "charts/episodic_return", "charts/episodic_length",
                "losses/value_loss", "losses/prim_value_loss", "losses/policy_loss",
                "losses/entropy", "charts/learning_rate", "eval/mean_return"):
        assert tag in logged, f"{tag} not logged; got {sorted(logged)}"
    assert logged["charts/SPS"][-1] > 0
    if mode == "rapl":
        # A_prim trains the critic at the states inside routines: its loss is not always 0.
        assert max(logged["losses/prim_value_loss"]) > 0
    else:
        # MacroAction and A2C have no primitive-level update.
        assert max(logged["losses/prim_value_loss"]) == 0
    if mode == "a2c":
        assert not any(tag.startswith("routines/") for tag in logged)
    else:
        usage = [logged[f"routines/usage_{k}"] for k in range(len(library))]
        assert f"routines/usage_{len(library)}" not in logged
        # Every decision is a primitive or a routine: the shares add up to 1.
        total = np.sum(usage, axis=0) + np.asarray(logged["routines/primitive_usage"])
        np.testing.assert_allclose(total, 1.0)
        assert all(0.0 <= u <= 1.0 for series in usage for u in series)


def test_reward_scale_shrinks_the_learning_targets_but_not_the_logged_score(rapl_a2c, tmp_path):
    losses, returns = {}, {}
    for scale in (1.0, 0.01):
        folder = run(rapl_a2c, tmp_path / str(scale), env_id="MiniQbert-v0", mode="a2c",
                     total_timesteps=300, reward_scale=scale)
        logged = scalars(folder)
        losses[scale] = logged["losses/value_loss"]
        returns[scale] = logged["charts/episodic_return"]
    # Same seed, same first rollout: MiniQbert pays 25 per new cube, so unscaled returns are
    # tens while scaled ones are tenths, and the first value loss shrinks by orders of magnitude.
    assert losses[0.01][0] < losses[1.0][0] / 100
    # The logged score is the game's: multiples of 25 at either scale.
    assert returns[0.01] and all(r % 25 == 0 for r in returns[0.01])
    assert max(returns[0.01]) >= 25
    with pytest.raises(ValueError, match="--reward-scale needs to be > 0"):
        rapl_a2c.main(rapl_a2c.Args(env_id="MiniQbert-v0", reward_scale=0.0))


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_every_mode_runs_on_atari_qbert(rapl_a2c, tmp_path, qbert_demo, mode):
    # ALE's shipped demo does not exist yet, so rapl/macro mine a 200-step random demo.
    # Evaluation plays whole games (thousands of steps), so it is tested on MiniQbert instead.
    demo = None if mode == "a2c" else qbert_demo
    folder = run(rapl_a2c, tmp_path, env_id="ALE/Qbert-v5", mode=mode, demo=demo,
                 total_timesteps=120)
    check_run_folder(folder, mode, eval_episodes=0)
    assert scalars(folder)["losses/value_loss"]


@pytest.mark.slow
@pytest.mark.parametrize("mode", MODES)
def test_every_mode_runs_on_coinrun_with_procgen_options(
    rapl_a2c, tmp_path, coinrun_demo, mode, monkeypatch
):
    made = []
    real_make_vector_env = rapl_a2c.make_vector_env

    def spy_make_vector_env(env_id, *args, **kwargs):
        made.append(kwargs["env_kwargs"])
        return real_make_vector_env(env_id, *args, **kwargs)

    monkeypatch.setattr(rapl_a2c, "make_vector_env", spy_make_vector_env)
    demo = None if mode == "a2c" else coinrun_demo
    folder = run(rapl_a2c, tmp_path, env_id="procgen/CoinRun-v0", mode=mode, demo=demo,
                 num_levels=7, start_level=3, distribution_mode="easy", total_timesteps=60)
    check_run_folder(folder, mode, eval_episodes=0)
    assert made == [{"num_levels": 7, "start_level": 3, "distribution_mode": "easy"}]


@pytest.mark.slow
@pytest.mark.parametrize("env_id", DEMO_SUITE)
def test_every_suite_env_runs_with_no_extra_flags(rapl_a2c, tmp_path, env_id):
    # The default mode is rapl: the routines come from the shipped demo, mined on the fly.
    folder = run(rapl_a2c, tmp_path, env_id=env_id, total_timesteps=40)
    library = check_run_folder(folder, "rapl", eval_episodes=0)
    assert len(library) == 3
    assert library.source["path"] == shipped_demo_path(env_id)


def test_procgen_is_evaluated_on_unseen_levels(rapl_a2c):
    args = rapl_a2c.Args(env_id="procgen/CoinRun-v0", num_levels=100, start_level=5,
                         distribution_mode="easy", eval_distribution_mode="hard")
    assert rapl_a2c.train_env_kwargs(args) == {
        "num_levels": 100, "start_level": 5, "distribution_mode": "easy"}
    # Levels 105, 106, ... (num_levels=0: unbounded), on the evaluation difficulty.
    assert rapl_a2c.eval_env_kwargs(args) == {
        "num_levels": 0, "start_level": 105, "distribution_mode": "hard"}
    atari = rapl_a2c.Args(env_id="ALE/Qbert-v5")
    assert rapl_a2c.train_env_kwargs(atari) == rapl_a2c.eval_env_kwargs(atari) == {}


# -- routines: where they come from, and the errors ------------------------------------------


def test_rapl_without_a_demo_explains_how_to_record_one(rapl_a2c, tmp_path):
    with pytest.raises(UsageError) as excinfo:
        run(rapl_a2c, tmp_path, env_id="CartPole-v1", mode="rapl")
    message = str(excinfo.value)
    assert "no demo of CartPole-v1 ships in demos/" in message
    assert "routine-gym record CartPole-v1" in message
    assert "--demo" in message


def test_a_demo_that_yields_no_routine_is_a_clear_error(rapl_a2c, tmp_path):
    # Actions 0 1 0: no digram repeats, so Sequitur has no rule and there is nothing to add.
    demo = Demo(
        actions=np.array([0, 1, 0]), rewards=np.ones(3), terminated=np.array([F, F, T]),
        truncated=np.zeros(3, bool), episode_lengths=np.array([3]),
        meta={"env_id": "CartPole-v1", "num_actions": 2, "seeds": [0]},
    )
    demo.save(tmp_path / "short.npz")
    with pytest.raises(UsageError) as excinfo:
        run(rapl_a2c, tmp_path / "runs", env_id="CartPole-v1", mode="macro",
            demo=str(tmp_path / "short.npz"))
    assert "no routine" in str(excinfo.value)
    assert "--mode a2c" in str(excinfo.value)


def test_a_library_mined_for_another_env_is_refused(rapl_a2c, tmp_path, repo_root):
    demo = Demo.load(repo_root / "demos" / "MiniQbert-v0.npz")
    library = load_routines("MiniQbert-v0", 3, demo=demo)
    library.save(tmp_path / "lib.json")
    assert library.source["env_id"] == "MiniQbert-v0"
    with pytest.raises(ValueError, match="MiniQbert-v0, not CartPole-v1"):
        run(rapl_a2c, tmp_path / "runs", env_id="CartPole-v1", mode="rapl",
            routine_library=str(tmp_path / "lib.json"))
    # The same library is used as is for its own env (no mining, no demo needed).
    again = load_routines("MiniQbert-v0", 3, library_path=str(tmp_path / "lib.json"))
    assert again.routines == library.routines


# -- checkpoints ---------------------------------------------------------------------------


def test_killed_run_resumes_from_its_last_checkpoint_and_finishes(rapl_a2c, tmp_path, repo_root,
                                                                   capsys):
    # Plain A2C: every iteration is exactly num_envs · num_steps = 2 · 5 = 10 primitive steps,
    # so checkpoints land on multiples of 500 and the run ends exactly at 3000.
    command = [
        sys.executable, str(repo_root / "algos" / "rapl_a2c.py"), "--env-id", "MiniQbert-v0",
        "--mode", "a2c", "--num-envs", "2", "--total-timesteps", "3000",
        "--checkpoint-every", "500", "--eval-episodes", "0", "--run-dir", str(tmp_path),
    ]
    checkpoint_path = kill_after_first_checkpoint(command, tmp_path)
    saved = torch.load(checkpoint_path, weights_only=True)
    killed_at = saved["global_step"]
    assert killed_at % 500 == 0 and 500 <= killed_at < 3000

    # Resume by run folder, with no other option: the run keeps its own settings and budget.
    rapl_a2c.main(rapl_a2c.Args(resume=str(checkpoint_path.parent)))
    out = capsys.readouterr().out
    assert f"resumed {checkpoint_path.parent.name} at step {killed_at}" in out
    final = torch.load(checkpoint_path, weights_only=True)
    assert final["global_step"] == 3000
    assert final["iteration"] == 3000 // 10
    assert json.loads(final["args"])["total_timesteps"] == 3000
    # The resumed run logged into the same folder, only at steps after the checkpoint.
    # The last written (not the last by name: both names may carry the same second, and then
    # the process ids decide).
    resumed = max(checkpoint_path.parent.glob("events.out.tfevents.*"),
                  key=lambda path: path.stat().st_mtime_ns)
    steps = _scalar_steps(resumed, "charts/SPS")
    assert min(steps) > killed_at and max(steps) == 3000
    # The killed run's event file holds every episode up to its checkpoint (the writer is
    # flushed before each checkpoint): the same episodes as an uninterrupted run of the seed.
    (killed,) = set(checkpoint_path.parent.glob("events.out.tfevents.*")) - {resumed}
    whole = tmp_path / "whole"
    subprocess.run([*command[:-1], str(whole)], check=True, capture_output=True)
    (whole_file,) = whole.glob("*/events.out.tfevents.*")
    expected = [(s, r) for s, r in _scalars(whole_file, "charts/episodic_return") if s <= killed_at]
    assert expected and _scalars(killed, "charts/episodic_return") == expected


def _scalar_steps(event_file: Path, tag: str) -> list[int]:
    return [step for step, _ in _scalars(event_file, tag)]


def _scalars(event_file: Path, tag: str) -> list[tuple[int, float]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(event_file), size_guidance={"scalars": 0})
    acc.Reload()
    return [(e.step, e.value) for e in acc.Scalars(tag)]


def test_resume_keeps_the_library_and_may_raise_the_budget(rapl_a2c, tmp_path, monkeypatch,
                                                           capsys):
    folder = run(rapl_a2c, tmp_path, env_id="MiniQbert-v0", mode="rapl", total_timesteps=100,
                 checkpoint_every=50)
    checkpoint = torch.load(folder / "checkpoint.pt", weights_only=True)
    first_step = checkpoint["global_step"]
    assert first_step >= 100
    library = RoutineLibrary.load(folder / "routines.json")
    assert RoutineLibrary.from_dict(json.loads(checkpoint["library"])).routines == library.routines

    def no_mining(*args, **kwargs):
        raise AssertionError("a resumed run must reuse the checkpoint's routines")

    # Run.routines mines through load_routines: a resumed run must never get there.
    monkeypatch.setattr("routine_gym.plumbing.loading.load_routines", no_mining)
    rapl_a2c.main(rapl_a2c.Args(resume=str(folder / "checkpoint.pt"), total_timesteps=300))
    assert f"at step {first_step}" in capsys.readouterr().out
    final = torch.load(folder / "checkpoint.pt", weights_only=True)
    assert final["global_step"] >= 300
    assert json.loads(final["args"])["total_timesteps"] == 300
    assert RoutineLibrary.load(folder / "routines.json").routines == library.routines


# -- outputs -------------------------------------------------------------------------------


def test_record_demo_writes_a_replayable_primitive_demo(rapl_a2c, tmp_path):
    out = tmp_path / "agent.npz"
    run(rapl_a2c, tmp_path / "runs", env_id="MiniQbert-v0", mode="rapl", total_timesteps=100,
        record_demo=str(out), demo_episodes=2, seed=3)
    demo = Demo.load(out, env_id="MiniQbert-v0")
    # The agent acted with routines, but the demo holds the primitive actions of the raw env.
    assert demo.num_actions == 6
    assert demo.actions.max() < 6
    assert demo.meta["mode"] == "rapl"
    assert demo.meta["trained_steps"] >= 100
    assert len(demo.meta["candidates"]["seeds"]) == 2  # best of 2 episodes
    result = replay(demo)
    assert result.matched
    np.testing.assert_array_equal(result.scores, demo.scores)


def test_save_model_writes_a_loadable_state_dict(rapl_a2c, tmp_path):
    folder = run(rapl_a2c, tmp_path, env_id="MiniQbert-v0", mode="a2c", total_timesteps=20,
                 save_model=True)
    state = torch.load(folder / "model.pt", weights_only=True)
    assert state["actor.weight"].shape[0] == 6  # MiniQbert's 6 actions, no routines


@pytest.mark.parametrize("mode", ["a2c", "rapl"])
def test_both_update_forwards_give_the_same_first_update(rapl_a2c, tmp_path, mode):
    # The first rollout draws the same actions either way (acting samples the same); its
    # update's losses come from the acting graphs or from one batched pass over the rollout,
    # the same numbers (the network applied to each state alone). Later updates differ by
    # float rounding of the gradient only (tests/test_rapl_a2c_update.py).
    first = {}
    for forward in ("acting", "rollout"):
        folder = run(rapl_a2c, tmp_path / forward, env_id="MinAtar/Breakout-v1", mode=mode,
                     seed=3, num_envs=4, total_timesteps=40, update_forward=forward,
                     scalars_every=1)
        values = scalars(folder)
        first[forward] = {tag: values[tag][0] for tag in ("losses/value_loss",
                                                          "losses/policy_loss",
                                                          "losses/entropy",
                                                          "losses/prim_value_loss")}
    # Up to float32 rounding: one batched pass and 5 small ones may pick different BLAS
    # kernels (a2c's policy loss differed by 1.4e-7 in 0.0296, 4.7e-6 relative, on this
    # machine at 07ce218 already).
    assert first["acting"] == pytest.approx(first["rollout"], rel=2e-5, abs=1e-7)
    assert first["acting"]["losses/value_loss"] > 0
