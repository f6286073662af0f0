"""Reference scores: how each game's scores are normalised (SPEC §8).

Human-normalised with the published table where the env's profile has a key in it (Atari), else
demo-normalised `(score − random)/(demo − random)` with the shipped demo's best episode and the
uniformly random policy's mean score (played once, cached in `reference_scores.json`), else
left raw (and out of the aggregates).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from routine_gym.experiments import json_kind, read_json_object
from routine_gym.experiments.results import is_number
from routine_gym.plumbing.atomic import atomic_write_text
from routine_gym.plumbing.errors import UsageError

__all__ = ["REFERENCE_EPISODES", "REFERENCE_SEED", "Reference", "demo_score",
           "random_policy_scores", "reference_scores"]

#: Episodes and first seed of the random policy behind a demo-normalised score.
REFERENCE_EPISODES = 10
REFERENCE_SEED = 0


class Reference(NamedTuple):
    """How a game's scores are normalised: `kind` is `"human"` (the published table, under
    `key`), `"demo"` (`(score − random)/(demo − random)`) or `"raw"` (not normalised)."""

    kind: str
    random: float | None = None
    top: float | None = None  # the human score or the demo's
    key: str | None = None
    note: str = ""

    def normalise(self, score: float) -> float:
        if self.kind == "human":
            from routine_gym.metrics import human_normalized_score

            return float(human_normalized_score(score, self.key))
        if self.kind == "demo":
            return (float(score) - self.random) / (self.top - self.random)
        return float(score)


def random_policy_scores(env_id: str, episodes: int, seed: int) -> dict[str, Any]:
    """The uniformly random policy's scores
    (`routine_gym.plumbing.evaluation.random_policy_scores`)."""
    from routine_gym.plumbing.evaluation import random_policy_scores as play

    return play(env_id, episodes, seed)


def demo_score(env_id: str, demo_set: str = "current") -> float | None:
    """The score of the best episode of `env_id`'s shipped demo in `demo_set`, or None
    without one."""
    from routine_gym.demo import Demo, shipped_demo_path

    path = shipped_demo_path(env_id, demo_set)
    if path is None:
        return None
    demo = Demo.load(path)
    return float(demo.scores[demo.best_episode])


def _human_key(env_id: str) -> str | None:
    from routine_gym.envs import profile_for
    from routine_gym.metrics import atari_game_name

    key = profile_for(env_id).score_key(env_id)
    if key is None:
        return None
    try:
        atari_game_name(key)
    except ValueError:
        return None  # an Atari game outside the published table
    return key


def _read_cache(cache: Path) -> dict[str, Any]:
    """The random-policy cache `reference_scores.json`, checked: UsageError naming it."""
    hint = "delete it: the next report plays the random policy again"
    stored = read_json_object(cache, hint)
    envs = stored.get("envs", {})
    if not isinstance(envs, dict):
        raise UsageError(f"{cache}: `envs` is {json_kind(envs)}, not an object; {hint}")
    for env_id, entry in envs.items():
        if not isinstance(entry, dict):
            raise UsageError(f"{cache}: `envs.{env_id}` is {json_kind(entry)}, not an object; "
                             f"{hint}")
        random = entry.get("random")
        if random is not None and (not is_number(random) or not math.isfinite(random)):
            raise UsageError(f"{cache}: `envs.{env_id}.random` is {random!r}, not a finite "
                             f"number; {hint}")
    return stored


def reference_scores(env_ids: Iterable[str], cache: str | Path, demo_set: str = "current",
                     episodes: int = REFERENCE_EPISODES) -> dict[str, Reference]:
    """Each env's `Reference`, written to `cache` (JSON); a random-policy score already there
    (same episodes and seed) is reused rather than played again.

    Args:
        env_ids: the games to normalise.
        cache: the JSON file of the random policy's scores (and the references used).
        demo_set: the shipped demos (`routine_gym.demo.DEMO_SETS`) whose best episode is a
            demo-normalised game's top: a budget's `demo_set`.
        episodes: the random policy's episodes (a budget's `reference_episodes`).
    """
    from routine_gym.metrics import HUMAN_RANDOM_SCORES, atari_game_name

    cache = Path(cache)
    cached: dict[str, Any] = {}
    if cache.exists():
        stored = _read_cache(cache)
        if (stored.get("episodes"), stored.get("seed")) == (episodes, REFERENCE_SEED):
            cached = stored.get("envs", {})
    references: dict[str, Reference] = {}
    for env_id in sorted(set(env_ids)):
        key = _human_key(env_id)
        if key is not None:
            random, human = HUMAN_RANDOM_SCORES[atari_game_name(key)]
            references[env_id] = Reference("human", random, human, key)
            continue
        demo = demo_score(env_id, demo_set)
        if demo is None:
            references[env_id] = Reference("raw", note="no shipped demo and no published table")
            continue
        random = cached.get(env_id, {}).get("random")
        if random is None:
            random = random_policy_scores(env_id, episodes, REFERENCE_SEED)["mean"]
        random = float(random)
        if math.isclose(demo, random):
            references[env_id] = Reference("raw", random, demo,
                                           note="the demo scores as the random policy")
        else:
            references[env_id] = Reference("demo", random, demo)
    envs = {env_id: {"normalisation": ref.kind, "random": ref.random, "reference": ref.top,
                     "score_key": ref.key, "note": ref.note}
            for env_id, ref in references.items()}
    stored = {"episodes": episodes, "seed": REFERENCE_SEED, "envs": {**cached, **envs}}
    if demo_set != "current":  # the committed caches of the first protocol stay as they were
        stored["demo_set"] = demo_set
    atomic_write_text(cache, json.dumps(stored, indent=2) + "\n")
    return references
