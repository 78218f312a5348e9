"""The distribution installs one top-level import name, ``cmm_comp``, and nothing else.

The folders ``compensation/``, ``protocol/``, ``daemon/``, ``sim_controller/``, ``cli/`` are
mapped to ``cmm_comp.*`` by setuptools (pyproject.toml). ``daemon`` is also the import name of
python-daemon, which the test extras install on purpose: this whole suite runs beside it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tomllib
import venv
from pathlib import Path

import pytest
from source_copy import copy_sources

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("compensation", "protocol", "daemon", "sim_controller", "cli")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_every_package_folder_is_listed_under_cmm_comp() -> None:
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    on_disk = {
        "cmm_comp." + ".".join(init.parent.relative_to(ROOT).parts)
        for folder in FOLDERS
        for init in (ROOT / folder).rglob("__init__.py")
    }
    assert on_disk - listed == set(), "pyproject.toml [tool.setuptools] packages misses these"
    assert listed - on_disk == set(), "pyproject.toml lists packages that do not exist"
    mapping = _pyproject()["tool"]["setuptools"]["package-dir"]
    assert mapping == {f"cmm_comp.{f}": f for f in FOLDERS}


def test_python_daemon_and_cmm_comp_daemon_coexist(tmp_path: Path) -> None:
    """In this environment (python-daemon is a test extra), ``import daemon`` is python-daemon
    and ``cmm_comp.daemon`` is ours. Run outside the checkout: ``python -m pytest`` puts the
    working directory first on sys.path, where the ``daemon/`` folder would shadow both."""
    code = (
        "import daemon\n"
        "from cmm_comp.daemon import ConfigError, DaemonConfig\n"
        "assert hasattr(daemon, 'DaemonContext'), daemon\n"
        "assert not hasattr(daemon, 'DaemonConfig')\n"
        "assert DaemonConfig(source='<t>').check().source == '<t>'\n"
        "print(daemon.__file__)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120
    )
    assert run.returncode == 0, run.stderr
    assert "site-packages" in run.stdout


@pytest.mark.slow
def test_a_built_wheel_in_a_fresh_venv_beside_python_daemon(tmp_path: Path) -> None:
    """Build and install the real wheel (not the editable finder) into a new venv that also sees
    python-daemon; import both and run a command that reads package data and does real work."""
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    purelib = Path(
        subprocess.check_output(
            [py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], text=True
        ).strip()
    )
    # The new venv borrows this environment's third-party libraries (numpy, scipy, python-daemon,
    # setuptools …) through a .pth line, but not cmm_comp: its own site-packages comes first and
    # the editable finder of this environment is a .pth *file*, which a path entry does not run.
    outer = sysconfig.get_paths()["purelib"]
    (purelib / "outer.pth").write_text(outer + "\n")
    # build from a copy: setuptools leaves build/ and *.egg-info in the folder it builds
    src = copy_sources(tmp_path / "src")
    wheel_dir = tmp_path / "wheel"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(wheel_dir),
            str(src),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (wheel,) = wheel_dir.glob("cmm_comp-*.whl")
    import zipfile

    with zipfile.ZipFile(wheel) as whl:  # the licence travels with the wheel's metadata
        licences = [n for n in whl.namelist() if ".dist-info/" in n and "LICENSE" in n]
        assert licences and b"Apache License" in whl.read(licences[0]), whl.namelist()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "-q",
            "--target",
            str(purelib),
            str(wheel),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    installed = sorted(p.name for p in purelib.iterdir() if not p.name.endswith((".pth",)))
    assert [n for n in installed if not n.startswith("cmm_comp")] in ([], ["bin"])
    code = """
import daemon, json, sys
from pathlib import Path
import cmm_comp.daemon as ours
from cmm_comp.compensation import Machine
from cmm_comp.protocol import dbc_text
assert hasattr(daemon, "DaemonContext"), daemon
assert Path(ours.__file__).parts[-3:-1] == ("cmm_comp", "daemon"), ours.__file__
machine = Machine.from_toml(sys.argv[1])
print(json.dumps({"daemon": daemon.__file__, "ours": ours.__file__,
                  "dbc": "BO_" in dbc_text(), "diag": machine.volumetric_error([[0, 0, 0]]).tolist()}))
"""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    out = subprocess.run(
        [py, "-c", code, str(ROOT / "examples" / "machines" / "npl-bridge.toml")],
        capture_output=True,
        text=True,
        cwd=tmp_path,  # not the checkout: the folders there must not be what gets imported
        env=env,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    import json

    result = json.loads(out.stdout)
    assert result["dbc"]
    assert str(purelib) in result["ours"], "cmm_comp came from somewhere else than the wheel"
    assert "site-packages/daemon" in result["daemon"]
    assert len(result["diag"][0]) == 3
