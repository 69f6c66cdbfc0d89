"""The package's layering (docs/architecture.md): ident's floors and no import circles.

Every ``import`` statement that runs counts, also those inside functions (issue 28: layers
that exist only as import depth hide circles); imports under ``if TYPE_CHECKING:`` never run
(they give mypy its types) and do not count."""

from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
#: Folder -> installed package (pyproject.toml [tool.setuptools.package-dir]).
PACKAGES = {"fnsi_lab": "fnsi_lab", "daq": "fnsi_lab.daq", "ident": "fnsi_lab.ident",
            "replay": "fnsi_lab.replay", "viewer": "fnsi_lab.viewer"}
#: ident's floors, bottom up; a floor may import its own and the ones below, and the
#: error tree (ident.errors), which imports nothing of ident.
FLOORS = ("core", "robust", "refine")


def _modules() -> dict[str, pathlib.Path]:
    out = {}
    for folder, package in PACKAGES.items():
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([package, *parts])] = path
    return out


def _imports(path: pathlib.Path, name: str, known: set[str]) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
                   for stmt in block.body for n in ast.walk(stmt)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")
                base = ".".join(up[:len(up) - node.level + 1] + ([base] if base else []))
            for alias in node.names:
                full = f"{base}.{alias.name}"
                found.add(full if full in known else base)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return {m for m in found if m in known and m != name}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(path, name, known) for name, path in modules.items()}


def _floor(module: str) -> str | None:
    parts = module.split(".")
    if parts[:2] == ["fnsi_lab", "ident"] and len(parts) > 2 and parts[2] in FLOORS:
        return parts[2]
    return None


def test_ident_floors_import_only_themselves_and_below(graph):
    wrong = []
    for module, deps in graph.items():
        floor = _floor(module)
        if floor is None:
            continue
        allowed = set(FLOORS[:FLOORS.index(floor) + 1])
        for dep in deps:
            if dep == "fnsi_lab.ident.errors" or not dep.startswith("fnsi_lab.ident"):
                continue
            if _floor(dep) not in allowed:
                wrong.append(f"{module} imports {dep}")
    assert not wrong, "\n".join(sorted(wrong))


def test_no_import_circle_in_the_package(graph):
    """Tarjan's strongly connected components over the import graph: every one is a
    single module (a package's ``__init__`` re-exporting its modules is not a circle)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    circles = []
    counter = [0]

    def deps(m):   # a package importing its own submodules (re-exports) is not a circle
        return {d for d in graph[m] if not d.startswith(m + ".")}

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in deps(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    import sys
    sys.setrecursionlimit(10000)
    for v in sorted(graph):
        if v not in index:
            visit(v)
    assert not circles, "\n".join(" <-> ".join(c) for c in circles)
