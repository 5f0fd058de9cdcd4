"""The site package's modules import one another one way: their import graph has no circle.

Every import statement of ``uav_struct_env/site/*.py`` is read with ``ast`` -- at module level,
inside functions and under ``TYPE_CHECKING`` alike -- and resolved to the site module it names
(the package ``__init__`` counts as the module ``uav_struct_env.site``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "uav_struct_env.site"
FOLDER = Path(__file__).resolve().parents[2] / "uav_struct_env" / "site"


def module_name(path: Path) -> str:
    return PACKAGE if path.stem == "__init__" else f"{PACKAGE}.{path.stem}"


MODULES = {module_name(p): p for p in sorted(FOLDER.glob("*.py"))}


def site_imports(path: Path) -> set[str]:
    """The site modules ``path`` imports, anywhere in the file."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name in MODULES}
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level == 1:  # relative to the folder
                module = f"{PACKAGE}.{module}".rstrip(".")
            for a in node.names:
                # ``from uav_struct_env.site import ifc``: the submodule, else the package itself.
                sub = f"{module}.{a.name}"
                out |= {sub} if sub in MODULES else {module} & MODULES.keys()
    out.discard(module_name(path))
    return out


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A circle of ``graph`` as a list of nodes (first repeated at the end), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        state[node] = 2
        path.pop()
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return None


def test_the_site_modules_import_without_a_circle():
    graph = {name: site_imports(path) for name, path in MODULES.items()}
    assert graph[PACKAGE], "the reader found no imports in the package __init__"
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_find_cycle_finds_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


@pytest.mark.parametrize(("source", "want"), [
    ("from uav_struct_env.site.model import Site", {"uav_struct_env.site.model"}),
    ("def f():\n    from uav_struct_env.site import ifc", {"uav_struct_env.site.ifc"}),
    ("from uav_struct_env.site import Site", {PACKAGE}),
    ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import uav_struct_env.site.io",
     {"uav_struct_env.site.io"}),
    ("from .landmarks import LandmarkSet", {"uav_struct_env.site.landmarks"}),
])
def test_every_kind_of_import_is_an_edge(tmp_path, source, want):
    path = tmp_path / "probe.py"
    path.write_text(source)
    assert site_imports(path) == want
