"""The native wing's loader, `routine_gym._native.core`: what `ROUTINE_GYM_NATIVE` keeps on, a
core that is not built (one warning, then its twin), a bad value as a user meets it (one line,
exit 2), and that no other module imports a compiled core."""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
from one_line import assert_one_line_error

from routine_gym import _native
from routine_gym.errors import UsageError

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize(("value", "on"), [
    ("", {"sequitur", "minatar_core", "masked_gru"}),
    ("1", {"sequitur", "minatar_core", "masked_gru"}),
    ("all", {"sequitur", "minatar_core", "masked_gru"}),
    ("0", set()),
    ("none", set()),
    ("sequitur", {"sequitur"}),
    ("sequitur,minatar_core", {"sequitur", "minatar_core"}),
    (" Masked_GRU , sequitur ,", {"masked_gru", "sequitur"}),  # spaces, case, a trailing comma
])
def test_the_variable_keeps_the_cores_it_names(value, on):
    assert {name for name in _native.CORES if _native.enabled(name, value)} == on


def test_a_name_that_is_no_core_is_a_usage_error_naming_the_cores():
    with pytest.raises(UsageError, match=r"^ROUTINE_GYM_NATIVE=sequitur,wrapper_core: "
                                         r"wrapper_core is not a compiled core \(the cores: "
                                         r"sequitur, minatar_core, masked_gru; 0 turns"):
        _native.enabled("sequitur", "sequitur,wrapper_core")
    with pytest.raises(ValueError, match="no compiled core named 'records'"):
        _native.core("records")


def test_a_core_turned_off_is_none_without_a_warning(monkeypatch):
    monkeypatch.setenv("ROUTINE_GYM_NATIVE", "0")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert [_native.core(name) for name in _native.CORES] == [None] * 3
    assert _native.unavailable("sequitur") == "ROUTINE_GYM_NATIVE=0 turns it off"


def test_a_core_not_built_warns_once_and_its_twin_runs(monkeypatch):
    monkeypatch.delenv("ROUTINE_GYM_NATIVE", raising=False)
    monkeypatch.setattr(_native, "_loaded", {})
    monkeypatch.setattr(_native, "_warned", set())
    real_import = _native.importlib.import_module

    def no_sequitur(name):
        if name == "routine_gym._native._sequitur":
            raise ImportError("No module named 'routine_gym._native._sequitur'")
        return real_import(name)

    monkeypatch.setattr(_native.importlib, "import_module", no_sequitur)
    with pytest.warns(RuntimeWarning, match=r"^the compiled core 'sequitur' is not built \(No "
                                            r"module named .*\); its Python twin runs \(set "
                                            r"ROUTINE_GYM_NATIVE=0"):
        assert _native.core("sequitur") is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _native.core("sequitur") is None  # the second time: no warning
    assert _native.unavailable("sequitur").startswith("the compiled core 'sequitur' is not built")


def test_a_bad_variable_is_a_one_line_error_from_the_cli(tmp_path):
    """As a user meets it: `routine-gym mine` induces a grammar, whose core the variable names."""
    demo = REPO / "demos" / "MiniQbert-v0.npz"
    env = {"PATH": f"{Path(sys.executable).parent}:/usr/bin:/bin", "HOME": str(tmp_path),
           "ROUTINE_GYM_NATIVE": "sequitur,fast"}
    proc = subprocess.run([str(Path(sys.executable).parent / "routine-gym"), "mine", str(demo),
                           "--out", "r.json"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert_one_line_error(proc, "ROUTINE_GYM_NATIVE=sequitur,fast", "fast is not a compiled core")


def test_only_the_loader_imports_a_compiled_core():
    """`core(name)` is the one way in: no module of the package, script or bench imports
    `routine_gym._native._x` (or a core by its old name) itself."""
    pattern = re.compile(r"(_native\._\w|import _(sequitur|minatar_core|masked_gru|records|"
                         r"wrapper_core)\b|from routine_gym\._(sequitur|minatar_core|masked_gru|"
                         r"records|wrapper_core)\b|routine_gym import _core)")
    loader = REPO / "routine_gym" / "_native" / "__init__.py"
    offenders = [
        str(path.relative_to(REPO))
        for folder in ("routine_gym", "algos", "bench")
        for path in sorted((REPO / folder).rglob("*.py"))
        if path != loader and pattern.search(path.read_text())
    ]
    assert offenders == []


def test_the_module_says_which_cores_run(tmp_path):
    """`python -m routine_gym._native` (what `make` prints after installing): a line per core."""
    proc = subprocess.run([sys.executable, "-m", "routine_gym._native"], cwd=tmp_path,
                          env={"PATH": "/usr/bin:/bin", "ROUTINE_GYM_NATIVE": "minatar_core"},
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0] == ("compiled core sequitur: not in use: ROUTINE_GYM_NATIVE=minatar_core "
                        "turns it off")
    assert lines[1].startswith("compiled core minatar_core: ")
    assert lines[1].endswith("built, in use") or "not built" in lines[1]
    assert lines[2].startswith("compiled core masked_gru: not in use: ROUTINE_GYM_NATIVE=")
    assert len(lines) == 3
