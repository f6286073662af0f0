"""Every writer of a user's path refuses a name no output should have (issue 46 case 3):
`--out minari:ID` wrote a file literally named `minari:ID` and exited 0.

The writers are enumerated from the command line itself (every `--out` of `routine-gym`, every
path option of the scripts' `Args` that names an output), so a writer added later without a
case here fails `test_every_writer_is_enumerated`. Each is run as a user runs it, with a
`minari:` name: one line, exit code 2, nothing written.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
from pathlib import Path

import pytest
from one_line import assert_one_line_error
from script_loader import load_script
from test_as_a_user import BIN, REPO, user

from routine_gym.atomic import atomic_write_bytes, check_folder, check_writable
from routine_gym.cli_parser import build_parsers
from routine_gym.errors import UsageError

DEMO = REPO / "demos" / "MiniQbert-v0.npz"
SCRIPTS = ("bc", "compile_a2c", "gail", "option_critic", "rapl_a2c", "rapl_ppo", "rapl_sqil")
#: The `Args` fields of the scripts that name an output (the rest are inputs or settings).
SCRIPT_OUTPUTS = ("run_dir", "record_demo")
#: Each `routine-gym` command with an output: its words before the output's flag.
CLI_WRITERS = {
    "mine": ["mine", str(DEMO)],
    "upgrade": ["upgrade", str(DEMO)],
    "picture": ["picture", str(DEMO)],
    "record": ["record", "MiniQbert-v0", "--episodes", "1"],
    "play": ["play", "MiniQbert-v0"],
    "experiment run": ["experiment", "run", "rl", "--budget", "smoke"],
    "experiment report": ["experiment", "report", "sweep"],
}


def _script_outputs(name: str) -> set[str]:
    fields = {f.name for f in dataclasses.fields(load_script(name).Args)}
    paths = {f for f in fields if f.endswith(("_dir", "_demo", "_out", "_path", "_file"))
             or f in ("out", "output")}
    return paths - {"demo"}  # `--demo` is read


def test_every_writer_is_enumerated():
    _, commands = build_parsers()
    with_out = {name for name, p in commands.items()
                if any("--out" in a.option_strings for a in p._actions)}
    assert with_out == set(CLI_WRITERS)
    for name in SCRIPTS:
        assert _script_outputs(name) <= set(SCRIPT_OUTPUTS), name


@pytest.mark.parametrize("command", list(CLI_WRITERS))
def test_a_cli_output_named_minari_is_refused(command, tmp_path):
    proc = user("routine-gym", *CLI_WRITERS[command], "--out", "minari:rg/x-v0", cwd=tmp_path)
    assert_one_line_error(proc, "--out minari:rg/x-v0", "names a Minari dataset",
                          "routine-gym export")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(("name", "flag"), [
    *((name, "--run-dir") for name in SCRIPTS),
    *((name, "--record-demo") for name in SCRIPTS
      if "record_demo" in _script_outputs(name)),
])
def test_a_script_output_named_minari_or_another_scheme_is_refused(name, flag, tmp_path):
    for value, message in (("minari:rg/x-v0", "names a Minari dataset"),
                           ("s3:bucket", "starts with a scheme (s3:)")):
        proc = subprocess.run(
            [str(BIN / "python"), str(REPO / "algos" / f"{name}.py"), "--env-id",
             "MiniQbert-v0", flag, value],  # refused before any training
            cwd=tmp_path, capture_output=True, text=True, timeout=300,
            env={"PATH": f"{BIN}:/usr/bin:/bin", "HOME": str(tmp_path)})
        assert_one_line_error(proc, f"{flag} {value}", message)
        assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(("out", "message"), [
    ("", "--out needs a path, actual value: ''"),
    ("xyz:lib.json", "starts with a scheme (xyz:)"),
    ("lib.txt", "--out needs a file name ending in .json (the format written there), "
                "actual value: lib.txt"),
    ("sub/", "--out sub/ names a folder"),
    ("folder", "--out folder is a folder"),
])
def test_mine_refuses_every_kind_of_unintended_output_name(out, message, tmp_path):
    (tmp_path / "folder").mkdir()
    proc = user("routine-gym", "mine", DEMO, "--out", out, cwd=tmp_path)
    assert_one_line_error(proc, message)
    assert os.listdir(tmp_path) == ["folder"]


def test_an_empty_output_is_refused_where_no_output_means_a_default(tmp_path):
    # upgrade rewrites its demo in place without --out; `--out ""` is no way of saying so.
    proc = user("routine-gym", "upgrade", DEMO, "--out", "", cwd=tmp_path)
    assert_one_line_error(proc, "--out needs a path, actual value: ''")


def test_a_file_of_a_scheme_like_name_is_written_when_asked_as_a_local_path(tmp_path):
    proc = user("routine-gym", "mine", DEMO, "--out", "./minari:mine.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "minari:mine.json").is_file()


@pytest.mark.parametrize(("check", "value", "message"), [
    (lambda v: check_writable(v, "--out", ".npz"), "demo.NPZ", None),
    (lambda v: check_writable(v, "--out", ".npz"), "demo", "ending in .npz"),
    (lambda v: check_writable(v, "--out"), "https://example.org/x.npz", "scheme (https:)"),
    (lambda v: check_folder(v, "--run-dir"), "minari:runs", "names a Minari dataset"),
    (lambda v: check_folder(v, "--run-dir"), " ", "--run-dir needs a path"),
    (lambda v: atomic_write_bytes(v, b"x"), "minari:x", "names a Minari dataset"),
    (lambda v: atomic_write_bytes(v, b"x"), Path("xyz:y"), "scheme (xyz:)"),
])
def test_the_shared_checks_of_an_output_name(check, value, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    if message is None:
        check(value)
    else:
        with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")):
            check(value)
    assert os.listdir(tmp_path) == []
