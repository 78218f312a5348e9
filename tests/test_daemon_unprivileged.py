"""The daemon started the way the shipped systemd unit starts it: an unprivileged user, a
read-only installation, no home, and (first) no writable cache for numba at all.

The installation is real: a venv made from ``/usr/bin/python3`` (an interpreter under /root is
unreadable to ``nobody``) in a folder ``nobody`` can read, the project installed into it by pip
(not editable), then made read-only. Its daemon folder is made by the command in the unit's own
install lines (``cmm-comp daemon init /etc/cmm-comp … --logs /var/log/cmm-comp``, every absolute
path moved under the test's folder, plus a ``udp_multicast`` bus for the test's controller).

1. ``setpriv --reuid=nobody`` with no ``HOME`` (nobody's is /nonexistent) and no
   ``NUMBA_CACHE_DIR``: numba finds no writable cache folder. Before issue 25 the daemon died on
   import (``RuntimeError: cannot cache function '_qmul': no locator available``); it must now
   compile in memory, say so, and answer readings.
2. In the unit's sandbox, rebuilt without systemd in a private mount namespace
   (``unshare --mount``): every mount read-only (``ProtectSystem=strict``) except the unit's
   ``LogsDirectory=`` and ``CacheDirectory=`` (owned by the user, as systemd makes them) and a
   writable ``/tmp`` (``PrivateTmp=true``); ``/home``, ``/root``, ``/run/user`` inaccessible
   (``ProtectHome=true``); the unit's ``Environment=`` (``NUMBA_CACHE_DIR=%C/cmm-comp``) and
   its ``ExecStart=``. The daemon must answer readings and leave its compiled kernels in the
   cache folder.

A controller in the test process checks every answer against the grid file (see
tests/daemon_process.py). Needs root (CI runs as root) and setpriv; skipped with the reason
otherwise.
"""

from __future__ import annotations

import grp
import json
import os
import pwd
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from daemon_process import check_answers, controller_on, stop, wait_ready
from source_copy import copy_sources
from systemd_unit import API_PATHS, parse_unit
from test_daemon_support import free_udp_port
from test_systemd_unit import UNIT_PATH, install_command

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"
SYSTEM_PYTHON = Path("/usr/bin/python3")
USER = "nobody"
READY_S = 900.0
"""A start without a cache compiles every kernel: ~20 s of CPU alone, minutes on a machine
whose 2 cores are shared by other test runs."""

pytestmark = [pytest.mark.slow, pytest.mark.timeout(3600)]


def _why_not() -> str | None:
    if os.geteuid() != 0:
        return "needs root (as CI runs) to start the daemon as nobody with setpriv"
    if shutil.which("setpriv") is None:
        return "setpriv (util-linux) not installed"
    try:
        pwd.getpwnam(USER)
    except KeyError:
        return f"no user {USER!r}"
    if not SYSTEM_PYTHON.exists():
        return f"{SYSTEM_PYTHON} missing (a venv readable by {USER} needs a system interpreter)"
    probe = subprocess.run(
        [SYSTEM_PYTHON, "-c", "import sys, venv, ensurepip; assert sys.version_info >= (3, 11)"],
        capture_output=True,
    )
    if probe.returncode != 0:
        return f"{SYSTEM_PYTHON} is not Python >= 3.11 with venv and ensurepip"
    return None


def _group() -> str:
    gid = pwd.getpwnam(USER).pw_gid
    return grp.getgrgid(gid).gr_name  # nogroup (Debian) or nobody (Fedora)


@dataclass(frozen=True)
class Tree:
    """The test's stand-in for the machine's root: every absolute path of the unit below it."""

    root: Path
    port: int

    def host(self, path: str) -> str:
        """Where the unit's absolute ``path`` lives in this test."""
        return str(self.root / path.lstrip("/")) if path.startswith("/") else path

    @property
    def config(self) -> Path:
        return self.root / "etc" / "cmm-comp" / "daemon.toml"

    @property
    def grid(self) -> Path:
        return self.root / "etc" / "cmm-comp" / "machine.grid"


def _root_env(tree: Tree) -> dict[str, str]:
    """Environment of the commands the test runs as root (their numba cache kept apart)."""
    return {
        "PATH": "/usr/bin:/bin",
        "LANG": "C.UTF-8",
        "NUMBA_CACHE_DIR": str(tree.root / "root-cache"),
    }


