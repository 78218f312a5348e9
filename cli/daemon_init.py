"""``cmm-comp daemon init DIR --machine MACHINE.toml``: a folder the daemon runs from as is.

:func:`init_daemon_dir` writes, into ``DIR``:

* ``machine.toml`` — a self-contained copy of the machine description (tables inline), the one
  the grid is bound to (its description sha256 equals the original's);
* ``machine.grid`` — the correction grid built from it (``--steps`` or the machine's own);
* ``keys/grid-signing-key.pem`` (private, 0600) and ``keys/grid-signing-key.pub.pem`` — a new
  Ed25519 key pair; the grid is signed with it;
* ``daemon.toml`` — the daemon configuration trusting that key and bound to that machine, every
  path absolute and inside ``DIR`` (the session logs in ``DIR/logs`` unless ``logs`` says
  otherwise), the CAN interface and channel given; every other setting at its default
  (``examples/daemon.toml`` lists them all). ``grid.stylus_mm`` is left unset: the grid's probe
  offset is used.

Nothing is overwritten: a ``DIR`` already holding any of these files is refused, and what a
failed run wrote is removed again. Units: mm.
"""

from __future__ import annotations

import contextlib
import json
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.daemon.config import ConfigError, DaemonConfig, config_from_dict

__all__ = [
    "CONFIG_NAME",
    "DEFAULT_CHANNELS",
    "InitError",
    "InitReport",
    "config_text",
    "daemon_dir_paths",
    "init_daemon_dir",
]

CONFIG_NAME = "daemon.toml"
MACHINE_NAME = "machine.toml"
GRID_NAME = "machine.grid"
KEYS_DIR = "keys"
LOGS_DIR = "logs"

DEFAULT_CHANNELS: dict[str, str] = {
    "socketcan": "can0",
    "udp_multicast": "ff11:7079:7468:6f6e:6465:6d6f:6d63:6173",
    "virtual": "cmm-comp",
}
"""The channel used when ``--can-channel`` is not given. ``udp_multicast``: python-can's IPv6
group with interface-local scope (ff11::…): a bus between processes on this host, never the
network (python-can's own default, ff15::…, is site-local)."""


class InitError(CmmCompError, ValueError):
    """``daemon init`` refused (message names the folder, file or flag)."""


@dataclass(frozen=True)
class InitReport:
    """What :func:`init_daemon_dir` wrote (absolute paths)."""

    config: Path
    machine: Path
    grid: Path
    private_key: Path
    public_key: Path
    logs: Path
    grid_sha256: str
    key_id: str
    machine_name: str
    steps: tuple[int, int, int]
    can_interface: str
    can_channel: str


