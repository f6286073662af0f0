"""The one evaluation of every training script, and its `eval.json`.

`evaluate_policy` runs a trained policy for full episodes on the env's evaluation view (no
training-only wrappers: no life-loss episodes, no reward clipping; Procgen on unseen levels
when the caller passes them) with a `DemoRecorder` under the preprocessing and a
`DecisionMarker` over it, so each episode's return is the game's score and its decided
*primitive* action trajectory (a routine decision counted as its executed primitive actions,
the steps the preprocessing injects left out) is known. Given the demo, each trajectory is
aligned with the demo's best episode (the alignment score of SPEC §5). `save_evaluation`
writes the summary as the run's `eval.json` and TensorBoard's `eval/*` scalars.

`eval.json` (every script): `env_id`, `episodes`, `seed`, `returns`, `lengths` (primitive
steps, injected ones included), `decisions` (decided primitive steps), `mean_return`,
`std_return`, `env_kwargs`; with a demo `alignments`, `mean_alignment`, `std_alignment`,
`demo_score`, `demo_length` (its best episode's decisions), and `aligned_length` when a demo
longer than `ALIGNMENT_MAX_LENGTH` decisions is aligned over its first ones only (the time of
an alignment grows as the square of the length); `human_normalized_score` where the
env's profile has a published table (Atari); and what the script adds (`method`,
`global_step`, ...).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import RecordEpisodeStatistics

from routine_gym.atomic import atomic_write_text
from routine_gym.demo import Demo, record_agent_demo
from routine_gym.demo.collect import _policy_caller
from routine_gym.envs import profile_for
from routine_gym.envs.factory import default_env_kwargs, preprocess
from routine_gym.library import RoutineLibrary
from routine_gym.metrics import ALIGNMENT_MAX_LENGTH, alignment_score, human_normalized_score

__all__ = ["evaluate_policy", "save_evaluation"]


#: The evaluation episodes `--capture-video` films (a GIF of a long Atari game is megabytes).
VIDEO_EPISODES = 3


def evaluate_policy(
    env_id: str,
    policy: Callable[[np.ndarray], int],
    episodes: int,
    seed: int,
    *,
    demo: Demo | None = None,
    routines: RoutineLibrary | Sequence[Sequence[int]] | None = None,
    env_kwargs: dict[str, Any] | None = None,
    max_steps: int | None = None,
    video_folder: str | None = None,
    stop_rule: Any = None,
) -> dict[str, Any]:
    """Run `policy` for `episodes` full episodes; score them and, with a demo, align them.

    Args:
        env_id: the env.
        policy: maps an observation of the agent's view to an action of `Discrete(n + K)`;
            called as `policy(obs, env)` when it has two required positional parameters.
        episodes: episodes to run, reset with seeds `seed, seed + 1, …`.
        seed: the first reset seed.
        demo: the demonstration whose best episode is the reference trajectory `ι_d` of the
            alignment score (None: no alignment).
        routines: the routines the policy can choose (None: primitives only).
        env_kwargs: `gym.make` keyword arguments (default: the demo's, else none), over the
            env's defaults.
        max_steps: cap on the primitive steps of an episode (None: the env's own limit).
        video_folder: film the first `VIDEO_EPISODES` episodes into
            `{video_folder}/eval-episode-{k}.gif`, each frame captioned with the primitive
            action or the routine step it executes (`routine_gym.video`); the env must render
            RGB frames.
        stop_rule: the stop rule the policy was trained under (`--interrupt`'s
            `PolicyStopRule`): its routines stop where it says, as in training, and the summary
            counts `interruptions` (None: every routine runs to its end).

    Returns:
        The JSON-able summary of the module docstring.
    """
    if episodes < 1:
        raise ValueError(f"episodes needs to be ≥ 1, actual value: {episodes}")
    if env_kwargs is None:
        env_kwargs = demo.env_kwargs if demo is not None else {}
    kwargs = {**default_env_kwargs(env_id), **env_kwargs}

    films = None

    def wrap(env: gym.Env) -> gym.Env:
        nonlocal films
        if video_folder is not None:
            from routine_gym.video import FrameRecorder

            # On the recorded env: the same primitive steps as the demo of the episodes.
            # Frames wait on disk beside the GIFs, not in memory (routine_gym.video).
            env = films = FrameRecorder(env, record=lambda episode: episode < VIDEO_EPISODES,
                                        spool_dir=video_folder)
        return preprocess(RecordEpisodeStatistics(env), env_id, training=False)

    choices: list[list[int]] = []  # the policy's decisions, per episode (for the captions)
    # Filming wraps the policy: the wrapper takes `(obs, env)` and calls the policy as
    # `record_agent_demo` would have (`policy(obs, env)` when it takes two arguments, as the
    # option policies of compile_a2c.py and option_critic.py do).
    call = _policy_caller(policy)

    def act(obs: np.ndarray, env: gym.Env) -> int:
        action = int(np.asarray(call(obs, env)).reshape(-1)[0])
        while len(choices) <= films.episode:
            choices.append([])
        choices[films.episode].append(action)
        return action

    stopped_before = getattr(stop_rule, "interruptions", 0)
    played = record_agent_demo(
        env_id, policy if video_folder is None else act, num_episodes=episodes, seed=seed,
        env_kwargs=kwargs if video_folder is None else {**kwargs, "render_mode": "rgb_array"},
        keep="all", max_steps=max_steps, progress=False, wrap_env=wrap, routines=routines,
        stop_rule=stop_rule,
    )
    if video_folder is not None:
        _write_videos(video_folder, played, films, choices, routines, env_id)
    trajectories = played.decision_actions()
    returns = played.scores.tolist()
    summary: dict[str, Any] = {
        "env_id": env_id,
        "episodes": episodes,
        "seed": seed,
        "returns": returns,
        "lengths": played.episode_lengths.tolist(),
        "decisions": [len(a) for a in trajectories],
        "mean_return": float(np.mean(returns)),
        "std_return": float(np.std(returns)),
        "env_kwargs": kwargs,
    }
    if stop_rule is not None and hasattr(stop_rule, "interruptions"):
        summary["interruptions"] = int(stop_rule.interruptions - stopped_before)
    if demo is not None:
        # ι_d and ι_t: the demonstrator's and the agent's decided primitive actions (a routine
        # as its executed primitives), without the steps the preprocessing injected into either.
        reference = demo.decision_actions()[demo.best_episode]
        alignments = [alignment_score(reference, actions, ALIGNMENT_MAX_LENGTH)
                      for actions in trajectories]
        summary.update(
            alignments=alignments,
            mean_alignment=float(np.mean(alignments)),
            std_alignment=float(np.std(alignments)),
            demo_score=float(demo.scores[demo.best_episode]),
            demo_length=len(reference),
        )
        if len(reference) > ALIGNMENT_MAX_LENGTH:
            summary["aligned_length"] = ALIGNMENT_MAX_LENGTH
    score_key = profile_for(env_id).score_key(env_id)
    if score_key is not None:
        try:
            summary["human_normalized_score"] = float(
                human_normalized_score(summary["mean_return"], score_key)
            )
        except ValueError:
            pass  # a game outside the published table
    return summary


def _write_videos(folder: str, played: Demo, films: Any, choices: list[list[int]],
                  routines: RoutineLibrary | Sequence[Sequence[int]] | None, env_id: str) -> None:
    """Each filmed evaluation episode as `{folder}/eval-episode-{k}.gif`, captioned."""
    from routine_gym.video import step_captions, write_gif

    fps = (films.metadata or {}).get("render_fps") or 15
    for k, (frames, _) in enumerate(films.episodes):
        episode = played.episode(k)
        captions = step_captions(episode.actions, episode.decisions, choices[k],
                                 played.num_actions, routines, played.action_meanings)
        captions.append(f"end of episode {k}: return {episode.score:g}")
        write_gif(frames, captions, os.path.join(folder, f"eval-episode-{k}.gif"), fps=fps)
        frames.close()
    print(f"{env_id}: {len(films.episodes)} evaluation video(s) in {folder}", flush=True)


def save_evaluation(summary: dict[str, Any], run_path: str, writer: Any, global_step: int,
                    name: str = "eval") -> None:
    """Write `{name}.json` (atomically) and the `{name}/*` TensorBoard scalars; print one
    line."""
    atomic_write_text(os.path.join(run_path, f"{name}.json"), json.dumps(summary, indent=2) + "\n")
    writer.add_scalar(f"{name}/mean_return", summary["mean_return"], global_step)
    line = (f"{name} over {summary['episodes']} episodes: return {summary['mean_return']:.1f} ± "
            f"{summary['std_return']:.1f}")
    if "mean_alignment" in summary:
        writer.add_scalar(f"{name}/mean_alignment", summary["mean_alignment"], global_step)
        writer.add_scalar(f"{name}/std_alignment", summary["std_alignment"], global_step)
        line += (f", alignment {summary['mean_alignment']:.3f} ± "
                 f"{summary['std_alignment']:.3f}")
    if "human_normalized_score" in summary:
        writer.add_scalar(f"{name}/human_normalized_score", summary["human_normalized_score"],
                          global_step)
        line += f", human-normalised {summary['human_normalized_score']:.1%}"
    print(line, flush=True)


#: The levels the CoinRun expert trains and records on (`rapl_a2c.py`'s defaults): the random
#: policy is scored there too.
TRAIN_LEVELS = {"num_levels": 100, "start_level": 0, "distribution_mode": "easy"}


def random_policy_scores(env_id: str, episodes: int, seed: int) -> dict[str, Any]:
    """Score and length of `episodes` full games of the uniformly random policy in the primitive
    env demos are recorded in (`make_primitive_env`; Procgen on the training levels), episode
    `k` reset with seed `seed + k`.

    Returns:
        `env_id, env_kwargs, episodes, seed, scores, lengths, mean, std, mean_length`.
    """
    from routine_gym.envs.factory import make_primitive_env

    kwargs = TRAIN_LEVELS if profile_for(env_id).has_levels else {}
    env = make_primitive_env(env_id, **kwargs)
    env.action_space.seed(seed)
    scores, lengths = [], []
    try:
        for episode in range(episodes):
            env.reset(seed=seed + episode)
            score, length, done = 0.0, 0, False
            while not done:
                _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
                score += float(reward)
                length += 1
                done = terminated or truncated
            scores.append(score)
            lengths.append(length)
    finally:
        env.close()
    return {"env_id": env_id, "env_kwargs": dict(kwargs), "episodes": episodes, "seed": seed,
            "scores": scores, "lengths": lengths,
            "mean": float(np.mean(scores)), "std": float(np.std(scores)),
            "mean_length": float(np.mean(lengths))}
