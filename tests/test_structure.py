"""The package's structure rules (docs/architecture.md, "Structure rules"), read from the source with `ast`:
no function over 80 lines in perception/, export/, sim/, geometry/, nerfstudio/model.py and
nerfstudio/model_outputs.py; no import circle between the package's modules, and none between its sub-packages (``nerfstudio/`` -> ``viewer/`` ->
``export/`` -> ``nerfstudio/`` is a loop even when no two files import each other). Imports inside functions
count: they close a circle at run time just the same."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "physgs_nerfstudio"
MAX_FUNCTION_LINES = 80
LENGTH_LIMITED = ("perception", "export", "sim", "geometry", "nerfstudio/model.py", "nerfstudio/model_outputs.py")


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package modules `name` imports anywhere in its file (`from . import x` imports x, not the face)."""
    deps: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            deps.update(a.name for a in node.names if a.name in modules)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            submodules = {f"{target}.{a.name}" for a in node.names} & modules.keys()
            if submodules and len(submodules) == len(node.names):
                deps.update(submodules)
            elif target in modules:
                deps.add(target)
                deps.update(submodules)
    deps.discard(name)
    return deps


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for dep in graph[node]:
            if dep not in index:
                visit(dep)
                low[node] = min(low[node], low[dep])
            elif dep in stack:
                low[node] = min(low[node], index[dep])
        if low[node] == index[node]:
            comp = []
            while comp[-1:] != [node]:
                comp.append(stack.pop())
            if len(comp) > 1:
                out.append(sorted(comp))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return out


def test_no_import_circles() -> None:
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    assert graph["physgs_nerfstudio.nerfstudio.pipeline"] >= {"physgs_nerfstudio.nerfstudio.model"}  # it reads
    assert _circles(graph) == []


def _package(module: str) -> str:
    """The sub-package of a module (``physgs_nerfstudio.export.run`` -> ``physgs_nerfstudio.export``); a module at
    the top of the package is its own."""
    return ".".join(module.split(".")[:2])


def _package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    packages: dict[str, set[str]] = {}
    for name, deps in graph.items():
        here = _package(name)
        packages.setdefault(here, set()).update(_package(d) for d in deps if _package(d) != here)
    for deps in list(packages.values()):
        for d in deps:
            packages.setdefault(d, set())
    return packages


def _edges(graph: dict[str, set[str]], circle: list[str]) -> list[str]:
    """The module imports that make a package circle (for the failure message)."""
    inside = set(circle)
    return sorted(f"{n} -> {d}" for n, deps in graph.items() for d in deps
                  if _package(n) in inside and _package(d) in inside and _package(n) != _package(d))  # fmt: skip


def test_no_import_circles_between_packages() -> None:
    modules = _modules()
    graph = {name: _imports(name, path, modules) for name, path in modules.items()}
    assert "physgs_nerfstudio.runfiles" in _package_graph(graph)["physgs_nerfstudio.export"]
    circles = _circles(_package_graph(graph))
    assert circles == [], "; ".join(" / ".join(_edges(graph, c)) for c in circles)


def test_the_package_circle_finder_sees_a_loop_no_file_circle_shows() -> None:
    graph = {"p.a.x": {"p.b.y"}, "p.b.y": {"p.a.z"}, "p.a.z": set()}
    assert _circles(graph) == []  # no module imports back the module that imports it
    assert _circles(_package_graph(graph)) == [["p.a", "p.b"]]


def test_circle_finder_finds_a_circle() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


@pytest.mark.parametrize("place", LENGTH_LIMITED)
def test_no_long_functions(place: str) -> None:
    root = PACKAGE / place
    files = [root] if root.is_file() else sorted(root.rglob("*.py"))
    long = [
        f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for path in files
        for node in ast.walk(ast.parse(path.read_text()))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
        and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES
    ]
    assert long == [], "split these functions: " + "; ".join(long)
