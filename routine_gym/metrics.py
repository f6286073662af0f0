"""Evaluation metrics of the paper (SPEC §5): alignment, human-normalised score, relative
performance, and the interquartile mean.

All functions are pure (numpy and rapidfuzz; `iqm` is rliable's) so they can be checked with
hand-computed numbers:

- `alignment_score(demo, agent) = 1 − Levenshtein(ι_d, ι_t) / |ι_d|`, the agent's primitive
  action trajectory cut or padded to the demonstration's length;
- `human_normalized_score(score, game) = (score − random) / (human − random)` with the
  standard per-game table `HUMAN_RANDOM_SCORES`;
- `relative_performance(S_R, S_A) = (S_R − S_A) / |S_A|`;
- `iqm(values)`, rliable's interquartile mean (the 25 % trimmed mean).

Confidence intervals, performance profiles and probabilities of improvement are rliable's own,
used by the experiment report (`routine_gym.experiments.report`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import NamedTuple

import numpy as np
from rapidfuzz.distance import Levenshtein

# Matches no action: actions are ids ≥ 0, so every padded slot costs one substitution.
PAD_ACTION = -1

#: The longest demonstration the evaluation aligns with in full (`max_length`): the
#: Levenshtein distance costs ~n²/64 steps, 0.1 s at this length but 50 s an episode against a
#: demo of 1.5 million decisions. Every shipped demo is shorter than 3,000 decisions.
ALIGNMENT_MAX_LENGTH = 50_000


def _action_sequence(actions: Sequence[int] | np.ndarray, name: str) -> list[int]:
    arr = np.asarray(actions)
    if arr.ndim != 1:
        raise ValueError(f"{name} needs to be a 1-D sequence of action ids, got shape {arr.shape}")
    if arr.size == 0:
        return []
    if not (np.issubdtype(arr.dtype, np.integer) or arr.dtype == np.bool_):
        raise TypeError(f"{name} needs integer action ids, got dtype {arr.dtype}")
    if arr.min() < 0:
        raise ValueError(f"{name} contains a negative action id: {int(arr.min())}")
    return arr.astype(np.int64).tolist()


def alignment_score(
    demo_actions: Sequence[int] | np.ndarray, agent_actions: Sequence[int] | np.ndarray,
    max_length: int | None = None,
) -> float:
    """How closely the agent's actions follow the demonstration: `1 − Lev(ι_d, ι_t) / |ι_d|`.

    The agent's trajectory `ι_t` is cut to the demonstration's length `|ι_d|`, or padded to it
    with `PAD_ACTION`, which matches no action. Both sequences then have length `|ι_d|`, so
    the Levenshtein distance is at most `|ι_d|` and the score lies in `[0, 1]`: 1 for an
    identical prefix, 0 for an empty agent trajectory. With `max_length`, a longer
    demonstration is first cut to its first `max_length` actions (the time is then bounded:
    see `ALIGNMENT_MAX_LENGTH`).

    Example:
        >>> alignment_score([0, 1, 2, 3], [0, 1, 3])  # [0,1,3,-1]: delete 2, insert -1
        0.5
        >>> alignment_score([0, 1, 2, 3], [1, 2, 3, 0])  # delete the leading 0, append one
        0.5
        >>> alignment_score([0, 1, 2, 3], [0, 1, 3], max_length=2)  # [0, 1] against [0, 1]
        1.0

    Raises:
        ValueError: for an empty demonstration, negative ids or a sequence that is not 1-D.
        TypeError: for non-integer ids.
    """
    if max_length is not None:
        if max_length < 1:
            raise ValueError(f"max_length needs to be ≥ 1, actual value: {max_length}")
        demo_actions = np.asarray(demo_actions)[:max_length]
        agent_actions = np.asarray(agent_actions)[:max_length]
    demo = _action_sequence(demo_actions, "demo_actions")
    agent = _action_sequence(agent_actions, "agent_actions")
    if not demo:
        raise ValueError("demo_actions is empty: the alignment score needs |ι_d| ≥ 1")
    n = len(demo)
    agent = agent[:n] + [PAD_ACTION] * max(0, n - len(agent))
    return 1.0 - Levenshtein.distance(demo, agent) / n


class GameScores(NamedTuple):
    """Reference scores of one Atari game: a uniformly random agent and a human tester."""

    random: float
    human: float


# Random and human scores of the 57 Atari games, as used by DQN (Mnih et al., 2015), Rainbow,
# Agent57 and rliable. Numbers from DeepMind's DQN Zoo `dqn_zoo/atari_data.py`; the human
# column is identical in rliable's tables. Random scores differ only for VideoPinball, where
# DQN Zoo (and the Nature DQN paper) give 16256.9 and the MuZero/rliable tables give 0.0;
# this table keeps DQN Zoo's value.
_SCORES: dict[str, tuple[float, float]] = {
    "Alien": (227.8, 7127.7),
    "Amidar": (5.8, 1719.5),
    "Assault": (222.4, 742.0),
    "Asterix": (210.0, 8503.3),
    "Asteroids": (719.1, 47388.7),
    "Atlantis": (12850.0, 29028.1),
    "BankHeist": (14.2, 753.1),
    "BattleZone": (2360.0, 37187.5),
    "BeamRider": (363.9, 16926.5),
    "Berzerk": (123.7, 2630.4),
    "Bowling": (23.1, 160.7),
    "Boxing": (0.1, 12.1),
    "Breakout": (1.7, 30.5),
    "Centipede": (2090.9, 12017.0),
    "ChopperCommand": (811.0, 7387.8),
    "CrazyClimber": (10780.5, 35829.4),
    "Defender": (2874.5, 18688.9),
    "DemonAttack": (152.1, 1971.0),
    "DoubleDunk": (-18.6, -16.4),
    "Enduro": (0.0, 860.5),
    "FishingDerby": (-91.7, -38.7),
    "Freeway": (0.0, 29.6),
    "Frostbite": (65.2, 4334.7),
    "Gopher": (257.6, 2412.5),
    "Gravitar": (173.0, 3351.4),
    "Hero": (1027.0, 30826.4),
    "IceHockey": (-11.2, 0.9),
    "Jamesbond": (29.0, 302.8),
    "Kangaroo": (52.0, 3035.0),
    "Krull": (1598.0, 2665.5),
    "KungFuMaster": (258.5, 22736.3),
    "MontezumaRevenge": (0.0, 4753.3),
    "MsPacman": (307.3, 6951.6),
    "NameThisGame": (2292.3, 8049.0),
    "Phoenix": (761.4, 7242.6),
    "Pitfall": (-229.4, 6463.7),
    "Pong": (-20.7, 14.6),
    "PrivateEye": (24.9, 69571.3),
    "Qbert": (163.9, 13455.0),
    "Riverraid": (1338.5, 17118.0),
    "RoadRunner": (11.5, 7845.0),
    "Robotank": (2.2, 11.9),
    "Seaquest": (68.4, 42054.7),
    "Skiing": (-17098.1, -4336.9),
    "Solaris": (1236.3, 12326.7),
    "SpaceInvaders": (148.0, 1668.7),
    "StarGunner": (664.0, 10250.0),
    "Surround": (-10.0, 6.5),
    "Tennis": (-23.8, -8.3),
    "TimePilot": (3568.0, 5229.2),
    "Tutankham": (11.4, 167.6),
    "UpNDown": (533.4, 11693.2),
    "Venture": (0.0, 1187.5),
    "VideoPinball": (16256.9, 17667.9),
    "WizardOfWor": (563.5, 4756.5),
    "YarsRevenge": (3092.9, 54576.9),
    "Zaxxon": (32.5, 9173.3),
}

HUMAN_RANDOM_SCORES: Mapping[str, GameScores] = MappingProxyType(
    {game: GameScores(*scores) for game, scores in _SCORES.items()}
)
"""Read-only `{game: GameScores(random, human)}` for the 57 Atari games, keyed by ALE's names."""

