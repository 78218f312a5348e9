"""numba kernels without a usable cache folder: compiled in memory, same results, no crash.

``numba.njit(cache=True)`` raises at import when numba finds no cache locator (a read-only
installation without a home: issue 25). That situation is made here for one subprocess, without
root, by numba's own switch ``NUMBA_CACHE_LOCATOR_CLASSES=ZipCacheLocator`` (a locator that only
serves code inside zip files, so none applies): plain ``numba.njit(cache=True)`` must fail there
(the switch works), every project module with kernels must import, and a kernel must give what
it gives in this process (compiled with the cache). The real case, an unprivileged user on a
read-only install, is tests/test_daemon_unprivileged.py.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from cmm_comp.compensation.grid import kernels

NO_LOCATOR = {"NUMBA_CACHE_LOCATOR_CLASSES": "ZipCacheLocator"}
MODULES = (
    "cmm_comp.compensation.grid.kernels",
    "cmm_comp.compensation.grid.uncertainty",
    "cmm_comp.compensation.uncertainty.chain_kernel",
)


def _python(code: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **NO_LOCATOR}
    env.pop("NUMBA_CACHE_DIR", None)
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path,
        timeout=300,
    )  # fmt: skip


def test_plain_cache_true_fails_under_the_switch(tmp_path: Path) -> None:
    (tmp_path / "plain.py").write_text(
        "import numba\n@numba.njit(cache=True)\ndef f(x):\n    return x + 1\n"
    )
    run = _python("import plain", tmp_path)
    assert run.returncode != 0 and "no locator available" in run.stderr


def test_kernels_import_and_compute_without_a_cache(tmp_path: Path) -> None:
    code = (
        "import importlib, json\n"
        f"for m in {MODULES!r}: importlib.import_module(m)\n"
        "from cmm_comp.compensation.grid import kernels as k\n"
        "print(json.dumps({'cache': k.kernels_cache_dir(),\n"
        "                  'q': list(k._qmul(0.9, 0.1, -0.2, 0.3, 0.5, -0.5, 0.5, 0.5)),\n"
        "                  'exp': list(k._qexp(1e-3, 2e-3, -3e-3))}))\n"
    )
    run = _python(code, tmp_path)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["cache"] is None  # compiled in memory
    assert out["q"] == list(kernels._qmul(0.9, 0.1, -0.2, 0.3, 0.5, -0.5, 0.5, 0.5))
    assert out["exp"] == list(kernels._qexp(1e-3, 2e-3, -3e-3))
