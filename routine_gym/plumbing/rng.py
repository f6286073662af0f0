"""Random-number-generator state for checkpoints, in a form `torch.load(weights_only=True)` reads.

A resumed run should draw the same random numbers it would have drawn had it never stopped:
Python's `random`, NumPy's global generator, an optional `np.random.Generator` the script owns,
and torch's CPU generator. The states are kept as tensors, lists and strings only, so the
checkpoint needs no unpickling of arbitrary objects.

Example:
    >>> import numpy as np
    >>> generator = np.random.default_rng(0)
    >>> state = rng_state(generator)
    >>> a = generator.integers(1_000_000)
    >>> set_rng_state(state, generator)
    >>> bool(generator.integers(1_000_000) == a)
    True
"""

from __future__ import annotations

import json
import random
from typing import Any

import numpy as np
import torch

__all__ = ["rng_state", "seed_and_tune", "set_rng_state"]


def rng_state(generator: np.random.Generator | None = None) -> dict[str, Any]:
    """Python, NumPy (global and `generator`) and torch RNG states, weights_only-safe."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()  # noqa: NPY002
    py_version, py_state, py_gauss = random.getstate()
    state: dict[str, Any] = {
        "python": [py_version, list(py_state), py_gauss],
        "numpy": [kind, torch.from_numpy(keys.astype(np.int64)), pos, has_gauss, cached],
        "torch": torch.get_rng_state(),
    }
    if generator is not None:
        # A PCG64 state holds 128-bit integers; JSON keeps them exactly.
        state["generator"] = json.dumps(generator.bit_generator.state)
    return state


def set_rng_state(state: dict[str, Any], generator: np.random.Generator | None = None) -> None:
    """Restore what :func:`rng_state` saved; `generator` gets the saved generator's state."""
    py_version, py_state, py_gauss = state["python"]
    random.setstate((py_version, tuple(py_state), py_gauss))
    kind, keys, pos, has_gauss, cached = state["numpy"]
    keys = keys.numpy().astype(np.uint32)
    np.random.set_state((kind, keys, pos, has_gauss, cached))  # noqa: NPY002
    torch.set_rng_state(state["torch"])
    if generator is not None:
        if "generator" not in state:
            raise ValueError("the checkpoint has no generator state to restore")
        generator.bit_generator.state = json.loads(state["generator"])


def seed_and_tune(seed: int, torch_threads: int) -> None:
    """What `start_run` sets for the whole process, also what the benchmarks' workers set to time
    a script's work as the script runs it: Python's, NumPy's and torch's global seeds, no
    checking of distribution arguments, torch's threads (`torch_threads` > 0; 0 leaves torch's
    own count) and freed memory kept for reuse (`routine_gym.plumbing.memory`)."""
    random.seed(seed)
    np.random.seed(seed)  # noqa: NPY002  (libraries draw from the global RNG)
    torch.manual_seed(seed)
    # The scripts build their distributions from network outputs that are valid by
    # construction; checking them costs about a tenth of a MinAtar step (sampling is the same).
    torch.distributions.Distribution.set_default_validate_args(False)
    if torch_threads > 0:
        torch.set_num_threads(torch_threads)
    from routine_gym.plumbing.memory import keep_freed_memory

    keep_freed_memory()  # a minibatch's blocks are reused, not page-faulted in again
