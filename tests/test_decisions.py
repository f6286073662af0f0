"""Demo format version 2: which steps the demonstrator decided and which a wrapper injected.

The recorder learns it from a `DecisionMarker` at the agent-facing top of the stack; every
reader of a demo's actions (miners, SQIL's demo buffer, BC/GAIL pairs, the alignment score)
uses the decisions only; `routine-gym upgrade` re-derives them for a version-1 file.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import routine_gym  # noqa: F401  (registers the envs)
from routine_gym.cli import main as cli_main
from routine_gym.demo import (
    DecisionMarker,
    Demo,
    DemoRecorder,
    demo_file_version,
    record_agent_demo,
    replay,
)
from routine_gym.envs.atari import FireOnLifeLoss, FireReset, NoopReset
from routine_gym.envs.factory import default_env_kwargs, preprocess
from routine_gym.imitation import build_demo_transitions, decision_steps
from routine_gym.library import RoutineLibrary
from routine_gym.metrics import alignment_score
from routine_gym.mining import SequiturMiner
from routine_gym.plumbing.evaluation import evaluate_policy
from routine_gym.wrapper import RoutineActionWrapper

QBERT = "ALE/Qbert-v5"


def _write_v1(demo_path: Path, out: Path) -> None:
    """`demo_path` rewritten as format version 1: no decisions array, version 1 in meta."""
    with np.load(demo_path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files if name != "decisions"}
    meta = json.loads(str(arrays["meta"][()]))
    meta["version"] = 1
    meta.pop("recorded_under", None)
    arrays["meta"] = np.array(json.dumps(meta))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    out.write_bytes(buffer.getvalue())


def _tiny_demo(actions, decisions, terminated_at=None):
    n = len(actions)
    terminated = np.zeros(n, bool)
    terminated[n - 1 if terminated_at is None else terminated_at] = True
    return Demo(actions=np.array(actions), rewards=np.zeros(n), terminated=terminated,
                truncated=np.zeros(n, bool), episode_lengths=np.array([n]),
                decisions=np.array(decisions, bool), meta={"num_actions": 6})


# -- the recorder and the marker --------------------------------------------------------------


def test_steps_taken_in_reset_and_after_a_served_life_are_injected():
    # Breakout: a no-op start, FIRE, then the agent's steps; when a life is lost the
    # evaluation stack serves the next one with NOOP and FIRE inside the same agent step.
    recorder = DemoRecorder(gym.make("ALE/Breakout-v5", frameskip=4), record_observations=False)
    env = DecisionMarker(FireReset(FireOnLifeLoss(NoopReset(recorder, noop_max=5))))
    env.reset(seed=1)
    episode = recorder._current
    opening = len(episode.actions)
    assert 2 <= opening <= 6 and episode.actions[-1] == 1  # 1–5 NOOPs, then FIRE
    decided = 0
    while not recorder.num_episodes:
        env.step(3)  # LEFT every step: the ball is never returned, every life is lost
        decided += 1
    demo = recorder.demo()
    served = demo.decisions[opening:]
    assert demo.decisions[:opening].tolist() == [False] * opening
    assert demo.num_decisions == decided
    # 5 lives: each of the first 4 lost lives is served with NOOP, FIRE (injected).
    assert demo.num_injected - opening == 8
    injected_after = np.flatnonzero(~served) + opening
    assert demo.actions[injected_after].tolist() == [0, 1] * 4
    assert demo.meta["recorded_under"] == ["NoopReset", "FireOnLifeLoss", "FireReset"]


def test_each_primitive_of_a_chosen_routine_is_a_decision():
    recorder = DemoRecorder(gym.make("MiniQbert-v0"), record_observations=False)
    env = RoutineActionWrapper(DecisionMarker(recorder), [[2, 3, 2]])
    env.reset(seed=0)
    env.step(6)  # the routine: 3 primitive steps
    env.step(1)
    demo = recorder.demo(include_unfinished=True)
    assert demo.actions.tolist()[:4] == [2, 3, 2, 1][: len(demo)]
    assert demo.decisions.all()


def test_a_recorder_without_a_marker_records_every_step_as_a_decision():
    recorder = DemoRecorder(gym.make("ALE/Breakout-v5", frameskip=4), record_observations=False)
    env = FireReset(recorder)  # no marker: the recorder cannot tell the FIRE apart (v1 habit)
    env.reset(seed=0)
    env.step(2)
    assert recorder.demo(include_unfinished=True).decisions.tolist() == [True, True]


def test_a_marker_needs_a_recorder_below_it():
    with pytest.raises(ValueError, match="needs a DemoRecorder below it"):
        DecisionMarker(gym.make("CartPole-v1"))
    recorder = DemoRecorder(gym.make("CartPole-v1"))
    DecisionMarker(recorder)
    with pytest.raises(ValueError, match="already has a DecisionMarker"):
        DecisionMarker(recorder)


def test_routines_inside_wrap_env_are_refused():
    with pytest.raises(ValueError, match="pass the routines as"):
        record_agent_demo("MiniQbert-v0", lambda obs: 0, num_episodes=1, progress=False,
                          wrap_env=lambda env: RoutineActionWrapper(env, [[2, 3]]))


def test_decisions_survive_save_load_select_and_replay(tmp_path):
    demo = record_agent_demo(
        QBERT, lambda obs: 3, num_episodes=2, seed=4, env_kwargs=default_env_kwargs(QBERT),
        max_steps=80, progress=False, keep="all",
        wrap_env=lambda env: preprocess(env, QBERT, training=False),
    )
    assert demo.num_injected > 0
    demo.save(tmp_path / "d.npz")
    loaded = Demo.load(tmp_path / "d.npz")
    np.testing.assert_array_equal(loaded.decisions, demo.decisions)
    np.testing.assert_array_equal(loaded.select([1]).decisions, demo.episode(1).decisions)
    np.testing.assert_array_equal(replay(loaded).demo.decisions, demo.decisions)


def test_a_version_1_file_loads_with_every_step_a_decision(tmp_path):
    demo = _tiny_demo([0, 1, 2, 2], [0, 0, 1, 1])
    demo.save(tmp_path / "v2.npz")
    _write_v1(tmp_path / "v2.npz", tmp_path / "v1.npz")
    assert demo_file_version(tmp_path / "v1.npz") == 1
    loaded = Demo.load(tmp_path / "v1.npz")
    assert loaded.decisions.tolist() == [True] * 4
    assert loaded.meta["version"] == 2  # what it would be saved as


# -- the readers use decisions only --------------------------------------------------------


def test_an_injected_step_splits_the_mined_sequence():
    # 2 3 2 3 | 0 (injected) | 2 3 2 3: counted overlapping, "3 2 3" occurs once per side
    # (twice), never across the injected NOOP; "2 3 2 3" occurs twice; with the NOOP a
    # decision the sequence 2 3 2 3 0 2 3 2 3 would also hold "2 3 0 2 ...".
    demo = _tiny_demo([2, 3, 2, 3, 0, 2, 3, 2, 3], [1, 1, 1, 1, 0, 1, 1, 1, 1])
    library = SequiturMiner(num_routines=1).mine(demo)
    assert library.routines == ((2, 3, 2, 3),)
    assert library.frequencies == (2,)
    assert library.occurrences == (((0, 0), (0, 5)),)  # demo steps, the NOOP counted


def test_demo_buffer_has_a_transition_per_decision_and_routines_index_decisions():
    # Steps:      0  1  2  3  4  5  6
    # actions:    0  1  2  3  0  2  3     decisions: F F T T F T T (terminates at step 6)
    # Decisions d0..d3 = 2 3 2 3 with states s0..s3 and the final state s4.
    demo = _tiny_demo([0, 1, 2, 3, 0, 2, 3], [0, 0, 1, 1, 0, 1, 1])
    steps = decision_steps(demo)
    assert steps.lengths.tolist() == [4]
    assert steps.index.tolist() == [-1, -1, 0, 1, -1, 2, 3]
    assert steps.terminated.tolist() == [False, False, False, True]
    library = RoutineLibrary(routines=((2, 3),), scores=(2.2,), frequencies=(2,),
                             occurrences=(((0, 2), (0, 5)),), params={},
                             source={"env_id": None, "seeds": [None], "scores": [0.0]})
    states = np.arange(5, dtype=np.float32)[:, None]
    buffer = build_demo_transitions(demo, states, gamma=0.5, library=library, num_primitives=6)
    assert buffer.actions.tolist() == [2, 3, 2, 3, 6, 6]
    assert buffer.state_index.tolist() == [0, 1, 2, 3, 0, 2]
    assert buffer.next_state_index.tolist() == [1, 2, 3, 4, 2, 4]
    assert buffer.terminated.tolist() == [False, False, False, True, False, True]
    assert buffer.rewards.tolist() == [1, 1, 1, 1, 1.5, 1.5]  # R_sq = 1 + 0.5 for ℓ = 2


def test_a_library_mined_before_the_steps_were_marked_is_located_afresh():
    # Occurrence (0, 0) covers the two injected steps: the buffer finds (0, 2) and (0, 5).
    demo = _tiny_demo([2, 3, 2, 3, 0, 2, 3], [0, 0, 1, 1, 0, 1, 1])
    library = RoutineLibrary(routines=((2, 3),), scores=(3.2,), frequencies=(3,),
                             occurrences=(((0, 0), (0, 2), (0, 5)),), params={},
                             source={"env_id": None, "seeds": [None], "scores": [0.0]})
    buffer = build_demo_transitions(demo, np.zeros((5, 1)), 0.9, library, num_primitives=6)
    assert buffer.state_index[buffer.is_routine].tolist() == [0, 2]


@pytest.mark.slow
def test_the_alignment_compares_decisions_only():
    # Qbert's shipped demo: ι_d is its 789 decisions (the 26-step no-op start and FIRE left out);
    # an agent that always goes UP has ι_t = UP × its decisions, its own injected no-ops and
    # FIRE left out too.
    from routine_gym.demo import shipped_demo_path

    demo = Demo.load(shipped_demo_path(QBERT))
    summary = evaluate_policy(QBERT, lambda obs: 2, episodes=1, seed=7, demo=demo, max_steps=120)
    reference = demo.decision_actions()[0]
    assert summary["demo_length"] == demo.num_decisions == len(reference) == 789
    (decided,) = summary["decisions"]
    assert decided < summary["lengths"][0]  # its no-op start and FIRE were injected
    assert summary["alignments"][0] == pytest.approx(alignment_score(reference, [2] * decided))


# -- routine-gym upgrade ---------------------------------------------------------------------


@pytest.mark.slow
def test_upgrade_gives_the_file_a_fresh_recording_gives(tmp_path, capsys):
    # A real Qbert episode recorded through the Atari evaluation stack (no-op start, FIRE, and
    # served lives: a random player loses lives fast), as rapl_a2c.py --record-demo does.
    rng = np.random.default_rng(5)
    fresh = record_agent_demo(
        QBERT, lambda obs: int(rng.integers(6)), num_episodes=1, seed=11,
        env_kwargs=default_env_kwargs(QBERT), max_steps=500, progress=False,
        wrap_env=lambda env: preprocess(env, QBERT, training=False),
    )
    first = int(np.argmax(fresh.decisions))
    assert first >= 2 and (~fresh.decisions[first:]).sum() >= 2  # a start and a served life
    fresh.save(tmp_path / "fresh.npz")
    _write_v1(tmp_path / "fresh.npz", tmp_path / "v1.npz")

    assert cli_main(["upgrade", str(tmp_path / "v1.npz"), "--out", str(tmp_path / "up.npz")]) == 0
    assert "'agent' preprocessing" in capsys.readouterr().out
    upgraded, original = Demo.load(tmp_path / "up.npz"), Demo.load(tmp_path / "fresh.npz")
    for name in ("actions", "rewards", "terminated", "truncated", "decisions",
                 "episode_lengths"):
        np.testing.assert_array_equal(getattr(upgraded, name), getattr(original, name), name)
    extra = {"upgraded_from_version", "recorded_under_stack"}
    assert {k: v for k, v in upgraded.meta.items() if k not in extra} == original.meta
    assert upgraded.meta["upgraded_from_version"] == 1


@pytest.mark.slow
def test_upgrade_refuses_a_demo_the_preprocessing_does_not_replay(tmp_path):
    # Recorded on the raw env (no no-op start): replaying it under the agent's stack diverges.
    demo = record_agent_demo(QBERT, lambda obs: 3, num_episodes=1, seed=2,
                             env_kwargs=default_env_kwargs(QBERT), max_steps=60,
                             progress=False)
    demo.save(tmp_path / "raw.npz")
    _write_v1(tmp_path / "raw.npz", tmp_path / "v1.npz")
    before = (tmp_path / "v1.npz").read_bytes()
    with pytest.raises(SystemExit) as exit_info:
        cli_main(["upgrade", str(tmp_path / "v1.npz"), "--preprocessing", "agent"])
    assert exit_info.value.code == 2
    assert (tmp_path / "v1.npz").read_bytes() == before  # nothing written
    # auto falls through to the raw stack: every step a decision.
    assert cli_main(["upgrade", str(tmp_path / "v1.npz")]) == 0
    upgraded = Demo.load(tmp_path / "v1.npz")
    assert upgraded.num_injected == 0 and upgraded.meta["recorded_under_stack"] == "raw"
