"""The shape of the house (issue 48, item 6), held by tests so that it stays true.

- No module of `routine_gym/` is over 600 lines and no function (or method) over 120: a reader
  finds one idea per module and can hold a function in view. Measured with `ast`.
- The packages and top-level modules of `routine_gym` import each other in no loop, even through
  other files: `test_no_import_cycles` holds single modules to that; here a package counts as one
  room, so a module the plumbing imports (the library, the demo formats, the videos) can never
  import the plumbing back, and the floors of the house stay floors.
- A routine proposer's name is typed in one registry, `routine_gym.mining.PROPOSER_NAMES`: the
  `routine-gym mine --proposer` choices come from it, and every script's `Args.proposer`
  `Literal` (tyro needs the names spelled out in the dataclass) is compared with it here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from test_no_import_cycles import find_cycle, import_graph

from routine_gym.cli_parser import build_parsers
from routine_gym.experiments.paper.ablation import ABLATIONS
from routine_gym.mining import PROPOSER_NAMES, make_proposer

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "routine_gym"
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 120


def function_lengths(source: str) -> dict[str, int]:
    """Lines of every function and method of `source`, from its `def` to its last line, by
    dotted name (`Class.method`, `outer.inner`)."""
    lengths: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                name = prefix + child.name
                if not isinstance(child, ast.ClassDef):
                    lengths[name] = child.end_lineno - child.lineno + 1
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return lengths


def _modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_function_lengths_measures_functions_methods_and_nested_ones():
    source = (
        "def f(x):\n"  # 1
        "    def g():\n"  # 2
        "        return x\n"  # 3
        "    return g\n"  # 4
        "\n"
        "class A:\n"
        "    @property\n"
        "    def m(self):\n"  # 8
        '        """doc"""\n'
        "        return 1\n"  # 10
    )
    assert function_lengths(source) == {"f": 4, "f.g": 2, "A.m": 3}


def test_no_module_of_routine_gym_is_over_600_lines():
    assert len(_modules()) > 50  # the package was found
    over = {str(p.relative_to(ROOT)): n for p in _modules()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not over, f"modules over {MAX_MODULE_LINES} lines (split them by idea): {over}"


def test_no_function_of_routine_gym_is_over_120_lines():
    over = {f"{p.relative_to(ROOT)}:{name}": n for p in _modules()
            for name, n in function_lengths(p.read_text()).items() if n > MAX_FUNCTION_LINES}
    assert not over, f"functions over {MAX_FUNCTION_LINES} lines (split them): {over}"


def _room(module: str) -> str:
    """The room a module stands in: `routine_gym`'s face, one of its top-level modules, or one
    of its packages as a whole (`routine_gym.plumbing.run` → `routine_gym.plumbing`)."""
    return ".".join(module.split(".")[:2])


def test_the_packages_and_top_modules_of_routine_gym_import_each_other_in_no_loop():
    rooms: dict[str, set[str]] = {}
    for module, imported in import_graph().items():
        rooms.setdefault(_room(module), set()).update(
            _room(other) for other in imported if _room(other) != _room(module))
    assert {"routine_gym.plumbing", "routine_gym.errors", "routine_gym.atomic"} <= set(rooms)
    assert "routine_gym.library" in rooms["routine_gym.plumbing"]  # packages are rooms
    assert "routine_gym.atomic" in rooms["routine_gym.library"]
    cycle = find_cycle(rooms)
    assert cycle is None, "an arrow back up: " + " → ".join(cycle)


def _literal_of(script: Path, field: str) -> tuple[str, ...] | None:
    """The values of `Args.<field>: Literal[...]` in a script's source (None: no such field)."""
    for node in ast.walk(ast.parse(script.read_text())):
        if isinstance(node, ast.ClassDef) and node.name == "Args":
            for item in node.body:
                if (isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name)
                        and item.target.id == field):
                    annotation = item.annotation
                    assert isinstance(annotation, ast.Subscript), ast.unparse(annotation)
                    assert ast.unparse(annotation.value) in ("Literal", "typing.Literal")
                    values = annotation.slice
                    elts = values.elts if isinstance(values, ast.Tuple) else [values]
                    return tuple(ast.literal_eval(e) for e in elts)
    return None


def test_every_scripts_proposer_choices_are_the_registry():
    found = {script.name: choices for script in sorted((ROOT / "algos").glob("*.py"))
             if (choices := _literal_of(script, "proposer")) is not None}
    assert {"rapl_a2c.py", "rapl_ppo.py", "rapl_sqil.py"} <= set(found)
    differ = {name: choices for name, choices in found.items() if choices != PROPOSER_NAMES}
    assert not differ, (f"Args.proposer differs from routine_gym.mining.PROPOSER_NAMES "
                        f"{PROPOSER_NAMES}: {differ}")


def test_the_cli_proposer_choices_are_the_registry():
    _, commands = build_parsers()
    (action,) = [a for a in commands["mine"]._actions if a.dest == "proposer"]
    assert tuple(action.choices) == PROPOSER_NAMES


def test_the_registry_names_every_proposer_make_proposer_makes():
    assert PROPOSER_NAMES == ("full", "random", "enumerate", "random-fetch", "repeat", "bpe")
    for name in PROPOSER_NAMES:
        assert make_proposer(name).name == name
    with pytest.raises(ValueError, match="unknown proposer 'nope'; choose from full, random"):
        make_proposer("nope")
    assert set(ABLATIONS.values()) <= set(PROPOSER_NAMES)


def test_literal_of_reads_a_scripts_args(tmp_path):
    script = tmp_path / "s.py"
    script.write_text("class Args:\n    proposer: Literal['a', 'b'] = 'a'\n    x: int = 1\n")
    assert _literal_of(script, "proposer") == ("a", "b")
    assert _literal_of(script, "other") is None
