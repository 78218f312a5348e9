"""A copy of the project's sources to build or install from (no tests in here).

setuptools leaves ``build/`` and ``*.egg-info`` in the folder it builds, so the tests that
build the real wheel or pip-install the project (test_packaging, test_daemon_unprivileged)
build from a copy: the package folders, ``pyproject.toml`` and ``README.md``, without bytecode.
"""

from __future__ import annotations

import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("compensation", "protocol", "daemon", "sim_controller", "cli")


def copy_sources(dst: Path) -> Path:
    """Copy what pip needs to build the project into ``dst`` (created); return ``dst``."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in (*FOLDERS, "pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, dst / name, ignore=ignore)
        else:
            dst.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, dst / name)
    return dst
