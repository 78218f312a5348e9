"""The shipped systemd unit (examples/cmm-comp-daemon.service) against systemd's own rules.

The unit is read as systemd reads it (tests/systemd_unit.py, written from systemd.exec(5)), and
``systemd-analyze verify`` (systemd's own parser, where installed) must accept it without a word.
The configuration its install lines make (``cmm-comp daemon init /etc/cmm-comp … --logs …``, in
the unit's header) must only write where the sandbox lets it (``ProtectSystem=strict``) and only
read what ``ProtectHome=true`` leaves visible; numba's cache must be a folder the unit creates.
The daemon's start in that sandbox, as an unprivileged user, is tests/test_daemon_unprivileged.py.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from systemd_unit import parse_unit, under

from cmm_comp.cli.daemon_init import config_text, daemon_dir_paths
from cmm_comp.daemon.config import config_from_dict
from cmm_comp.daemon.service import SIGTERM_STOP_S

ROOT = Path(__file__).resolve().parents[1]
UNIT_PATH = ROOT / "examples" / "cmm-comp-daemon.service"


def _unit():
    return parse_unit(UNIT_PATH.read_text(encoding="utf-8"))


def install_command(unit, word: str) -> list[str]:
    """The header's install line running ``cmm-comp daemon …`` with ``word`` in it, split."""
    lines = [c for c in unit.header_comments if "cmm-comp daemon" in c and word in c]
    assert len(lines) == 1, unit.header_comments
    return shlex.split(lines[0])


def _init_args(unit) -> tuple[str, str]:
    """(DIR, --logs) of the header's ``daemon init`` line."""
    argv = install_command(unit, " init ")
    i = argv.index("init")
    return argv[i + 1], argv[argv.index("--logs") + 1]


def test_systemd_analyze_verify_accepts_the_unit(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed: the unit is checked by parsing only")
    # verify also checks that ExecStart= is an executable: point it at this environment's
    exe = Path(sys.executable).with_name("cmm-comp")
    assert exe.is_file(), exe
    text = UNIT_PATH.read_text(encoding="utf-8")
    text = re.sub(r"^ExecStart=\S+", f"ExecStart={exe}", text, count=1, flags=re.M)
    copy = tmp_path / UNIT_PATH.name
    copy.write_text(text, encoding="utf-8")
    run = subprocess.run(
        [analyze, "verify", "--man=no", str(copy)], capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 0 and run.stderr.strip() == "", run.stderr
    # the bad unit case: systemd-analyze does complain (so an empty stderr above means something)
    copy.write_text(text.replace("ProtectSystem=strict", "ProtectSystem=strictly"))
    run = subprocess.run(
        [analyze, "verify", "--man=no", str(copy)], capture_output=True, text=True, timeout=60
    )
    assert "strictly" in run.stderr


def test_everything_the_configuration_writes_is_writable_in_the_sandbox() -> None:
    unit = _unit()
    assert unit.last("Service", "ProtectSystem") == "strict" and unit.is_true("ProtectHome")
    folder, logs = _init_args(unit)
    paths = daemon_dir_paths(folder, logs)
    text = config_text(paths, "m", "0" * 64, "socketcan", "can0", {}, [4, 4, 4])
    cfg = config_from_dict(tomllib.loads(text), str(paths["config"]))
    writable, hidden = unit.writable(), unit.hidden()
    # written: the session logs, and numba's cache of the compiled kernels
    assert under(cfg.mcap.path, writable), (cfg.mcap.path, writable)
    numba_cache = unit.environment().get("NUMBA_CACHE_DIR")
    assert numba_cache is not None, "no NUMBA_CACHE_DIR: numba has no writable cache"
    assert under(numba_cache, writable), (numba_cache, writable)
    assert numba_cache in [f"/var/cache/{n}" for n in unit.words("Service", "CacheDirectory")]
    # read: the configuration, the grid, the machine, the key and the program itself
    argv = shlex.split(unit.last("Service", "ExecStart"))
    assert argv[argv.index("--config") + 1] == str(paths["config"])
    for path in (argv[0], cfg.grid.path, cfg.grid.machine, cfg.grid.public_key):
        assert not under(path, hidden), (path, hidden)
    # a path the namespace set-up needs must exist at start: only what the unit or init creates
    created = [folder, *(f"/var/log/{n}" for n in unit.words("Service", "LogsDirectory"))]
    for path in unit.must_exist():
        assert under(path, created), f"{path} may not exist at start (226/NAMESPACE)"


def test_the_unit_keeps_what_the_daemon_needs() -> None:
    unit = _unit()
    families = set(unit.words("Service", "RestrictAddressFamilies"))
    assert {"AF_CAN", "AF_INET", "AF_INET6", "AF_UNIX"} <= families
    assert not unit.is_true("MemoryDenyWriteExecute"), "numba's JIT needs W+X memory"
    assert not unit.is_true("PrivateDevices"), "USB CAN adapters with a vendor driver use /dev"
    assert unit.last("Service", "User") not in ("", "root")
    assert "-HUP" in unit.last("Service", "ExecReload")  # SIGHUP reloads the grid
    timeout = unit.last("Service", "TimeoutStopSec")
    assert float(timeout) > SIGTERM_STOP_S, "systemd would kill the daemon mid-flush"
    folder, logs = _init_args(unit)
    assert logs in [f"/var/log/{n}" for n in unit.words("Service", "LogsDirectory")]
    check = install_command(unit, "--check")
    assert check[check.index("--config") + 1] == str(daemon_dir_paths(folder)["config"])
