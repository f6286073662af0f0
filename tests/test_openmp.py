"""The scripts shorten OpenMP's spin before torch loads it (`routine_gym.plumbing.openmp`): the
call comes first in every script, importing the module loads no torch, a script's process
runs with `GOMP_SPINCOUNT=10000`, and a user's own spin or wait policy is left alone."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

from routine_gym.plumbing.openmp import SPIN_COUNT, shorten_spin

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "algos").glob("*.py"))


def test_a_users_choice_wins():
    assert shorten_spin(env := {}) and env == {"GOMP_SPINCOUNT": SPIN_COUNT}
    assert not shorten_spin(env := {"GOMP_SPINCOUNT": "5"}) and env == {"GOMP_SPINCOUNT": "5"}
    assert not shorten_spin(env := {"OMP_WAIT_POLICY": "ACTIVE"})
    assert env == {"OMP_WAIT_POLICY": "ACTIVE"}


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_every_script_sets_the_spin_before_anything_imports_torch(script):
    body = [node for node in ast.parse(script.read_text()).body
            if not (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant))
            and not (isinstance(node, ast.ImportFrom) and node.module == "__future__")]
    first, second = body[0], body[1]
    assert isinstance(first, ast.ImportFrom) and first.module == "routine_gym.plumbing.openmp"
    assert isinstance(second, ast.Expr) and ast.unparse(second) == "shorten_spin()"


def _spin_seen_by(code: str, **extra_env: str) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "OMP_WAIT_POLICY")}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT, env={**env, **extra_env})
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_importing_the_module_loads_no_torch():
    code = ("import sys; import routine_gym.plumbing.openmp; "
            "print('torch' in sys.modules)")
    assert _spin_seen_by(code) == "False"


def test_a_script_process_runs_with_the_short_spin_unless_the_user_chose():
    # The script's module top runs (its imports, not its main); then the process's environment.
    code = ("import os, runpy; runpy.run_path('algos/bc.py', run_name='not_main'); "
            "print(os.environ.get('GOMP_SPINCOUNT'))")
    assert _spin_seen_by(code) == SPIN_COUNT
    assert _spin_seen_by(code, OMP_WAIT_POLICY="PASSIVE") == "None"
    assert _spin_seen_by(code, GOMP_SPINCOUNT="77") == "77"
