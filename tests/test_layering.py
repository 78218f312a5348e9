"""Layering rule: lower packages never import higher ones (STYLE.md).

compensation  <  protocol  <  daemon  <  cli
compensation  <  sim_controller  <  cli

The rule is configuration: import-linter contracts in pyproject.toml (``[tool.importlinter]``),
run by ``.ci/run`` as ``lint-imports``. grimp, under it, reads every import of the installed
packages, relative and function-level ones included. Here: the contracts catch violations
planted in a copy of the tree (they can fail), and the checks import-linter cannot express:
what the lazy ``__init__.pyi`` stubs import (grimp reads ``.py`` files only), and that the
tests, benchmarks and examples (not packages) name the installed namespace ``cmm_comp.*``: a bare
``import daemon`` would pick up python-daemon (or any other distribution's module).
"""

from __future__ import annotations

import ast
import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("compensation", "protocol", "daemon", "sim_controller", "cli")
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _lint_imports(cwd: Path, pythonpath: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(LINT_IMPORTS), "--no-cache", "--no-logo"],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(pythonpath)},
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_the_contracts_report_planted_violations(tmp_path: Path) -> None:
    """A copy of the tree as ``cmm_comp.*`` (first on PYTHONPATH, ahead of the editable
    install) with three violations import-linter must each report: an absolute import inside a
    function, a relative import across packages that also breaks the layers, and a relative
    import across packages in the allowed direction."""
    tree = tmp_path / "cmm_comp"
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tree / package, ignore=shutil.ignore_patterns("*.pyc"))
    for name in ("pyproject.toml", "import_contracts.py"):
        shutil.copy(ROOT / name, tmp_path / name)
    planted = {
        "compensation/kinematics.py": "def _planted():\n    from cmm_comp.daemon import config\n",
        "daemon/metrics.py": "from .. import sim_controller as _planted\n",
        "daemon/config.py": "from ..protocol import can_ids as _planted\n",
    }
    for rel, code in planted.items():
        with open(tree / rel, "a", encoding="utf-8") as fh:
            fh.write("\n\n" + code)
    run = _lint_imports(tmp_path, tmp_path)
    out = " ".join(run.stdout.split())  # the report wraps long lines
    assert run.returncode != 0, out
    assert "cmm_comp.compensation.kinematics -> cmm_comp.daemon.config" in out
    assert "cmm_comp.daemon.metrics -> cmm_comp.sim_controller" in out
    assert "from .. import sim_controller" in out
    assert "from ..protocol import can_ids" in out
    assert "2 broken" in out, out


def _stub_imports(stub: Path) -> list[tuple[str, list[str]]]:
    """(absolute module, imported names) of each ``from … import …`` in a package's stub."""
    package = "cmm_comp." + ".".join(stub.parent.relative_to(ROOT).parts)
    out = []
    for node in ast.walk(ast.parse(stub.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(alias.name, []) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")
            base = base[: len(base) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            out.append((module, [alias.name for alias in node.names]))
    return out


STUBS = sorted(p for package in PACKAGES for p in (ROOT / package).rglob("__init__.pyi"))


@pytest.mark.parametrize("stub", STUBS, ids=[str(p.relative_to(ROOT)) for p in STUBS])
def test_lazy_stubs_import_their_own_package_and_every_name_resolves(stub: Path) -> None:
    """A stub names what its package's ``__getattr__`` loads on first use: a name from another
    package would be an import grimp never sees, a stale name an AttributeError for users."""
    package = "cmm_comp." + ".".join(stub.parent.relative_to(ROOT).parts)
    loaded = importlib.import_module(package)
    for module, names in _stub_imports(stub):
        assert module.startswith(package + "."), f"{stub}: imports {module} (outside {package})"
        for name in names:
            assert getattr(loaded, name) is not None, f"{package}.{name}"


def _bare_imports(path: Path) -> set[str]:
    """Top-level names imported without the ``cmm_comp.`` namespace."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_nothing_imports_the_folders_by_their_bare_names() -> None:
    dirs = [ROOT / p for p in PACKAGES] + [ROOT / "tests", ROOT / "benchmarks", ROOT / "examples"]
    bad = []
    for path in sorted(p for d in dirs for p in d.rglob("*.py")):
        hits = _bare_imports(path) & set(PACKAGES)
        if hits:
            bad.append(f"{path.relative_to(ROOT)} imports {sorted(hits)} (use cmm_comp.<name>)")
    assert not bad, "\n".join(bad)


def test_bare_import_check_detects_one(tmp_path: Path) -> None:
    bad = tmp_path / "m.py"
    bad.write_text("import cmm_comp.daemon.service\nimport daemon\nfrom sim_controller import x\n")
    assert _bare_imports(bad) & set(PACKAGES) == {"daemon", "sim_controller"}
