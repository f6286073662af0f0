"""The CompILE baseline: its loss terms worked by hand, the segmentation of a synthetic demo of
known motifs (boundary precision and recall against chance), the option wrapper, and
`algos/compile_a2c.py` on every env family, killed and resumed."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from resume_checks import kill_after_first_checkpoint
from script_loader import load_script

from routine_gym.baselines.compile import (
    CompILE,
    CompILEConfig,
    CompILEOptions,
    OptionActionWrapper,
    Segmentation,
    boundary_mask,
    boundary_scores,
    kl_boundary,
    kl_latent_uniform,
    load_compile,
    most_used_codes,
    option_primitive_policy,
    poisson_length_log_prior,
    reconstruction_nll,
    save_compile,
    segment,
    segment_probabilities,
    train_compile,
)
from routine_gym.demo import record_agent_demo
from routine_gym.envs.factory import default_env_kwargs

pytestmark = pytest.mark.filterwarnings(
    "ignore::DeprecationWarning",
    # Tiny CompILE budgets on random demos may use fewer codes than K: the script says so.
    "ignore:the demo's segmentation uses .* code:UserWarning",
)


# -- the loss terms, by hand -------------------------------------------------------------------


def test_segment_masks_split_each_step_between_the_segments_around_a_soft_boundary():
    # L = 3, b_0 is position 1 or 2 with probability ½ each, b_1 the window's end. P(b_0 ≤ t) =
    # 0, ½, 1 for t = 0, 1, 2, so segment 0 holds the steps with 1, ½, 0 and segment 1 the rest.
    b = torch.tensor([[[0.0, 0.5, 0.5, 0.0]], [[0.0, 0.0, 0.0, 1.0]]])
    masks = segment_probabilities(b)
    assert masks[:, 0].tolist() == [[1.0, 0.5, 0.0], [0.0, 0.5, 1.0]]
    # A third segment after a boundary at the end is empty.
    b3 = torch.cat([b, torch.tensor([[[0.0, 0.0, 0.0, 1.0]]])])
    assert segment_probabilities(b3)[2, 0].tolist() == [0.0, 0.0, 0.0]


def test_the_next_boundary_is_masked_up_to_the_previous_one_but_the_end_stays_open():
    start = torch.tensor([[[1.0, 0.0, 0.0, 0.0, 0.0]]])
    # b_0 at 1 or 2 (½ each): P(b_0 < t) = 0, 0, ½, 1, 1.
    soft = torch.tensor([[[0.0, 0.5, 0.5, 0.0, 0.0]]])
    assert boundary_mask(torch.cat([start, soft])).tolist() == [[0.0, 0.0, 0.5, 1.0, 1.0]]
    # A boundary at the end leaves only the end for the next one.
    end = torch.tensor([[[0.0, 0.0, 0.0, 0.0, 1.0]]])
    assert boundary_mask(torch.cat([start, end])).tolist() == [[0.0, 0.0, 0.0, 0.0, 1.0]]


def test_reconstruction_nll_weights_each_step_by_its_segment_probability():
    # Two segments, two steps, actions 0 then 1. Under z_0 the decoder gives them ½ and ¼,
    # under z_1 0.8 and ½; step 0 is in segment 0, step 1 half in each:
    # −(log ½ + ½ log ¼ + ½ log ½) = (1 + 1 + ½) log 2.
    probs = torch.tensor([[[[0.5, 0.5], [0.75, 0.25]]], [[[0.8, 0.2], [0.5, 0.5]]]])
    nll = reconstruction_nll(torch.log(probs), torch.tensor([[0, 1]]),
                             torch.tensor([[[1.0, 0.5]], [[0.0, 0.5]]]))
    assert float(nll) == pytest.approx(2.5 * math.log(2))


def test_latent_kl_against_the_uniform_prior():
    # q = (½, ¼, ¼): ½ log ½ + ½ log ¼ + log 3 = log 3 − 1.5 log 2.
    q = torch.tensor([0.5, 0.25, 0.25])
    assert float(kl_latent_uniform(torch.log(q))) == pytest.approx(math.log(3) - 1.5 * math.log(2))
    assert float(kl_latent_uniform(torch.zeros(5))) == pytest.approx(0.0, abs=1e-7)


def test_the_poisson_prior_counts_lengths_from_the_segment_start():
    # λ = 2, L = 3. From 0: lengths 1, 2, 3 ∝ 2¹/1!, 2²/2!, 2³/3! = 2, 2, 4/3 → 3/8, 3/8, 1/4.
    # From 1: lengths 1, 2 at positions 2, 3 ∝ 2, 2 → ½, ½. From L: the empty segment, p(L) = 1.
    p = poisson_length_log_prior(4, torch.tensor([0, 1, 3]), 2.0).exp()
    np.testing.assert_allclose(p.numpy(), [[0, 3 / 8, 3 / 8, 1 / 4], [0, 0, 0.5, 0.5],
                                           [0, 0, 0, 1]], atol=1e-6)


def test_boundary_kl_against_the_poisson_prior():
    start = torch.tensor([0])
    certain = torch.tensor([[-1e9, 50.0, -1e9, -1e9]])  # surely length 1, prior 3/8
    assert float(kl_boundary(certain, start, 2.0)[0]) == pytest.approx(math.log(8 / 3), rel=1e-5)
    # q uniform over positions 1–3: ⅓ (2 log(⅓ / ⅜) + log(⅓ / ¼)) = ⅓ (2 log 8/9 + log 4/3).
    uniform = torch.tensor([[-1e9, 0.0, 0.0, 0.0]])
    expected = (2 * math.log(8 / 9) + math.log(4 / 3)) / 3
    assert float(kl_boundary(uniform, start, 2.0)[0]) == pytest.approx(expected, rel=1e-4)
    # An empty segment at the window's end costs nothing.
    at_end = torch.tensor([[-1e9, -1e9, -1e9, 0.0]])
    assert float(kl_boundary(at_end, torch.tensor([3]), 2.0)[0]) == pytest.approx(0.0, abs=1e-6)
    # The positions the prior rules out (−inf) leave the gradient finite.
    logits = torch.zeros(1, 4, requires_grad=True)
    kl_boundary(logits, torch.tensor([1]), 2.0).sum().backward()
    assert torch.isfinite(logits.grad).all()


def test_the_negative_elbo_is_the_nll_plus_the_weighted_kls():
    config = CompILEConfig(env_id="CartPole-v1", obs_shape=(4,), obs_dtype="float32",
                           num_actions=2, num_segments=3, window=6, hidden_dim=16,
                           beta_b=0.3, beta_z=0.2)
    torch.manual_seed(0)
    model = CompILE(config)
    features = model.features(torch.randn(2 * 6, 4)).view(2, 6, -1)
    actions = torch.randint(0, 2, (2, 6))
    recognition = model.recognise(features, actions)
    terms = model.negative_elbo(features, actions, recognition)
    assert terms["loss"].item() == pytest.approx(
        (terms["nll"] + 0.2 * terms["kl_z"] + 0.3 * terms["kl_b"]).item())
    assert recognition.boundaries.shape == (3, 2, 7)
    # Boundaries lie after the previous one; every step is in one hard segment.
    hard = model.recognise(features, actions, hard=True)
    cuts = hard.boundaries.argmax(dim=-1)  # [M, B]
    assert (cuts[1:] >= cuts[:-1]).all() and (cuts[0] >= 1).all() and (cuts[-1] == 6).all()
    np.testing.assert_allclose(segment_probabilities(hard.boundaries).sum(0).numpy(), 1.0)


def test_most_used_codes_and_boundary_scores():
    s = Segmentation(episodes=np.zeros(6, int), starts=np.array([0, 2, 5, 6, 9, 10]),
                     lengths=np.array([2, 3, 1, 3, 1, 2]), codes=np.array([3, 1, 3, 1, 5, 1]))
    assert most_used_codes(s, 2) == [1, 3]
    assert most_used_codes(s, 5) == [1, 3, 5]
    assert s.boundaries().tolist() == [2, 5, 6, 9, 10]
    # Each true boundary is matched once: 5 and 6 cannot both match 5.
    assert boundary_scores([5, 6], [5], tolerance=1) == (0.5, 1.0)
    assert boundary_scores([], [3]) == (0.0, 0.0)


# -- segmentation of a demo of known motifs -----------------------------------------------------

#: Three motifs of 3–5 actions over 6 actions. Each uses its own two actions, and the states
#: carry no information: the structure is in the actions alone, as in the reference code's toy.
#: (A state showing the previous action would let the decoder chain its way across any cut, so
#: the ELBO could not tell the true boundaries from shifted ones.)
MOTIFS = ((0, 1, 0), (2, 3, 3, 2), (4, 5, 5, 4, 5))


def motif_demo(num_motifs: int, seed: int):
    """Motifs in random order, never the same twice in a row (two in a row are one segment to
    any segmenter); the states, one before each action and a final one, and the true starts."""
    rng = np.random.default_rng(seed)
    order = [int(rng.integers(len(MOTIFS)))]
    for _ in range(num_motifs - 1):
        order.append((order[-1] + int(rng.integers(1, len(MOTIFS)))) % len(MOTIFS))
    actions = np.concatenate([MOTIFS[m] for m in order]).astype(np.int64)
    starts = np.cumsum([0] + [len(MOTIFS[m]) for m in order])[:-1]
    states = np.zeros((len(actions) + 1, 4), dtype=np.float32)
    return states, actions, starts


def chance_scores(num_predicted: int, true: np.ndarray, length: int, tolerance: int,
                  rng: np.random.Generator, draws: int = 200) -> tuple[float, float]:
    """Precision and recall of as many boundaries drawn uniformly at random (no repeats)."""
    scores = [boundary_scores(np.sort(rng.choice(np.arange(1, length), num_predicted,
                                                 replace=False)), true, tolerance)
              for _ in range(draws)]
    return tuple(np.mean(scores, axis=0))


def test_compile_finds_the_boundaries_of_known_motifs_well_above_chance(capsys):
    states, actions, starts = motif_demo(100, seed=0)
    # Windows of 12 decisions (12 / λ = 3 motifs of the prior's mean length) in M = 5 segments,
    # a smaller copy of the script's 32 in 10.
    config = CompILEConfig(env_id="CartPole-v1", obs_shape=(4,), obs_dtype="float32",
                           num_actions=6, num_latents=8, num_segments=5, window=12,
                           hidden_dim=64)
    model, log = train_compile(states, actions, [len(actions)], config, iterations=300,
                               batch_size=32, learning_rate=3e-3, seed=0, log_every=100)
    assert [entry["iteration"] for entry in log] == [100, 200, 300]
    assert all(math.isfinite(entry["loss"]) for entry in log)
    segmentation = segment(model, states, actions, [len(actions)])
    # A partition of the demo into contiguous segments.
    assert segmentation.starts[0] == 0 and segmentation.lengths.sum() == len(actions)
    np.testing.assert_array_equal(segmentation.starts[1:], np.cumsum(segmentation.lengths)[:-1])

    predicted, true = segmentation.boundaries(), starts[1:]
    rng = np.random.default_rng(1)
    report = []
    for tolerance in (0, 1):
        precision, recall = boundary_scores(predicted, true, tolerance)
        chance_p, chance_r = chance_scores(len(predicted), true, len(actions), tolerance, rng)
        report.append(f"±{tolerance}: precision {precision:.2f} (chance {chance_p:.2f}), "
                      f"recall {recall:.2f} (chance {chance_r:.2f})")
        # Exactly placed, chance is about one boundary in four positions (motifs of 3–5); within
        # ±1 step, three positions in four are near a true boundary.
        margin = 0.35 if tolerance == 0 else 0.15
        assert precision >= chance_p + margin and recall >= chance_r + margin, report[-1]
    with capsys.disabled():
        print(f"\nCompILE on {len(true)} motif boundaries: " + "; ".join(report))


# -- the option wrapper -------------------------------------------------------------------------


class ScriptedOptions:
    """Option 0 pushes right and ends after `ends_after` steps; option 1 pushes towards the
    pole's lean and never ends by itself. Counts its calls."""

    codes = (4, 7)

    def __init__(self, ends_after: int = 3) -> None:
        self.ends_after = ends_after
        self.run = 0

    def __len__(self) -> int:
        return 2

    def evaluate(self, obs, k):
        if k == 0:
            self.run += 1
            # Called once before each step and once on the state reached: the state after step
            # `ends_after` is the call number ends_after + 1.
            done = self.run > self.ends_after
            if done:
                self.run = 0
            return 1, float(done)
        return int(obs[2] > 0), 0.0


