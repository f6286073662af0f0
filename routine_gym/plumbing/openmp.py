"""OpenMP's spinning threads against ale-py's emulator threads: a shorter spin for the scripts.

With two or more torch threads, torch's OpenMP runtime (GNU libgomp in the Linux wheels) keeps
its worker threads spinning after each parallel region, 300,000 turns by default, so that the
next region starts at once. Between two network passes a training script steps its envs; on
Atari those are ale-py's C++ games, one thread each (`routine_gym.envs.atari_vector`), and on a
machine of few cores the spinning workers take the cores they need: on this project's 2-core
machine a 16-env `ALE/Qbert-v5` step took 4.4 ms inside training against 2.8 ms alone.
`GOMP_SPINCOUNT=10000` keeps the workers spinning across back-to-back operations of one pass
(the network-only bound is as fast as with the default) and frees the cores soon after the last:
`rapl_a2c.py --mode a2c` on Qbert made ~1,680 agent steps/s instead of ~1,330 (README, Benchmarks).

libgomp reads `GOMP_SPINCOUNT` once, when torch loads it, so the training scripts call
`shorten_spin()` before they import torch (called later, it changes nothing in the running
process; its child processes get the setting). A user's own `GOMP_SPINCOUNT` or
`OMP_WAIT_POLICY` is left as it is; other OpenMP runtimes ignore the variable.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

__all__ = ["SPIN_COUNT", "shorten_spin"]

#: The spin of libgomp's idle workers that the scripts set (libgomp's default: 300,000).
SPIN_COUNT = "10000"


def shorten_spin(environ: MutableMapping[str, str] = os.environ) -> bool:
    """Set `GOMP_SPINCOUNT` to `SPIN_COUNT` in `environ` unless the user chose a spin or a wait
    policy; whether it was set.

    Example:
        >>> env = {}
        >>> shorten_spin(env), env
        (True, {'GOMP_SPINCOUNT': '10000'})
        >>> shorten_spin({"OMP_WAIT_POLICY": "PASSIVE"})
        False
    """
    if "GOMP_SPINCOUNT" in environ or "OMP_WAIT_POLICY" in environ:
        return False
    environ["GOMP_SPINCOUNT"] = SPIN_COUNT
    return True

