"""No two modules of `routine_gym` import each other, directly or through others.

The graph is read from the source with `ast`, not by importing: a node per module of
`routine_gym/` (its `.py` files and its compiled extensions), an edge per `import` or `from`
statement that names another node. Imports inside functions count as much as those at module
level: deferring an import changes *when* a module is loaded, not that the two modules depend on
each other, and routine-gym defers imports to keep `import routine_gym` light of *third-party*
modules (torch, ALE, Procgen), which are not nodes. The circle of issue 25 (`routine_gym.envs` →
`routine_gym.envs.minatar` → `routine_gym.networks` → `routine_gym.envs`) ran through two
deferred imports and one module-level one; a module-level-only graph could not see it.

One statement is not an edge: `import routine_gym` (or any package holding the importing
module) in one of its submodules. Python has begun importing that package before the submodule
runs, so the statement only binds its name (a submodule that reads `routine_gym.__file__`, say).
`from routine_gym import Name` of a name the package defines is an edge, as the name
may not exist yet while the package is half imported.
"""

from __future__ import annotations

import ast
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "routine_gym"


def _modules() -> dict[str, Path | None]:
    """Dotted name → source file of every module of the package (None for an extension)."""
    modules: dict[str, Path | None] = {}
    for path in PACKAGE.rglob("*"):
        rel = path.relative_to(PACKAGE.parent)
        if path.suffix == ".py":
            parts = rel.with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
        else:
            for suffix in EXTENSION_SUFFIXES:
                if path.name.endswith(suffix):
                    modules[".".join((*rel.parent.parts, path.name[: -len(suffix)]))] = None
    return modules


def _imports(name: str, path: Path, modules: dict[str, Path | None]) -> set[str]:
    """The modules of `modules` that `name`'s source imports anywhere in it."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in modules and not name.startswith(alias.name + "."):
                    found.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: `from . import x`, `from ..envs import y`
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            for alias in node.names:
                if f"{base}.{alias.name}" in modules:  # a submodule
                    found.add(f"{base}.{alias.name}")
                elif base in modules:  # a name the module defines
                    found.add(base)
    found.discard(name)
    return found


def import_graph() -> dict[str, set[str]]:
    """Each module of `routine_gym` → the modules of `routine_gym` it imports."""
    modules = _modules()
    return {name: _imports(name, path, modules) if path else set()
            for name, path in modules.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle of `graph` as [a, b, ..., a], or None when it has none (depth-first search)."""
    done: set[str] = set()
    for start in sorted(graph):
        if start in done:
            continue
        path, on_path = [start], {start}
        stack = [iter(sorted(graph[start]))]
        while stack:
            nxt = next(stack[-1], None)
            if nxt is None:
                finished = path.pop()
                on_path.discard(finished)
                done.add(finished)
                stack.pop()
                continue
            if nxt in on_path:
                return path[path.index(nxt):] + [nxt]
            if nxt not in done:
                path.append(nxt)
                on_path.add(nxt)
                stack.append(iter(sorted(graph.get(nxt, ()))))
    return None


def test_find_cycle_finds_a_circle_and_passes_a_tree():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_the_graph_sees_the_modules_and_their_imports():
    graph = import_graph()
    assert "routine_gym.envs.factory" in graph and "routine_gym.envs" in graph
    assert "routine_gym.envs" in graph["routine_gym.envs.factory"]  # module level
    assert "routine_gym.envs.minatar" in graph["routine_gym.envs"]  # inside a function
    assert "routine_gym" not in graph["routine_gym.demo.suite"]  # its own package


def test_routine_gym_has_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " → ".join(cycle)
