"""`python -m routine_gym._native`: which compiled cores this install runs, one line each (what
`make` prints after installing; a core not built runs its Python twin, docs/native.md)."""

from __future__ import annotations

import warnings

from routine_gym import _native


def main() -> None:
    """Print each core and whether `core(name)` finds it, or why not."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the reason is printed instead
        for name in _native.CORES:
            reason = _native.unavailable(name)
            print(f"compiled core {name}: " + ("built, in use" if reason is None else
                                               f"not in use: {reason}"))


if __name__ == "__main__":
    main()
