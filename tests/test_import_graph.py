"""compensation's module import graph has no cycle (issue 10: no ``machine ↔ machine_io ↔
offsets`` circle), at module level and including imports inside functions.

Edges come from the source (ast), not from running it: ``from .a import b`` is an edge to
``a.b`` when that is a module, else to ``a``; importing a module also imports the packages
above it, so those count too, except the importer's own ancestors (already being imported)
unless a name defined in one of them is imported (``from cmm_comp.compensation import Machine``
inside the package would need its ``__init__`` to have run that far).
Imports under ``if TYPE_CHECKING:`` never run and are left out.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "compensation"
PACKAGE = "cmm_comp.compensation"


def _modules() -> dict[str, tuple[Path, bool]]:
    out: dict[str, tuple[Path, bool]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        out[".".join([PACKAGE, *parts])] = (path, is_pkg)
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _import_nodes(tree: ast.Module, *, nested: bool) -> list[ast.Import | ast.ImportFrom]:
    found: list[ast.Import | ast.ImportFrom] = []

    def visit(body: list[ast.stmt], top: bool) -> None:
        for node in body:
            if isinstance(node, ast.Import | ast.ImportFrom):
                found.append(node)
            elif isinstance(node, ast.If) and _is_type_checking(node):
                visit(node.orelse, top)
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                if nested:
                    visit(node.body, False)
            else:
                for field in ("body", "orelse", "finalbody", "handlers"):
                    sub = getattr(node, field, None)
                    if isinstance(sub, list):
                        visit([s for s in sub if isinstance(s, ast.stmt)], top)
                    for handler in sub or []:
                        if isinstance(handler, ast.ExceptHandler):
                            visit(handler.body, top)

    visit(tree.body, True)
    return found


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def import_graph(*, nested: bool) -> dict[str, set[str]]:
    """module → the compensation modules it imports (see the module docstring)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, (path, is_pkg) in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        package = name if is_pkg else name.rsplit(".", 1)[0]
        targets: set[str] = set()
        from_package: set[str] = set()  # ``from <ancestor> import <name defined there>``
        for node in _import_nodes(tree, nested=nested):
            if isinstance(node, ast.Import):
                bases = [alias.name for alias in node.names]
                for base in bases:
                    while base and base not in modules:
                        base = base.rpartition(".")[0]
                    if base:
                        targets.add(base)
                continue
            if node.level:
                base_parts = package.split(".")
                base_parts = base_parts[: len(base_parts) - (node.level - 1)]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if sub in modules:
                    targets.add(sub)
                elif base in modules:
                    targets.add(base)
                    from_package.add(base)
        own = set(_ancestors(name)) | {name}
        edges: set[str] = {t for t in from_package if t != name}
        for target in targets:
            for t in [*_ancestors(target), target]:
                if t in modules and t not in own:
                    edges.add(t)
        graph[name] = edges
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


@pytest.mark.parametrize("nested", [False, True], ids=["module_level", "with_function_level"])
def test_compensation_imports_have_no_cycle(nested: bool) -> None:
    graph = import_graph(nested=nested)
    assert f"{PACKAGE}.machine" in graph
    assert find_cycles(graph) == []


def test_the_graph_sees_known_edges() -> None:
    graph = import_graph(nested=True)
    assert f"{PACKAGE}.kinematics" in graph[f"{PACKAGE}.machine"]
    assert f"{PACKAGE}.formats.machine_parser" in graph[f"{PACKAGE}.machine"]
    assert f"{PACKAGE}.formats" in graph[f"{PACKAGE}.machine"]  # the package above it runs too
    assert f"{PACKAGE}.machine" in graph[f"{PACKAGE}.formats.seedfiles"]
    # a made-up circle is found
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
