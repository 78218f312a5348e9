"""A copy of the project's sources to build or install from, its wheel built once per test
session, and its dependencies copied from this environment (no tests in here).

setuptools leaves ``build/`` and ``*.egg-info`` in the folder it builds, so the tests that
build the real wheel or pip-install the project (test_packaging, test_daemon_unprivileged)
build from a copy: the package folders, ``pyproject.toml`` and ``README.md``, without bytecode.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

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


def project_wheel(tmp_path_factory: Any) -> Path:
    """The project's wheel (``pip wheel --no-deps --no-build-isolation`` of a source copy), built
    once per test session and shared by pytest-xdist's workers (under a file lock in the
    session's common temporary folder)."""
    import fcntl
    import os
    import subprocess
    import sys

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    out = shared / "cmm-comp-wheel"
    with open(shared / "cmm-comp-wheel.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        wheels = sorted(out.glob("cmm_comp-*.whl"))
        if not wheels:
            src = copy_sources(shared / "cmm-comp-wheel-src")
            subprocess.run(
                [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                 "-q", "-w", str(out), str(src)],
                check=True, capture_output=True, timeout=600,
            )  # fmt: skip
            shutil.rmtree(src)
            wheels = sorted(out.glob("cmm_comp-*.whl"))
    assert len(wheels) == 1, wheels
    return wheels[0]


def copy_dependencies(wheel: Path, site_packages: Path) -> list[str]:
    """Copy into ``site_packages`` every distribution the wheel requires (``Requires-Dist``
    without extras, and theirs, recursively) as installed in this environment: each file its
    RECORD lists under this environment's site-packages, ``.dist-info`` included, so the target
    sees them as installed. A requirement the wheel forgot is not copied (the target then fails
    to import it, as a real install would). Returns the distributions' names."""
    import importlib.metadata as md
    import re
    import zipfile

    from packaging.requirements import Requirement

    with zipfile.ZipFile(wheel) as whl:
        meta = next(n for n in whl.namelist() if n.endswith(".dist-info/METADATA"))
        text = whl.read(meta).decode("utf-8")
    todo = [
        Requirement(line.split(":", 1)[1])
        for line in text.splitlines()
        if line.startswith("Requires-Dist:")
    ]
    done: dict[str, md.Distribution] = {}
    while todo:
        req = todo.pop()
        key = re.sub(r"[-_.]+", "-", req.name).lower()
        if key in done or (req.marker is not None and not req.marker.evaluate({"extra": ""})):
            continue
        dist = md.distribution(req.name)
        done[key] = dist
        todo += [Requirement(r) for r in dist.requires or []]
    for dist in done.values():
        root = Path(str(dist.locate_file(""))).resolve()
        for file in dist.files or []:
            src = Path(str(dist.locate_file(file))).resolve()
            if not src.is_relative_to(root) or not src.is_file():
                continue  # a script in bin/, or a file RECORD lists that is gone
            dst = site_packages / src.relative_to(root)
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst)
            if src.suffix == ".py":
                _copy_bytecode(src, dst)
    return sorted(done)


def _copy_bytecode(src: Path, dst: Path) -> None:
    """This interpreter's cached bytecode of ``src`` beside ``dst``, where it exists and RECORD
    does not list it: an environment installed with ``pip install --no-compile`` has bytecode
    only for the modules something imported, and a read-only copy could never write
    it (its daemon would compile those modules anew at every start)."""
    import importlib.util

    pyc = Path(importlib.util.cache_from_source(str(src)))
    target = Path(importlib.util.cache_from_source(str(dst)))
    if pyc.is_file() and not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(pyc, target)