def test_an_option_runs_until_its_termination_head_fires():
    env = OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(ends_after=3),
                              max_length=6)
    assert env.action_space == gym.spaces.Discrete(4)
    assert env.get_action_meanings() == ["0", "1", "O0:z4", "O1:z7"]
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step(2)
    assert (reward, info["routine_length"], info["routine_index"]) == (3.0, 3, 0)
    assert info["routine_actions"].tolist() == [1, 1, 1, -1, -1, -1]
    assert info["routine_rewards"].tolist() == [1.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    assert not info["routine_terminated"].any() and not info["routine_truncated"].any()
    # A primitive is an option of length 1, with the same keys.
    _, reward, _, _, info = env.step(0)
    assert (reward, info["routine_length"], info["routine_index"]) == (1.0, 1, -1)
    assert info["routine_actions"].tolist() == [0, -1, -1, -1, -1, -1]


def test_an_option_stops_at_max_length_and_never_ends_before_its_first_step():
    env = OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(ends_after=10),
                              max_length=4)
    env.reset(seed=0)
    assert env.step(2)[4]["routine_length"] == 4

    class EndsEverywhere(ScriptedOptions):
        def evaluate(self, obs, k):
            return 0, 1.0

    env = OptionActionWrapper(gym.make("CartPole-v1"), EndsEverywhere(), max_length=4)
    env.reset(seed=0)
    assert env.step(3)[4]["routine_length"] == 1


