"""The demo file: its `.npz` layout, its size limits, and reading it without trusting it.

`Demo.save` writes this file and `Demo.load` reads it (`routine_gym.demo.format`); this module
holds what the file is and the checks a file must pass before a byte of it is believed.

File format (version 2)
-----------------------
One compressed NumPy archive (`.npz`, written with `np.savez_compressed` and replaced
atomically). It holds no pickles: every member is a plain numeric or unicode array, and it loads
with `np.load(path, allow_pickle=False)`. With T steps in E episodes:

| array                | shape          | dtype   | content                                       |
|----------------------|----------------|---------|-----------------------------------------------|
| `actions`            | (T,)           | int64   | primitive action ids, episodes concatenated   |
| `rewards`            | (T,)           | float64 | reward of each step                           |
| `terminated`         | (T,)           | bool    | `terminated` flag of each step                |
| `truncated`          | (T,)           | bool    | `truncated` flag of each step                 |
| `decisions`          | (T,)           | bool    | True: the demonstrator chose the action;      |
|                      |                |         | False: a wrapper injected it (version 2)      |
| `episode_lengths`    | (E,)           | int64   | steps per episode, each ≥ 1, summing to T     |
| `observations`       | (T, *obs)      | env's   | optional: the observation before each action  |
| `final_observations` | (E, *obs)      | env's   | optional: the observation after the last step |
| `meta`               | ()             | unicode | JSON object, below                            |

Episode `e` occupies steps `offsets[e] : offsets[e] + episode_lengths[e]` with
`offsets = cumsum(episode_lengths) - episode_lengths`; `final_observations[e]` is the
observation after episode `e`'s last action. Only an episode's last step may carry a
`terminated` or `truncated` flag; a last step with neither marks an episode cut short (a human
who closed the window). `observations` and `final_observations` are stored together or not at
all.

`meta` keys: `format` (`"routine-gym/demo"`), `version` (`2`), `env_id` (or null for an env
not made by `gym.make`), `env_kwargs` (the keyword arguments of `gym.make`, without
`render_mode`), `max_episode_steps` (the time limit `gym.make` applied, or null), `seeds` (the
reset seed of each episode), `num_actions`, `action_meanings`, `scores` (undiscounted return of
each episode, checked against `rewards` on load), `source` (`"agent"`, `"human"`, `"random"`,
...), `created` (ISO 8601, UTC) and `routine_gym_version`; any other key is provenance that is
kept as is (`candidates` lists every episode `record_agent_demo` chose the best from;
`recorded_under` names the wrappers between the recorder and the decision marker). A tuple
anywhere in `meta` is written as `{"__tuple__": [...]}` so that it loads back as a tuple.

Version 1 (the same without `decisions`) still loads, with every step a decision;
`routine-gym upgrade DEMO` (`upgrade_demo`) rewrites it as version 2 by replaying it through
the preprocessing it was recorded under, which re-derives the injected steps from the seeds.
Loading checks everything above and names the file and the problem in a `ValueError`.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib
from typing import Any

import numpy as np

from routine_gym.errors import UsageError

__all__ = [
    "DEMO_FORMAT",
    "DEMO_VERSION",
    "MAX_META_BYTES",
    "MAX_OBSERVATION_BYTES",
    "MAX_STEPS",
    "READABLE_VERSIONS",
    "demo_file_version",
    "read_demo_file",
]

DEMO_FORMAT = "routine-gym/demo"
DEMO_VERSION = 2
#: File versions `Demo.load` reads (version 1 has no `decisions`: every step is a decision).
READABLE_VERSIONS = (1, 2)

_STEP_ARRAYS = ("actions", "rewards", "terminated", "truncated")
_REQUIRED_ARRAYS = (*_STEP_ARRAYS, "episode_lengths", "meta")
_OBS_ARRAYS = ("observations", "final_observations")
_V2_ARRAYS = ("decisions",)
#: Size limits of a demo file's members once uncompressed (a small file can expand without
#: bound): the JSON `meta`, each per-step or per-episode array, and the observations.
MAX_META_BYTES = 1 << 20
MAX_STEPS = 10**8
MAX_OBSERVATION_BYTES = 16 << 30


# -- JSON helpers ------------------------------------------------------------------------


def _to_json(value: Any) -> Any:
    """`value` as JSON-able data (tuples tagged so they come back); TypeError if impossible."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return {"__tuple__": [_to_json(v) for v in value]}
    if isinstance(value, list):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError(f"dict keys must be strings: {list(value)!r}")
        return {k: _to_json(v) for k, v in value.items()}
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable: {value!r}")


