"""The paper's six experiments (SPEC §8): one `Experiment` per file in `paper/`, listed in
`registry.py`; `sweep.py` runs them and `report.py` writes their figures.

This module holds what every module here needs. `read_json_object` is how every file of a
sweep folder is read (manifests, `config.json`, `result.json`, the report's random-policy
cache, a snapshot's provenance): a file that is missing, unreadable, not JSON, nested too
deeply or not a JSON object is a one-line `UsageError` naming the file and the problem, never a
traceback.
"""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime
from typing import Any

from routine_gym.errors import UsageError, one_line

__all__ = ["JSON_KINDS", "json_kind", "os_problem", "read_json_object", "utc_now"]

#: How a JSON value's type reads in a message.
JSON_KINDS = {list: "a list", str: "a string", int: "a number", float: "a number",
              bool: "a boolean", type(None): "null", dict: "an object"}


def json_kind(value: Any) -> str:
    """`"a list"`, `"a string"`, ... : how a JSON value reads in an error message."""
    return JSON_KINDS.get(type(value), type(value).__name__)


def read_json_object(path: str | os.PathLike, hint: str = "") -> dict[str, Any]:
    """The JSON object (dict) in `path`.

    Args:
        path: the file.
        hint: appended to the message (what to do about it), e.g. "delete it and run again".

    Raises:
        UsageError: one line naming `path` and what is wrong: missing, a folder, unreadable,
            not UTF-8, empty, not valid JSON, nested too deeply, or not a JSON object.
    """
    more = f"; {hint}" if hint else ""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, not a JSON file{more}") from None
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file{more}") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot read it ({exc.strerror or exc}){more}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise UsageError(f"{path}: not a JSON file (not UTF-8 text){more}") from None
    if not text.strip():
        raise UsageError(f"{path}: empty, not a JSON object{more}") from None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UsageError(f"{path}: not valid JSON ({exc}){more}") from None
    except RecursionError:
        raise UsageError(f"{path}: JSON nested too deeply to read{more}") from None
    if not isinstance(value, dict):
        raise UsageError(f"{path}: holds {json_kind(value)}, not a JSON object{more}")
    return value


def utc_now() -> str:
    """The time now in UTC, `2026-12-02T10:00:00Z`: how a sweep folder's files stamp times."""
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def os_problem(exc: OSError) -> str:
    """What an `OSError` says, in a few words (`Permission denied`)."""
    return exc.strerror or one_line(exc)