def test_an_option_stops_early_when_the_episode_ends():
    # Pushing right for ever topples CartPole after about ten steps: the option stops there.
    env = OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(ends_after=100),
                              max_length=50)
    env.reset(seed=0)
    _, reward, terminated, truncated, info = env.step(2)
    length = info["routine_length"]
    assert terminated and not truncated and 1 < length < 50 and reward == length
    assert info["routine_terminated"].tolist() == [j == length - 1 for j in range(50)]
    assert (info["routine_actions"][length:] == -1).all()


def test_option_infos_stack_in_a_vector_env_with_same_step_autoreset():
    def make():
        return OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(ends_after=100),
                                   max_length=50)

    envs = gym.vector.SyncVectorEnv([make, make],
                                    autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    envs.reset(seed=0)
    _, rewards, terminated, _, info = envs.step(np.array([2, 0]))
    # Env 0's option toppled the pole: its step's info moved to final_info.
    assert terminated.tolist() == [True, False]
    final = info["final_info"]
    assert final["routine_rewards"].shape == (2, 50) and final["_routine_length"].tolist() == [
        True, False]
    assert final["routine_length"][0] == rewards[0]
    assert info["routine_length"].tolist()[1] == 1 and info["routine_rewards"].shape == (2, 50)
    envs.close()


def test_the_wrapper_refuses_bad_envs_and_actions():
    with pytest.raises(TypeError, match="Discrete action space"):
        OptionActionWrapper(gym.make("Pendulum-v1"), ScriptedOptions(), max_length=3)
    with pytest.raises(ValueError, match="max_length needs to be ≥ 1, actual value: 0"):
        OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(), max_length=0)
    env = OptionActionWrapper(gym.make("CartPole-v1"), ScriptedOptions(), max_length=3)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="outside the action space Discrete"):
        env.step(4)