# Lower-case names without separators, so "Qbert", "qbert" and DQN Zoo's "bank_heist" resolve.
_BY_KEY = {game.lower(): game for game in HUMAN_RANDOM_SCORES}
_VERSION = re.compile(r"-v\d+$")
_VARIANTS = ("noframeskip", "deterministic", "-ram")


def atari_game_name(env_id: str) -> str:
    """The `HUMAN_RANDOM_SCORES` key of an Atari env id or game name.

    `"ALE/Qbert-v5"`, `"QbertNoFrameskip-v4"`, `"Qbert-ram-v5"`, `"qbert"` → `"Qbert"`;
    `"bank_heist"` (DQN Zoo's spelling) → `"BankHeist"`.

    Raises:
        ValueError: naming the id when it is not one of the 57 games (e.g. `"MiniQbert-v0"`).
        TypeError: when `env_id` is not a string.
    """
    if not isinstance(env_id, str):
        raise TypeError(f"env_id needs to be a string, got {env_id!r}")
    name = env_id.split("/")[-1]
    name = _VERSION.sub("", name).lower()
    key = name.replace("_", "").replace(" ", "")
    if key not in _BY_KEY:
        # Strip gym's variant suffixes ("QbertNoFrameskip", "Qbert-ram", "QbertDeterministic").
        for variant in _VARIANTS:
            key = key.replace(variant, "")
        key = key.replace("-", "")
    if key not in _BY_KEY:
        raise ValueError(
            f"{env_id!r} is not one of the 57 Atari games with published human and random "
            f"scores (e.g. 'ALE/Qbert-v5' or 'Qbert')"
        )
    return _BY_KEY[key]


