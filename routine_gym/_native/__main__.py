"""`python -m routine_gym._native`: which compiled cores this install runs, one line each (what
`make` prints after installing; a core not built runs its Python twin, docs/native.md)."""

from __future__ import annotations

import sys
import warnings

from routine_gym import _native
from routine_gym.errors import UsageError


def main() -> None:
    """Print each core and whether `core(name)` finds it, or why not; a `ROUTINE_GYM_NATIVE`
    naming something else is one line and exit code 2, as everywhere else."""
    try:
        _native.enabled(_native.CORES[0])  # reads the variable: a bad value was a traceback
    except UsageError as exc:
        print(f"python -m routine_gym._native: error: {exc}", file=sys.stderr)
        sys.exit(2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reason is printed instead
        for name in _native.CORES:
            reason = _native.unavailable(name)
            print(f"compiled core {name}: " + ("built, in use" if reason is None else
                                               f"not in use: {reason}"))


if __name__ == "__main__":
    main()