def _toml_value(value: Any) -> str:
    """A TOML literal of a str, bool, int, float or list of them (JSON strings are TOML basic
    strings)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise InitError(f"--can-option value {value!r}: only strings, numbers, booleans and lists")


def config_text(
    report_paths: Mapping[str, Path],
    machine_name: str,
    machine_sha256: str,
    can_interface: str,
    can_channel: str,
    can_options: Mapping[str, Any],
    steps: Sequence[int],
) -> str:
    """The ``daemon.toml`` written by ``daemon init`` (commented)."""
    p = {k: str(v) for k, v in report_paths.items()}
    lines = [
        "# cmm-comp daemon configuration written by `cmm-comp daemon init`",
        f"# machine {machine_name!r}, description sha256 {machine_sha256}",
        "# Every other setting is at its default; examples/daemon.toml and docs/daemon.md list",
        "# them all (each can also be given on the command line: --<section>-<key> VALUE).",
        f"#   check: cmm-comp daemon --config {p['config']} --check",
        f"#   start: cmm-comp daemon --config {p['config']}",
        "",
        "[grid]",
        f"path = {_toml_value(p['grid'])}",
        f"# built with steps {list(steps)} from machine.toml below and signed with "
        f"{KEYS_DIR}/grid-signing-key.pem;",
        "# a new grid: cmm-comp grid build MACHINE -o GRID, cmm-comp grid sign GRID --key KEY,",
        "# then SIGHUP (systemctl reload) or a restart",
        f"machine = {_toml_value(p['machine'])}     # the grid must be built from this",
        f"public_key = {_toml_value(p['public_key'])}",
        "# stylus_mm = [0.0, 0.0, 0.0]  # unset: the grid's probe offset (the machine's [probe])",
        "",
        "[can]",
        f"interface = {_toml_value(can_interface)}",
        f"channel = {_toml_value(can_channel)}",
    ]
    if can_options:
        lines += ["", "[can.options]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in can_options.items()]
    lines += ["", "[mcap]", f"path = {_toml_value(p['logs'])}   # session logs (MCAP)", ""]
    return "\n".join(lines)


def daemon_dir_paths(folder: str | Path, logs: str | Path | None = None) -> dict[str, Path]:
    """The absolute paths ``daemon init`` writes (``config``, ``machine``, ``grid``,
    ``private_key``, ``public_key``) and the session-log folder (``logs``, default
    ``folder/logs``) for the daemon folder ``folder``."""
    from cmm_comp.compensation.grid.signing import PRIVATE_KEY_NAME, PUBLIC_KEY_NAME

    d = Path(folder).absolute()
    return {
        "config": d / CONFIG_NAME,
        "machine": d / MACHINE_NAME,
        "grid": d / GRID_NAME,
        "private_key": d / KEYS_DIR / PRIVATE_KEY_NAME,
        "public_key": d / KEYS_DIR / PUBLIC_KEY_NAME,
        "logs": Path(logs).absolute() if logs is not None else d / LOGS_DIR,
    }


def _refuse_existing(paths: Sequence[Path], folder: Path) -> None:
    there = [p for p in paths if p.exists() or p.is_symlink()]
    if there:
        names = ", ".join(str(p.relative_to(folder)) for p in there)
        raise InitError(
            f"{folder}: already holds {names}; daemon init never overwrites: choose a new "
            "folder (a new grid for an existing daemon: cmm-comp grid build + cmm-comp grid sign)"
        )


def init_daemon_dir(
    directory: str | Path,
    machine_path: str | Path,
    can_interface: str = "socketcan",
    can_channel: str | None = None,
    can_options: Mapping[str, Any] | None = None,
    steps: Sequence[int] | None = None,
    logs: str | Path | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> InitReport:
    """Build, sign and configure (see the module doc); InitError / MachineFileError naming the
    file or flag on bad input, nothing left behind."""
    from cmm_comp.compensation.formats.atomic import write_text_atomic
    from cmm_comp.compensation.grid import CorrectionGrid
    from cmm_comp.compensation.grid.signing import generate_signing_key, sign_grid
    from cmm_comp.compensation.machine import Machine

    folder = Path(directory).absolute()
    if folder.exists() and not folder.is_dir():
        raise InitError(f"{directory}: exists and is not a folder")
    channel = can_channel if can_channel is not None else DEFAULT_CHANNELS.get(can_interface)
    if not channel:
        raise InitError(
            f"--can-interface {can_interface}: give --can-channel (defaults exist only for "
            f"{', '.join(DEFAULT_CHANNELS)})"
        )
    paths = daemon_dir_paths(folder, logs)
    _refuse_existing([paths[k] for k in ("config", "machine", "grid", "private_key")], folder)
    _refuse_existing([paths["public_key"]], folder)
    machine = Machine.from_toml(machine_path)
    grid = CorrectionGrid.build(machine, steps=steps, progress=progress)  # before any write
    text = config_text(
        paths,
        machine.name,
        machine.identity_sha256(),
        can_interface,
        channel,
        dict(can_options or {}),
        list(grid.steps),
    )
    _check_config_text(text, paths["config"])  # a bad --can-option is refused before any write
    keys = paths["private_key"].parent
    # what this run creates, parents first (removed in reverse order if a step fails)
    created = [p for p in (folder, keys) if not p.exists()]
    created += [paths[k] for k in ("machine", "private_key", "public_key", "grid", "config")]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        machine.to_toml(paths["machine"])
        copy = Machine.from_toml(paths["machine"])
        if copy.identity_sha256() != machine.identity_sha256():  # pragma: no cover - a bug
            raise InitError(f"{paths['machine']}: the copy does not describe the same machine")
        private, public = generate_signing_key(keys)
        sha = grid.save(paths["grid"])
        kid = sign_grid(paths["grid"], private)
        write_text_atomic(paths["config"], text)
    except BaseException:
        for path in reversed(created):
            with contextlib.suppress(OSError):  # not made (or a file in the way): nothing to undo
                path.rmdir() if path.is_dir() else path.unlink(missing_ok=True)
        raise
    return InitReport(
        config=paths["config"],
        machine=paths["machine"],
        grid=paths["grid"],
        private_key=private,
        public_key=public,
        logs=paths["logs"],
        grid_sha256=sha,
        key_id=kid,
        machine_name=machine.name,
        steps=(int(grid.steps[0]), int(grid.steps[1]), int(grid.steps[2])),
        can_interface=can_interface,
        can_channel=channel,
    )


def _check_config_text(text: str, path: Path) -> DaemonConfig:
    """The written configuration must load as the daemon loads it (a bad ``--can-option``
    value is named here, before anything is left behind)."""
    try:
        return config_from_dict(tomllib.loads(text), str(path))
    except tomllib.TOMLDecodeError as exc:  # pragma: no cover - _toml_value writes valid TOML
        raise InitError(f"{path}: generated TOML does not parse ({exc})") from None
    except ConfigError as exc:
        raise InitError("\n".join(exc.lines)) from None