def test_the_evaluation_policy_plays_the_options_as_the_wrapper_does():
    # The same controller (primitive, then each option in turn) through the wrapper and through
    # option_primitive_policy: the same primitive actions, episode after episode.
    def controller_factory():
        count = iter(range(10**6))
        return lambda obs: (0, 2, 3, 1)[next(count) % 4]

    wrapped = OptionActionWrapper(gym.wrappers.RecordEpisodeStatistics(gym.make("CartPole-v1")),
                                  ScriptedOptions(ends_after=2), max_length=5)
    through_wrapper = []
    controller = controller_factory()
    for seed in (0, 1):
        obs, _ = wrapped.reset(seed=seed)
        done = False
        while not done:
            obs, _, terminated, truncated, info = wrapped.step(controller(obs))
            through_wrapper += info["routine_actions"][: info["routine_length"]].tolist()
            done = terminated or truncated

    env = gym.wrappers.RecordEpisodeStatistics(gym.make("CartPole-v1"))
    policy = option_primitive_policy(controller_factory(), ScriptedOptions(ends_after=2), 5, 2)
    through_policy = []
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            action = policy(obs, env)
            through_policy.append(action)
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
    assert through_policy == through_wrapper


def test_compile_options_act_greedily_on_one_thread_and_survive_saving(tmp_path):
    config = CompILEConfig(env_id="CartPole-v1", obs_shape=(4,), obs_dtype="float32",
                           num_actions=2, num_latents=3, hidden_dim=16)
    torch.manual_seed(0)
    model = CompILE(config)
    options = CompILEOptions(model, [2, 0])
    obs = np.array([0.1, -0.2, 0.05, 0.3], dtype=np.float32)
    threads = torch.get_num_threads()
    action, beta = options.evaluate(obs, 0)
    assert torch.get_num_threads() == threads
    with torch.no_grad():
        features = model.features(torch.as_tensor(obs[None]))
        z = torch.eye(3)[[2]]
        assert action == int(model.policy_logits(features, z).argmax())
        assert beta == pytest.approx(float(torch.sigmoid(model.termination_logits(features, z))))
    save_compile(tmp_path / "compile_model.pt", model, {"codes": [2, 0]})
    loaded, meta = load_compile(tmp_path / "compile_model.pt")
    assert meta == {"codes": [2, 0]} and loaded.config == config
    assert CompILEOptions(loaded, [2, 0]).evaluate(obs, 0) == (action, beta)
    with pytest.raises(ValueError, match="code 3 is not one of the model's 3 latent codes"):
        CompILEOptions(model, [3])


