"""Importing the light parts of routine-gym loads neither ALE nor Procgen (nor torch)."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("module", ["routine_gym", "routine_gym.metrics", "routine_gym.sequitur",
                                    "routine_gym.mining", "routine_gym.demo"])
def test_importing_does_not_load_ale_or_procgen(module):
    code = (f"import sys, {module}\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('ale_py', 'procgen', 'torch')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_register_envs_adds_ale():
    code = ("import gymnasium as gym, routine_gym\n"
            "before = 'ALE/Qbert-v5' in gym.registry\n"
            "routine_gym.register_envs()\n"
            "print(before, 'ALE/Qbert-v5' in gym.registry, 'MiniQbert-v0' in gym.registry)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.split() == ["False", "True", "True"]