def human_normalized_score(score: float | np.ndarray, game_or_env_id: str) -> float | np.ndarray:
    """`(score − random) / (human − random)` for an Atari game: 0 is random play, 1 is human.

    `game_or_env_id` is a game name or env id (see `atari_game_name`). An array of scores
    gives an array; a number gives a float.

    Example:
        >>> round(human_normalized_score(13455.0, "ALE/Qbert-v5"), 6)
        1.0

    Raises:
        ValueError: for a game outside the table.
    """
    random, human = HUMAN_RANDOM_SCORES[atari_game_name(game_or_env_id)]
    normalized = (np.asarray(score, dtype=np.float64) - random) / (human - random)
    return float(normalized) if normalized.ndim == 0 else normalized


def relative_performance(score_rapl: float, score_baseline: float) -> float:
    """Relative improvement of RAPL over a baseline: `(S_R − S_A) / |S_A|`.

    Dividing by `|S_A|` keeps the sign meaningful for negative baseline scores (Pong, Skiing):
    a positive value always means RAPL scored higher.

    Example:
        >>> relative_performance(150.0, 100.0), relative_performance(-10.0, -20.0)
        (0.5, 0.5)

    Raises:
        ValueError: when the baseline score is 0 (the ratio is undefined) or a score is not
            finite.
    """
    s_r, s_a = float(score_rapl), float(score_baseline)
    if not (math.isfinite(s_r) and math.isfinite(s_a)):
        raise ValueError(f"scores need to be finite, got S_R={s_r!r}, S_A={s_a!r}")
    if s_a == 0.0:
        raise ValueError(
            "score_baseline is 0: the relative performance (S_R − S_A)/|S_A| is undefined"
        )
    return (s_r - s_a) / abs(s_a)


def _finite_array(values: np.ndarray | Sequence[float], name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        raise ValueError(f"{name} is empty")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def iqm(values: np.ndarray | Sequence[float]) -> float:
    """Interquartile mean: the mean of the middle 50 % of all values (any shape, flattened).

    Same definition as rliable's `aggregate_iqm`, i.e. `scipy.stats.trim_mean(x, 0.25)`:
    `⌊n/4⌋` values are dropped from each end of the sorted values, so for fewer than 4 values
    it is the plain mean.

    Example:
        >>> iqm([1, 2, 3, 4, 5, 6, 7, 8])  # mean of 3, 4, 5, 6
        4.5

    Raises:
        ValueError: for no values, or NaN/infinite values.
    """
    from rliable.metrics import aggregate_iqm  # imported here: rliable loads scipy and arch

    return float(aggregate_iqm(_finite_array(values, "values").ravel()))
