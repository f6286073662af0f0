"""The demonstration suite shipped with routine-gym, and where its files are."""

from __future__ import annotations

import os

import routine_gym

#: Where the shipped demonstrations live. The repository's top-level `demos/` folder is installed
#: as `routine_gym/demos/` (package data, mapped in pyproject.toml); an editable install or a
#: source checkout has no such folder and reads `demos/` in place, next to the package.
# The package is `routine_gym` itself, not this module's folder (its `demo/` subpackage).
_PACKAGE_DIR = os.path.dirname(os.path.abspath(routine_gym.__file__))
DEMOS_DIR = os.path.join(_PACKAGE_DIR, "demos")
if not os.path.isdir(DEMOS_DIR):
    DEMOS_DIR = os.path.join(os.path.dirname(_PACKAGE_DIR), "demos")


#: The demonstration suite shipped in `demos/`: the paper's Atari games, CoinRun and MinAtar's
#: five games, one trained agent's demo each. `routine-gym show-demos` lists it; the scripts
#: default to it.
DEMO_SUITE: tuple[str, ...] = (
    "ALE/Qbert-v5",
    "ALE/Breakout-v5",
    "ALE/SpaceInvaders-v5",
    "ALE/BeamRider-v5",
    "ALE/Seaquest-v5",
    "ALE/MsPacman-v5",
    "procgen/CoinRun-v0",
    "MinAtar/Asterix-v1",
    "MinAtar/Breakout-v1",
    "MinAtar/Freeway-v1",
    "MinAtar/Seaquest-v1",
    "MinAtar/SpaceInvaders-v1",
)


def demo_filename(env_id: str) -> str:
    """The file name of `env_id`'s shipped demo: `ALE/Qbert-v5` → `ALE-Qbert-v5.npz`."""
    return env_id.replace("/", "-") + ".npz"


def shipped_demo_path(env_id: str) -> str | None:
    """The path of the demo shipped in `demos/` for `env_id`, or None if there is none."""
    from routine_gym.envs import canonical_env_id

    path = os.path.join(DEMOS_DIR, demo_filename(canonical_env_id(env_id)))
    return path if os.path.isfile(path) else None
