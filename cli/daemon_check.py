"""What ``cmm-comp daemon --check`` (and ``daemon init``) verifies beyond the configuration's own values: every
problem at once, each one line naming the setting, the file and what to do.

:func:`preflight` checks, each on its own (one failing check never hides another):

* the grid and its trust: ``grid.path`` set and readable, ``grid.machine`` readable,
  ``grid.public_key`` a key, a machine bound, then the grid file's signature and machine
  binding (:meth:`cmm_comp.daemon.grid_trust.GridTrust.problems`) and, when all of that holds, the full load
  with its self-check (:func:`cmm_comp.daemon.grid_slot.load_grid`). Any of these failing means the daemon
  would start and correct **nothing**: every answer ``no_grid`` with the indicated position;
* the session log folder (``mcap.path``) can be created and written by this user;
* the CAN bus opens (``can.interface`` / ``can.channel``; the message suggests ``virtual``
  or ``udp_multicast`` when there is no hardware) and the metrics and Modbus ports are free;
  skipped when the configuration itself has problems (its values are not to be trusted then);

and notes (warnings, not problems) a ``grid.stylus_mm`` that differs from the grid's probe
offset (:func:`cmm_comp.daemon.grid_slot.stylus_note`, which the daemon also logs at
start) and a missing cache for the compiled grid kernels.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass, field
from pathlib import Path

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.daemon.config import DaemonConfig
from cmm_comp.daemon.grid_slot import (
    KERNEL_CACHE_OFF,
    GridLoadError,
    LoadedGrid,
    load_grid,
    stylus_note,
)
from cmm_comp.daemon.grid_trust import GridTrust, TrustedMachine

__all__ = ["NOT_CORRECTING", "Preflight", "preflight"]

NOT_CORRECTING = (
    "the daemon would start but correct nothing: every answer says no_grid and carries the "
    "indicated position"
)
"""Appended to each grid problem: what it means for the readings."""


@dataclass
class Preflight:
    """The outcome of :func:`preflight`."""

    problems: list[str] = field(default_factory=list)
    """Each would stop the daemon, or leave it running without correcting."""
    warnings: list[str] = field(default_factory=list)
    """Worth knowing; the daemon corrects."""
    loaded: LoadedGrid | None = None
    """The grid as the daemon would load it (None when it would not)."""


def preflight(config: DaemonConfig, config_ok: bool = True) -> Preflight:
    """Every problem of ``config``'s files, folders, bus and ports (see the module doc);
    ``config_ok`` False skips the bus and port checks."""
    out = Preflight()
    _check_grid(config, out)
    _check_mcap(config, out)
    if config_ok:
        _check_can(config, out)
        _check_ports(config, out)
    cache = _kernel_cache_note()
    if cache is not None:
        out.warnings.append(cache)
    return out


def _check_grid(config: DaemonConfig, out: Preflight) -> None:
    g, where = config.grid, config.source
    if not g.path:
        out.problems.append(f"{where}: grid.path is empty: {NOT_CORRECTING}")
        return
    trust = GridTrust.from_section(g)
    before = len(out.problems)
    machine, unusable = trust.setting_problems()
    out.problems += [f"{where}: {line}" for p in unusable.values() for line in p.splitlines()]
    if not Path(g.path).is_file():
        out.problems.append(f"{where}: grid.path {g.path}: no such grid file")
    else:
        _check_grid_file(Path(g.path), trust, machine, unusable, out)
    if len(out.problems) > before:
        out.problems[-1] += f"; {NOT_CORRECTING}"
        return
    try:
        out.loaded = load_grid(g.path, trust)
    except GridLoadError as exc:
        out.problems.append(f"{exc}; {NOT_CORRECTING}")
        return
    note = stylus_note(g.stylus_mm, out.loaded.probe_offset_mm, out.loaded.path)
    if note is not None:
        out.warnings.append(f"{where}: {note}")


def _check_grid_file(
    path: Path,
    trust: GridTrust,
    machine: TrustedMachine | None,
    unusable: dict[str, str],
    out: Preflight,
) -> None:
    from cmm_comp.compensation.grid.file import read_grid_contents

    try:
        contents = read_grid_contents(path)
    except (CmmCompError, OSError) as exc:
        out.problems.append(str(exc) if str(path) in str(exc) else f"{path}: {exc}")
        return
    out.problems += trust.problems(
        contents, machine, "signature" not in unusable, "machine" not in unusable
    )


def _check_mcap(config: DaemonConfig, out: Preflight) -> None:
    path = config.mcap.path
    if not path:
        return
    folder = Path(path) if not path.endswith(".mcap") else Path(path).parent
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        out.problems.append(
            f"{config.source}: mcap.path {path}: {existing} is not a folder: the daemon would not "
            "start"
        )
    elif not os.access(existing, os.W_OK | os.X_OK):
        what = "write in" if existing == folder else f"create {folder} in"
        out.problems.append(
            f"{config.source}: mcap.path {path}: this user (uid {os.geteuid()}) cannot {what} "
            f"{existing}: the daemon would not start (give it a folder it may write, e.g. the "
            "systemd unit's LogsDirectory=)"
        )


def _check_can(config: DaemonConfig, out: Preflight) -> None:
    if not config.can.enabled:
        return
    from cmm_comp.daemon.can_endpoint import can_open_error, open_bus
    from cmm_comp.protocol.can_ids import CanIds

    try:
        bus = open_bus(config.can, CanIds(config.can.node_id, config.can.base_id))
    except Exception as exc:  # any python-can backend error: reported, not raised
        out.problems.append(f"{config.source}: {can_open_error(config.can, exc)}")
        return
    bus.shutdown()


def _check_ports(config: DaemonConfig, out: Preflight) -> None:
    wanted = []
    if config.metrics.enabled:
        wanted.append(("metrics", config.metrics.host, config.metrics.port))
    if config.modbus.enabled:
        wanted.append(("modbus", config.modbus.host, config.modbus.port))
    for section, host, port in wanted:
        if port == 0:
            continue
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            with socket.socket(infos[0][0], socket.SOCK_STREAM) as s:
                s.bind(infos[0][4])
        except OSError as exc:
            out.problems.append(
                f"{config.source}: {section}.host/{section}.port {host}:{port}: cannot listen "
                f"({exc.strerror or exc}): the daemon would not start (another daemon running? "
                f"set {section}.port, 0 = any free port)"
            )


def _kernel_cache_note() -> str | None:
    from cmm_comp.compensation.grid.kernels import kernels_cache_dir

    if kernels_cache_dir() is not None:
        return None
    return KERNEL_CACHE_OFF
