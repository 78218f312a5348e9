"""Layering rule: lower packages never import higher ones (STYLE.md).

compensation  <  protocol  <  daemon  <  cli
compensation  <  sim_controller  <  cli

The daemon runs in production and never imports the simulator; only the CLI (the demo) wires
the two together. Every import names the installed namespace ``cmm_comp.*``: a bare
``import daemon`` would pick up python-daemon (or any other distribution's module).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("compensation", "protocol", "daemon", "sim_controller", "cli")
FORBIDDEN = {
    "compensation": {"protocol", "daemon", "sim_controller", "cli"},
    "protocol": {"daemon", "sim_controller", "cli"},
    "sim_controller": {"daemon", "cli"},
    "daemon": {"sim_controller", "cli"},
}


def _imports(path: Path) -> tuple[set[str], set[str]]:
    """(project packages imported as ``cmm_comp.<pkg>``, bare top-level names imported)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    ours: set[str] = set()
    bare: set[str] = set()
    modules: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules.extend(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules.append(node.module)
    for name in modules:
        parts = name.split(".")
        if parts[0] == "cmm_comp" and len(parts) > 1:
            ours.add(parts[1])
        else:
            bare.add(parts[0])
    return ours, bare


def _sources() -> list[Path]:
    dirs = [ROOT / p for p in PACKAGES] + [ROOT / "tests", ROOT / "benchmarks", ROOT / "examples"]
    return sorted(p for d in dirs for p in d.rglob("*.py"))


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_does_not_import_higher_layers(package: str) -> None:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        hits = _imports(path)[0] & FORBIDDEN[package]
        if hits:
            bad.append(f"{path.relative_to(ROOT)} imports {sorted(hits)}")
    assert not bad, "layering violated:\n" + "\n".join(bad)


def test_nothing_imports_the_folders_by_their_bare_names() -> None:
    bad = []
    for path in _sources():
        hits = _imports(path)[1] & set(PACKAGES)
        if hits:
            bad.append(f"{path.relative_to(ROOT)} imports {sorted(hits)} (use cmm_comp.<name>)")
    assert not bad, "\n".join(bad)


def test_checker_detects_a_violation(tmp_path: Path) -> None:
    bad = tmp_path / "m.py"
    bad.write_text(
        "import cmm_comp.daemon.service\nfrom cmm_comp.protocol import can_frames\n"
        "import daemon\nfrom sim_controller import x\n"
    )
    ours, bare = _imports(bad)
    assert ours == {"daemon", "protocol"}
    assert {"daemon", "sim_controller"} <= bare
