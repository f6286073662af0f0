"""The compiled cores, and the one place that imports them: `core(name)`.

Each core is a C++ twin of a Python function that stays the reference and the fallback
(`docs/native.md` gives each one's twin, what it follows upstream, its measured gain on a
whole run and its tests):

- `sequitur` (`_sequitur.cpp`): `routine_gym.sequitur`'s grammar induction and expansion;
- `minatar_core` (`_minatar_core.cpp`): `routine_gym.envs.minatar_vector`'s games, ports of the
  Python games of `minatar` 1.0.15 (`MINATAR_VERSION`);
- `masked_gru` (`_masked_gru.cpp`): `routine_gym.baselines.compile.masked_gru`'s loops.

Every core is optional: `pip install` without a C++17 compiler skips it (and says so) and the
Python twin runs. `core(name)` returns the module, or None where the twin runs instead:

- the environment variable `ROUTINE_GYM_NATIVE` turns cores off. Unset, empty, `1` or `all`:
  every core that is built. `0` or `none`: none. Otherwise a comma-separated list of core names
  (`ROUTINE_GYM_NATIVE=sequitur,minatar_core`): those cores alone, the others off. It is read at
  every call, so a test may set it with `monkeypatch.setenv`. A name that is not a core is a
  `UsageError` (one line from a script or the CLI).
- a core that is not built (or fails to import) runs its twin, with one `RuntimeWarning` per
  process naming it (`ROUTINE_GYM_NATIVE=0` says the twin is wanted and silences it);
- a core that ports an upstream package (`UPSTREAM`) checks the installed version when it is
  first loaded: on any other version it runs the twin, with one `RuntimeWarning`.

Example:
    >>> import os
    >>> from routine_gym._native import CORES, enabled
    >>> CORES
    ('sequitur', 'minatar_core', 'masked_gru')
    >>> enabled("sequitur", "sequitur,masked_gru"), enabled("minatar_core", "sequitur,masked_gru")
    (True, False)
    >>> enabled("sequitur", "0"), enabled("sequitur", "")
    (False, True)
"""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import warnings
from types import ModuleType

from routine_gym.errors import UsageError

__all__ = ["CORES", "MINATAR_VERSION", "NATIVE_VARIABLE", "UPSTREAM", "core", "enabled",
           "installed_version", "unavailable"]

#: The environment variable that turns cores off (the module doc).
NATIVE_VARIABLE = "ROUTINE_GYM_NATIVE"

#: The cores, by the name `core` takes; core `x` is the extension `routine_gym._native._x`.
CORES = ("sequitur", "minatar_core", "masked_gru")

#: The MinAtar release whose Python games `_minatar_core.cpp` ports line for line (pyproject
#: pins it): its games' private variables and rules are what the core reads and plays.
MINATAR_VERSION = "1.0.15"

#: Per core that ports an upstream package: (distribution, the version it follows).
UPSTREAM: dict[str, tuple[str, str]] = {"minatar_core": ("minatar", MINATAR_VERSION)}

_ALL = ("", "1", "all")
_NONE = ("0", "none")

# name -> the module, or the reason it is not used (an import error, an upstream version).
_loaded: dict[str, ModuleType | str] = {}
_warned: set[str] = set()


def _wanted(value: str) -> set[str]:
    """The cores a `ROUTINE_GYM_NATIVE` value keeps on."""
    value = value.strip().lower()
    if value in _ALL:
        return set(CORES)
    if value in _NONE:
        return set()
    names = {part.strip() for part in value.split(",") if part.strip()}
    unknown = sorted(names - set(CORES))
    if unknown:
        raise UsageError(f"{NATIVE_VARIABLE}={value}: {', '.join(unknown)} is not a compiled "
                         f"core (the cores: {', '.join(CORES)}; 0 turns them all off)")
    return names


def enabled(name: str, value: str | None = None) -> bool:
    """Whether `ROUTINE_GYM_NATIVE` (or `value`, when given) leaves core `name` on.

    Raises:
        UsageError: the variable names something other than a core.
    """
    if name not in CORES:
        raise ValueError(f"no compiled core named {name!r} (the cores: {', '.join(CORES)})")
    return name in _wanted(os.environ.get(NATIVE_VARIABLE, "") if value is None else value)


def installed_version(distribution: str) -> str | None:
    """The installed version of `distribution` (None: not installed)."""
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


def _load(name: str) -> ModuleType | str:
    """Import core `name` and check what it follows upstream: the module, or why not."""
    try:
        module = importlib.import_module(f"routine_gym._native._{name}")
    except ImportError as error:  # not built (no compiler at install), or built for another ABI
        return (f"the compiled core {name!r} is not built ({error}); its Python twin runs "
                f"(set {NATIVE_VARIABLE}=0 to ask for the twins and silence this)")
    if name in UPSTREAM:
        distribution, follows = UPSTREAM[name]
        found = installed_version(distribution)
        if found != follows:
            return (f"the compiled core {name!r} ports {distribution} {follows}, but "
                    f"{distribution} {found} is installed; its Python twin runs (pip install "
                    f"'{distribution}=={follows}' for the core)")
    return module


def core(name: str) -> ModuleType | None:
    """The compiled core `name`, or None where its Python twin runs instead (the module doc).

    Raises:
        UsageError: `ROUTINE_GYM_NATIVE` names something other than a core.
    """
    if not enabled(name):
        return None
    found = _loaded.get(name)
    if found is None:
        found = _loaded[name] = _load(name)
    if isinstance(found, str):
        if name not in _warned:
            _warned.add(name)
            warnings.warn(found, RuntimeWarning, stacklevel=2)
        return None
    return found


def unavailable(name: str) -> str | None:
    """Why `core(name)` is None (None when it is the module): for error messages."""
    if not enabled(name):
        return f"{NATIVE_VARIABLE}={os.environ.get(NATIVE_VARIABLE, '')} turns it off"
    found = _loaded.get(name)
    if found is None:
        found = _loaded[name] = _load(name)
    return found if isinstance(found, str) else None
