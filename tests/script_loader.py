"""Import the training scripts of `algos/` as modules (they are files, not a package).

The test files import this module by name: pytest puts `tests/` on `sys.path`.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ALGOS = Path(__file__).resolve().parent.parent / "algos"


def load_script(name: str, module_name: str | None = None) -> ModuleType:
    """Execute `algos/{name}.py` as the module `module_name` (default `algos_{name}`).

    A distinct `module_name` gives a test file its own copy to monkeypatch.
    """
    module_name = module_name or f"algos_{name}"
    spec = importlib.util.spec_from_file_location(module_name, ALGOS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module