def _install(tree: Tree) -> None:
    """A venv from the system Python at the unit's /opt/cmm-comp/.venv, the project installed
    by pip (not editable) from a copy of the sources, then read-only."""
    venv = Path(tree.host("/opt/cmm-comp/.venv"))
    subprocess.run([SYSTEM_PYTHON, "-m", "venv", venv], check=True, timeout=300)
    src = copy_sources(tree.root / "src")
    pip = subprocess.run(
        [venv / "bin" / "python", "-m", "pip", "install", "--no-cache-dir", "-q", str(src)],
        capture_output=True,
        text=True,
        timeout=1800,
        env={**_root_env(tree), "HOME": str(tree.root)},
    )
    assert pip.returncode == 0, f"pip install of the project failed:\n{pip.stderr[-3000:]}"
    shutil.rmtree(src)
    subprocess.run(["chmod", "-R", "a+rX,a-w", str(tree.root / "opt")], check=True)


def _init_daemon_folder(tree: Tree) -> None:
    """The unit's install lines (init, then --check), as root, paths moved under the tree."""
    unit = parse_unit(UNIT_PATH.read_text(encoding="utf-8"))
    argv = [tree.host(a) for a in install_command(unit, " init ")]
    argv[argv.index("--machine") + 1] = str(NPL)
    argv += ["--can-interface", "udp_multicast", "--can-option", f"port={tree.port}"]
    run = subprocess.run(argv, capture_output=True, text=True, timeout=900, env=_root_env(tree))
    assert run.returncode == 0, run.stderr
    assert f"cmm-comp daemon --config {tree.config}" in run.stdout, run.stdout
    check = [tree.host(a) for a in install_command(unit, "--check")]
    run = subprocess.run(check, capture_output=True, text=True, timeout=900, env=_root_env(tree))
    assert run.returncode == 0 and ": ok" in run.stdout, run.stdout + run.stderr
    # what systemd does for LogsDirectory= / CacheDirectory=: created, owned by User=
    for path in ("/var/log/cmm-comp", "/var/cache/cmm-comp"):
        folder = Path(tree.host(path))
        folder.mkdir(parents=True, exist_ok=True)
        shutil.chown(folder, USER, _group())
    key = tree.root / "etc" / "cmm-comp" / "keys" / "grid-signing-key.pem"
    assert key.stat().st_mode & 0o777 == 0o600  # the daemon's user cannot read the private key


@pytest.fixture(scope="module")
def tree() -> Iterator[Tree]:
    reason = _why_not()
    if reason is not None:
        pytest.skip(reason)
    root = Path(tempfile.mkdtemp(prefix="cmm-comp-ro-", dir="/tmp"))
    try:
        root.chmod(0o755)  # mkdtemp makes 0700: nobody could not even enter it
        t = Tree(root, free_udp_port())
        _install(t)
        _init_daemon_folder(t)
        yield t
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _events(log: Path) -> list[dict]:
    return [json.loads(line) for line in log.read_text().splitlines() if line.startswith("{")]


def _uid_of(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(next(line for line in status.splitlines() if line.startswith("Uid:")).split()[1])


def _run_and_check(tree: Tree, argv: list[str], env: dict[str, str], log: Path) -> list[dict]:
    """Start ``argv``, check it runs as the user and answers readings, stop it with SIGTERM."""
    with open(log, "w") as out:
        proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, env=env, cwd="/")
    try:
        with controller_on(tree.port) as ctl:
            ready_s = wait_ready(ctl, proc, log, READY_S)
            print(f"{log.name}: ready after {ready_s:.1f} s")  # shown with pytest -s
            assert _uid_of(proc.pid) == pwd.getpwnam(USER).pw_uid
            assert check_answers(ctl, tree.grid) == 20
    finally:
        code = stop(proc)
    text = log.read_text()
    assert code == 0 and "Traceback" not in text, text
    logs = list(Path(tree.host("/var/log/cmm-comp")).glob("*.mcap"))
    assert logs and all(p.stat().st_uid == pwd.getpwnam(USER).pw_uid for p in logs)
    return _events(log)


def _setpriv() -> list[str]:
    return ["setpriv", f"--reuid={USER}", f"--regid={_group()}", "--clear-groups", "--"]


