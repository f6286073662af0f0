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


#: The shipped demo sets: `current` (the files in `demos/`, what every script defaults to) and
#: the sets they replaced, each kept in a subfolder of `demos/` so that the runs made with it
#: stay reproducible. `first`: MinAtar's five demos of the first protocol (5M-step A2C experts,
#: 2026-12-01), replaced on 2026-12-06 by demos of 10M-step experts that score at least the
#: best any learner reached in the `long` sweep (issue 47). A set holds only the files that
#: changed; an env it lacks reads the current file.
DEMO_SETS: dict[str, str] = {"current": "", "first": "first"}


def demo_filename(env_id: str) -> str:
    """The file name of `env_id`'s shipped demo: `ALE/Qbert-v5` → `ALE-Qbert-v5.npz`."""
    return env_id.replace("/", "-") + ".npz"


def shipped_demo_path(env_id: str, demo_set: str = "current") -> str | None:
    """The path of the demo shipped for `env_id` in `demo_set` (`DEMO_SETS`: `current` is
    `demos/`, an older set its subfolder, falling back to `demos/` for an env the set did not
    change), or None if there is none.

    Raises:
        ValueError: `demo_set` is not one of `DEMO_SETS`.
    """
    from routine_gym.envs import canonical_env_id

    if demo_set not in DEMO_SETS:
        raise ValueError(f"unknown demo set {demo_set!r}; choose from {', '.join(DEMO_SETS)}")
    name = demo_filename(canonical_env_id(env_id))
    for folder in (os.path.join(DEMOS_DIR, DEMO_SETS[demo_set]), DEMOS_DIR):
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            return path
    return None


def demo_set_file(env_id: str, demo_set: str) -> str | None:
    """The file `demo_set` holds for `env_id` itself (not the current one it falls back to),
    as a path relative to `demos/` (`first/MinAtar-Breakout-v1.npz`), or None: the set has
    none, so `env_id` reads the current demo in that set too."""
    from routine_gym.envs import canonical_env_id

    if not DEMO_SETS.get(demo_set):
        return None
    relative = os.path.join(DEMO_SETS[demo_set], demo_filename(canonical_env_id(env_id)))
    return relative if os.path.isfile(os.path.join(DEMOS_DIR, relative)) else None