def _from_json(value: Any) -> Any:
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    if isinstance(value, dict):
        if set(value) == {"__tuple__"} and isinstance(value["__tuple__"], list):
            return tuple(_from_json(v) for v in value["__tuple__"])
        return {k: _from_json(v) for k, v in value.items()}
    return value


# -- reading a demo file ------------------------------------------------------------------


def read_demo_file(path: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The parsed `meta` and the arrays of the demo file at `path`, every member checked
    against the limits above before it is read and nothing unpickled.

    Raises:
        FileNotFoundError: `path` does not exist.
        ValueError: naming the file, for a file that is not a readable demo (not a zip,
            truncated, corrupt, too large, missing arrays, unknown format or version).
    """
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: no such demo file")
    if not os.path.isfile(path):
        raise ValueError(f"{path}: not a file")
    if not zipfile.is_zipfile(path):
        raise ValueError(
            f"{path}: not a routine-gym demo: not an .npz (zip) archive; "
            "the file may be truncated or corrupt"
        )
    _check_member_sizes(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            names = set(data.files)
            if "meta" not in names:
                raise ValueError(
                    f"not a routine-gym demo: it has no 'meta' array (arrays: {sorted(names)})"
                )
            meta = _parse_meta(_read_array(data, "meta"))
            required = _REQUIRED_ARRAYS + (_V2_ARRAYS if meta["version"] >= 2 else ())
            missing = [n for n in required if n not in names]
            if missing:
                raise ValueError(f"missing arrays {missing} (arrays: {sorted(names)})")
            arrays = {
                n: _read_array(data, n)
                for n in (*required, *_OBS_ARRAYS)
                if n in names and n != "meta"
            }
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        raise ValueError(f"{path}: corrupt demo file ({type(exc).__name__}: {exc})") from exc
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc
    return meta, arrays


def _read_array(data: Any, name: str) -> np.ndarray:
    try:
        arr = data[name]
    except ValueError as exc:
        if "allow_pickle" in str(exc):
            raise ValueError(
                f"array {name!r} holds pickled Python objects, which routine-gym never loads"
            ) from exc
        raise ValueError(f"array {name!r} is not a valid array ({exc})") from exc
    if not isinstance(arr, np.ndarray):  # NpzFile hands back raw bytes for a non-.npy member
        raise ValueError(f"member {name!r} is not a .npy array")
    return arr


def _check_member_sizes(path: str) -> None:
    """Refuse a demo whose members expand beyond the documented limits (`MAX_*`), before
    anything is allocated.

    Both sizes are checked: the zip member's declared size, and the shape × item size its
    `.npy` header claims (`np.load` allocates that much before reading a byte of data, so a
    1.8 KB file claiming a shape of 10^12 would end in a `MemoryError`). The header must also
    agree with the member's size and must not declare an object dtype (a pickle).
    """
    try:
        with zipfile.ZipFile(path) as archive:
            for member in archive.infolist():
                name = member.filename.removesuffix(".npy")
                if name == "meta":
                    limit, what = MAX_META_BYTES, f"{MAX_META_BYTES >> 20} MiB of metadata"
                elif name in _OBS_ARRAYS:
                    limit = MAX_OBSERVATION_BYTES
                    what = f"{MAX_OBSERVATION_BYTES >> 30} GiB of observations"
                else:
                    limit, what = 8 * MAX_STEPS + 4096, f"{MAX_STEPS:,} steps"
                if member.file_size > limit:
                    raise ValueError(
                        f"{path}: its {name!r} expands to {member.file_size:,} bytes, over the "
                        f"limit of {what} a demo may hold"
                    )
                with archive.open(member) as stream:
                    _check_array_header(path, name, stream, member.file_size, limit, what)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        raise ValueError(f"{path}: corrupt demo file ({type(exc).__name__}: {exc})") from exc


class _CountingReader:
    """A read-only stream that counts the bytes read through it (the `.npy` header's size)."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.count = 0

    def read(self, size: int = -1) -> bytes:
        data = self.stream.read(size)
        self.count += len(data)
        return data


def _check_array_header(path: str, name: str, stream: Any, size: int, limit: int,
                        what: str) -> None:
    """Refuse a `.npy` member whose header claims more than `limit` bytes, more or fewer
    than the `size` bytes it holds, or an object dtype; a member that is not `.npy` is left
    to `_read_array`."""
    npy = np.lib.format
    stream = _CountingReader(stream)
    if stream.read(len(npy.MAGIC_PREFIX)) != npy.MAGIC_PREFIX:
        return
    try:
        version = tuple(stream.read(2))
        if version == (1, 0):
            shape, _, dtype = npy.read_array_header_1_0(stream)
        elif version in ((2, 0), (3, 0)):
            shape, _, dtype = npy.read_array_header_2_0(stream)
        else:
            raise ValueError(f".npy format version {version} is not supported")
    except ValueError as exc:
        raise UsageError(f"{path}: member {name!r} has no valid .npy header ({exc})") from None
    header_bytes = stream.count
    claims = f"{path}: member {name!r} claims shape {shape} of {dtype}"
    if dtype.hasobject:
        raise UsageError(f"{path}: member {name!r} holds pickled Python objects (it claims "
                         f"shape {shape} of {dtype}), which routine-gym never loads")
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes > limit:
        raise UsageError(f"{claims}, {nbytes:,} bytes, over the limit of {what} a demo may hold")
    if nbytes != size - header_bytes:
        raise UsageError(f"{claims}, {nbytes:,} bytes, but holds {size - header_bytes:,} "
                         "bytes of data")


def demo_file_version(path: str | os.PathLike) -> int:
    """The format version a demo file was written in (1 or 2), read from its `meta` alone.

    Raises:
        ValueError: naming the file, for a file that is not a readable demo.
    """
    path = os.fspath(path)
    if not zipfile.is_zipfile(path):
        raise ValueError(f"{path}: not a routine-gym demo: not an .npz (zip) archive")
    _check_member_sizes(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            if "meta" not in data.files:
                raise ValueError("not a routine-gym demo: it has no 'meta' array")
            return int(_parse_meta(_read_array(data, "meta"))["version"])
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as exc:
        raise ValueError(f"{path}: corrupt demo file ({type(exc).__name__}: {exc})") from exc
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _parse_meta(arr: np.ndarray) -> dict[str, Any]:
    if arr.shape != () or arr.dtype.kind != "U":
        raise ValueError(
            f"'meta' must be a 0-d unicode array of JSON, got dtype {arr.dtype} shape {arr.shape}"
        )
    try:
        meta = json.loads(str(arr[()]))
    except json.JSONDecodeError as exc:
        raise ValueError(f"'meta' is not valid JSON ({exc})") from exc
    if not isinstance(meta, dict):
        raise ValueError(f"'meta' must be a JSON object, got {type(meta).__name__}")
    if meta.get("format") != DEMO_FORMAT:
        raise ValueError(
            f"not a routine-gym demo: format is {meta.get('format')!r}, expected {DEMO_FORMAT!r}"
        )
    version = meta.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise ValueError(
            f"demo format version {version!r} is not supported; "
            f"this routine-gym reads versions {', '.join(map(str, READABLE_VERSIONS))}"
        )
    return _from_json(meta)
