"""compensation's module import graph has no cycle (issue 10: no ``machine ↔ machine_io ↔
offsets`` circle), imports inside functions included.

import-linter cannot say this: its ``acyclic_siblings`` contract squashes subpackages, and
compensation has package-level cycles (``machine → formats → machine``) that are no module cycle.
So the graph comes from grimp (the library under import-linter: relative and function-level
imports resolved, ``if TYPE_CHECKING:`` imports left out) and its strongly connected components
from scipy. Importing a module also runs the packages above it, so those count as edges too,
except the importer's own ancestors (already being imported) unless it imports a name from one
(``from cmm_comp.compensation import Machine`` inside the package: a direct edge in grimp).
"""

from __future__ import annotations

import grimp
import numpy as np
from scipy.sparse import csr_array
from scipy.sparse.csgraph import connected_components

PACKAGE = "cmm_comp.compensation"


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def import_graph() -> dict[str, set[str]]:
    """module → the compensation modules importing it runs (see the module docstring)."""
    graph = grimp.build_graph(PACKAGE, exclude_type_checking_imports=True, cache_dir=None)
    modules = graph.modules
    out: dict[str, set[str]] = {}
    for name in modules:
        own = {*_ancestors(name), name}
        edges = set(graph.find_modules_directly_imported_by(name)) - {name}
        for target in list(edges):
            edges.update(a for a in _ancestors(target) if a in modules and a not in own)
        out[name] = edges
    return out


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module."""
    names = sorted(graph.keys() | {t for ts in graph.values() for t in ts})
    index = {n: i for i, n in enumerate(names)}
    pairs = [(index[a], index[b]) for a, ts in graph.items() for b in ts]
    rows, cols = (
        (np.array(x, dtype=np.int32) for x in zip(*pairs, strict=True)) if pairs else ([], [])
    )
    adjacency = csr_array((np.ones(len(pairs)), (rows, cols)), shape=(len(names), len(names)))
    _, labels = connected_components(adjacency, directed=True, connection="strong")
    components: dict[int, list[str]] = {}
    for name, label in zip(names, labels, strict=True):
        components.setdefault(int(label), []).append(name)
    return sorted(sorted(c) for c in components.values() if len(c) > 1)


def test_compensation_imports_have_no_cycle() -> None:
    graph = import_graph()
    assert f"{PACKAGE}.machine" in graph
    assert find_cycles(graph) == []


def test_the_graph_sees_known_edges() -> None:
    graph = import_graph()
    assert f"{PACKAGE}.kinematics" in graph[f"{PACKAGE}.machine"]
    assert f"{PACKAGE}.formats.machine_parser" in graph[f"{PACKAGE}.machine"]
    assert f"{PACKAGE}.formats" in graph[f"{PACKAGE}.machine"]  # the package above it runs too
    assert f"{PACKAGE}.machine" in graph[f"{PACKAGE}.formats.seedfiles"]
    # a made-up circle is found
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