def test_read_only_install_no_home_no_cache_answers_readings(tree: Tree) -> None:
    assert not Path(pwd.getpwnam(USER).pw_dir).exists(), "this user has a home: not the case"
    env = {"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8"}  # no HOME, no NUMBA_CACHE_DIR
    cmm = tree.host("/opt/cmm-comp/.venv/bin/cmm-comp")
    argv = [*_setpriv(), cmm, "daemon", "--config", str(tree.config), "--metrics-port", "0"]
    events = _run_and_check(tree, argv, env, tree.root / "no-cache.log")
    cache = [e for e in events if e["event"] == "kernel_cache"]
    assert len(cache) == 1 and cache[0]["cache"] is None and cache[0]["level"] == "warning"
    assert "NUMBA_CACHE_DIR" in cache[0]["detail"]


SANDBOX = r"""
set -eu
tree=$1; shift
rw=""
while [ "$1" != "--" ]; do rw="$rw $1"; shift; done
shift
mount --make-rprivate /
# writable: /tmp and /var/tmp first (the tree lives in /tmp), then the tree read-only below
# them, then the unit's folders inside the tree
for d in $rw; do case "$d" in "$tree"/*) ;; *) mount --bind "$d" "$d" ;; esac; done
mount --bind "$tree" "$tree"
for d in $rw; do case "$d" in "$tree"/*) mount --bind "$d" "$d" ;; esac; done
# ProtectSystem=strict: every other mount read-only (the API file systems excepted)
awk '$6 ~ /^rw/ {print $5}' /proc/self/mountinfo | sort -u | while read -r mp; do
    case "$mp" in /proc|/proc/*|/sys|/sys/*|/dev|/dev/*) continue ;; esac
    keep=0
    for d in $rw; do [ "$mp" = "$d" ] && keep=1; done
    [ "$keep" = 1 ] || mount -o remount,bind,ro "$mp"
done
# ProtectHome=true (the tree, under /tmp, stays visible: it stands for /opt, /etc and /var)
for h in /home /root /run/user; do
    if [ -d "$h" ]; then mount -t tmpfs -o mode=000,size=4k tmpfs "$h"; fi
done
# the sandbox must hold even for root: nothing outside the writable folders can be written
for probe in "$tree/opt/.probe" "$tree/etc/cmm-comp/.probe" /usr/.cmm-comp-sandbox-probe; do
    if touch "$probe" 2>/dev/null; then rm -f "$probe"; echo "sandbox: $probe writable" >&2; exit 97; fi
done
exec "$@"
"""


def test_in_the_units_sandbox_with_its_cache_dir(tree: Tree) -> None:
    if subprocess.run(["unshare", "--mount", "true"], capture_output=True).returncode != 0:
        pytest.skip("no mount namespaces here (unshare --mount): the sandbox cannot be rebuilt")
    unit = parse_unit(UNIT_PATH.read_text(encoding="utf-8"))
    env = {"PATH": "/usr/bin:/bin", "LANG": "C.UTF-8", "HOME": pwd.getpwnam(USER).pw_dir}
    env |= {k: tree.host(v) for k, v in unit.environment().items()}
    cache = Path(env["NUMBA_CACHE_DIR"])
    assert cache == Path(tree.host("/var/cache/cmm-comp"))
    # PrivateTmp=true: a writable /tmp and /var/tmp (here the host's, not private ones)
    private_tmp = ["/tmp", "/var/tmp"] if unit.is_true("PrivateTmp") else []
    unit_dirs = [p for p in unit.writable() if p not in (*API_PATHS, *private_tmp)]
    assert sorted(unit_dirs) == ["/var/cache/cmm-comp", "/var/log/cmm-comp"]
    writable = [*private_tmp, *(tree.host(p) for p in unit_dirs)]
    exec_argv = [tree.host(a) for a in shlex.split(unit.last("Service", "ExecStart"))]
    argv = [
        "unshare", "--mount", "sh", "-c", SANDBOX, "sandbox", str(tree.root), *writable, "--",
        *_setpriv(), *exec_argv, "--metrics-port", "0",
    ]  # fmt: skip
    events = _run_and_check(tree, argv, env, tree.root / "sandbox.log")
    said = [e for e in events if e["event"] == "kernel_cache"]
    assert len(said) == 1 and said[0]["cache"] is not None
    assert Path(said[0]["cache"]).is_relative_to(cache), said
    index = list(cache.rglob("*.nbi"))
    assert index, f"numba left no cache index in {cache}"
    assert all(p.stat().st_uid == pwd.getpwnam(USER).pw_uid for p in index)