# -- the script --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def compile_a2c():
    yield load_script("compile_a2c", "compile_a2c")
    sys.modules.pop("compile_a2c", None)


def record_random_demo(env_id: str, num_actions: int, path: Path, **kwargs) -> str:
    rng = np.random.default_rng(0)
    demo = record_agent_demo(env_id, lambda obs: int(rng.integers(num_actions)),
                             env_kwargs=default_env_kwargs(env_id), progress=False, **kwargs)
    demo.save(path, include_observations=False)
    return str(path)


@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("demos")


TINY = dict(num_envs=2, total_timesteps=100, eval_episodes=0, log_every=10**9,
            compile_iterations=3, compile_batch_size=4, compile_option_steps=2)


def run(module, run_dir: Path, **kwargs) -> Path:
    """`main(Args(...))` with tiny budgets; returns the run folder it created."""
    before = set(run_dir.iterdir()) if run_dir.exists() else set()
    module.main(module.Args(**{**TINY, "run_dir": str(run_dir), **kwargs}))
    (folder,) = set(run_dir.iterdir()) - before
    return folder


def scalars(folder: Path) -> dict[str, list[float]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    acc.Reload()
    return {tag: [e.value for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def check_run_folder(folder: Path, num_actions: int) -> dict:
    """compile_model.pt (loadable without unpickling, K options) and the logged keys."""
    model, meta = load_compile(folder / "compile_model.pt")
    assert model.config.num_actions == num_actions
    assert 1 <= len(meta["codes"]) <= 3 and meta["max_length"] >= 2
    logged = scalars(folder)
    for tag in ("charts/SPS", "charts/learning_rate", "losses/value_loss", "losses/policy_loss",
                "losses/entropy", "options/primitive_usage", "options/usage_0", "compile/loss"):
        assert tag in logged, f"{tag} not logged; got {sorted(logged)}"
    usage = np.sum([logged[f"options/usage_{k}"] for k in range(len(meta["codes"]))], axis=0)
    np.testing.assert_allclose(usage + np.asarray(logged["options/primitive_usage"]), 1.0)
    return meta


def test_the_script_runs_on_cartpole_and_evaluates(compile_a2c, tmp_path, demo_dir):
    demo = record_random_demo("CartPole-v1", 2, demo_dir / "cartpole.npz", num_episodes=3)
    folder = run(compile_a2c, tmp_path, env_id="CartPole-v1", demo=demo, eval_episodes=2)
    meta = check_run_folder(folder, num_actions=2)
    summary = json.loads((folder / "eval.json").read_text())
    assert summary["method"] == "compile" and summary["episodes"] == 2
    assert summary["option_codes"] == meta["codes"] and "mean_alignment" in summary
    # Every decided primitive step is counted, the options' included.
    assert summary["decisions"] == summary["lengths"]
    assert "charts/episodic_return" in scalars(folder)


def test_the_script_runs_on_minatar_breakout(compile_a2c, tmp_path, demo_dir):
    demo = record_random_demo("MinAtar/Breakout-v1", 3, demo_dir / "breakout.npz",
                              num_episodes=2)
    check_run_folder(run(compile_a2c, tmp_path, env_id="MinAtar/Breakout-v1", demo=demo),
                     num_actions=3)


def test_the_script_runs_on_miniqbert_with_its_shipped_demo(compile_a2c, tmp_path):
    meta = check_run_folder(run(compile_a2c, tmp_path, env_id="MiniQbert-v0"), num_actions=6)
    assert meta["demo"].endswith("demos/MiniQbert-v0.npz")


@pytest.mark.slow
@pytest.mark.parametrize("env_id, num_actions", [("ALE/Qbert-v5", 6), ("procgen/CoinRun-v0", 5)])
def test_the_script_runs_on_atari_and_procgen_with_their_shipped_demos(compile_a2c, tmp_path,
                                                                       env_id, num_actions):
    meta = check_run_folder(run(compile_a2c, tmp_path, env_id=env_id, compile_option_steps=1,
                                compile_batch_size=2, total_timesteps=40), num_actions)
    assert "demos/" in meta["demo"]


def test_bad_compile_flags_are_refused(compile_a2c, tmp_path):
    with pytest.raises(ValueError, match="--compile-window needs to be ≥ 1, actual value: 0"):
        run(compile_a2c, tmp_path, env_id="MiniQbert-v0", compile_window=0)
    with pytest.raises(ValueError, match="--num-options needs to be at most --compile-latents"):
        run(compile_a2c, tmp_path, env_id="MiniQbert-v0", num_options=9)


def test_a_bad_gru_choice_is_one_line_before_any_run_folder(tmp_path, repo_root):
    """`ROUTINE_GYM_COMPILE_GRU` is read before the run starts, as a user runs the script."""
    import os
    import subprocess

    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST")}
    env["ROUTINE_GYM_COMPILE_GRU"] = "fast"
    done = subprocess.run(
        [sys.executable, str(repo_root / "algos" / "compile_a2c.py"), "--env-id", "MiniQbert-v0",
         "--total-timesteps", "100"], capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env=env)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "compile_a2c.py: error: ROUTINE_GYM_COMPILE_GRU='fast': expected 'compiled' (the "
        "default) or 'torch'"]
    assert list(tmp_path.iterdir()) == []


def test_killed_run_resumes_with_its_own_options(compile_a2c, tmp_path, repo_root, monkeypatch,
                                                 capsys):
    command = [
        sys.executable, str(repo_root / "algos" / "compile_a2c.py"), "--env-id", "MiniQbert-v0",
        "--num-envs", "2", "--total-timesteps", "3000", "--checkpoint-every", "300",
        "--eval-episodes", "0", "--compile-iterations", "3", "--compile-batch-size", "4",
        "--compile-option-steps", "2", "--torch-threads", "1", "--run-dir", str(tmp_path),
    ]
    checkpoint_path = kill_after_first_checkpoint(command, tmp_path, timeout=90)
    killed_at = torch.load(checkpoint_path, weights_only=True)["global_step"]
    assert 300 <= killed_at < 3000
    saved_model, saved_meta = load_compile(checkpoint_path.parent / "compile_model.pt")

    def no_training(*args, **kwargs):
        raise AssertionError("a resumed run must reuse the checkpoint's CompILE model")

    monkeypatch.setattr(compile_a2c, "train_compile", no_training)
    compile_a2c.main(compile_a2c.Args(resume=str(checkpoint_path.parent)))
    assert f"resumed {checkpoint_path.parent.name} at step {killed_at}" in capsys.readouterr().out
    final = torch.load(checkpoint_path, weights_only=True)
    assert final["global_step"] >= 3000
    resumed_model, resumed_meta = compile_a2c.compile_from_state(final["compile"])
    assert resumed_meta["codes"] == saved_meta["codes"]
    for name, tensor in saved_model.state_dict().items():
        torch.testing.assert_close(resumed_model.state_dict()[name], tensor)


def test_a_seeded_fit_is_the_same_fit_on_two_threads():
    # The windows share states, so each state's features get the gradients of several
    # windows; the sum must not depend on which of the CPU's threads finishes first (indexing's
    # backward made every seeded fit of compile_a2c.py on MinAtar a different one).
    rng = np.random.default_rng(0)
    decisions = 80
    states = (rng.random((decisions + 1, 4, 10, 10)) < 0.1).astype(np.float32)
    actions = rng.integers(0, 3, decisions)
    # The script's windows (16 of 32 decisions: 512 rows of 128 features, enough for torch to
    # split the sum between threads), a smaller model.
    config = CompILEConfig(env_id="MinAtar/Breakout-v1", obs_shape=(4, 10, 10),
                           obs_dtype="float32", num_actions=3, num_segments=3, window=32,
                           hidden_dim=32)
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        fits = [train_compile(states, actions, [decisions], config, iterations=10,
                              batch_size=16, seed=3, log_every=5)
                for _ in range(3)]
    finally:
        torch.set_num_threads(threads)
    (first, first_log), *others = fits
    for model, log in others:
        assert log == first_log
        for (name, a), b in zip(first.state_dict().items(), model.state_dict().values(),
                                strict=True):
            assert torch.equal(a, b), name
