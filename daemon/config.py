"""Daemon configuration: a TOML file (``tomllib``) whose every setting a CLI flag can override.

Sections and keys mirror the dataclasses below (``examples/daemon.toml`` documents them all).
:func:`add_override_flags` adds one ``--<section>-<key>`` flag per setting to an argparse
parser (``--can-interface virtual``, ``--modbus-port 1502``, ``--limits-error-um 100``);
:func:`load_config` reads the file and applies the flags given. Errors name the file, the key
and what is allowed (:class:`ConfigError`); nothing is started on a bad configuration.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, get_args, get_origin, get_type_hints

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.thermal import TEMPERATURE_ROLES
from cmm_comp.protocol.can_ids import NODE_STRIDE, STANDARD_ID_MAX

from .config_checks import range_errors
from .live.settings import LIVE_RULES, LiveSection, live_problems

MCAP_COMPRESSIONS = ("zstd", "lz4", "none")
REMOVED_KEYS: dict[str, tuple[str, str]] = {
    "mcap.writer": ("process", "the session log is always written in a child process"),
    "mcap.writer_priority": ("idle", "the session log's writer always runs at SCHED_IDLE"),
    "live.sender": ("process", "the live view always runs in a child process"),
}
"""Keys of earlier versions: ``key → (the only behaviour left, why)``. A file giving that value
loads with a note to delete the line; any other value is an error."""


class ConfigError(CmmCompError, ValueError):
    """A daemon configuration file or flag is invalid (message names the key and the rule).

    ``lines``: one line per problem (the message is those lines joined by newlines).
    """

    def __init__(self, message: str | list[str]) -> None:
        self.lines = [message] if isinstance(message, str) else list(message)
        super().__init__("\n".join(self.lines))


@dataclass
class GridSection:
    """The correction grid (a file built by ``cmm-comp grid build``)."""

    path: str = ""
    """Grid file; empty = start without a grid (every answer says ``no_grid``)."""
    stylus_mm: list[float] | None = None
    """Stylus tip offset used for every reading, mm (X, Y, Z); None (not set) = the grid's
    probe offset (the machine's ``[probe] offset_mm`` it was built with). A value that differs
    from the grid's is used, and said at start and by ``--check``."""
    machine: str = ""
    """The machine description (TOML) the grid must have been built from: its sha256 is
    computed here and the grid's volume must lie inside the machine's."""
    expect_machine_sha256: str = ""
    """Alternatively the machine description's sha256 (hex); both set must agree."""
    allow_any_machine: bool = False
    """Accept grids of any machine when neither ``machine`` nor ``expect_machine_sha256`` is set."""
    public_key: str = ""
    """Ed25519 public key (PEM) grids must be signed with (``cmm-comp grid sign``)."""
    allow_unsigned: bool = False
    """Accept grids without a signature (a signature present is still checked against
    ``public_key`` when one is set)."""


@dataclass
class CanSection:
    """The CAN side: any python-can interface."""

    enabled: bool = True
    interface: str = "socketcan"
    """python-can interface name: socketcan on a real host; virtual or udp_multicast in tests."""
    channel: str = "can0"
    bitrate: int = 0
    """Bit rate, bit/s; 0 = leave the interface's setting alone."""
    fd: bool = False
    node_id: int = 0
    base_id: int = 0x200
    options: dict[str, Any] = field(default_factory=dict)
    """Extra keyword arguments for ``can.Bus`` (e.g. ``port`` of udp_multicast)."""
    triplet_timeout_s: float = 0.05
    """Pending readings are dropped (answered ``incomplete_reading``) after this long without
    any new axis frame, s."""
    window: int = 4
    """Pending readings the assembler keeps."""
    send_timeout_s: float = 0.01
    heartbeat_s: float = 0.1
    reconnect_s: float = 0.5
    """Delay before reopening the bus after a bus error, s (doubles up to 10 s)."""
    log_frames: bool = True
    """Log every received and sent frame to MCAP (/cmm/can_rx, /cmm/can_tx)."""
    send_uncertainty: bool = False
    """Send each answer's expanded uncertainty U (k = 2) in a CORRECTION_UNCERTAINTY frame
    between CORRECTED_Z and CORRECTION_STATUS (a fifth frame per reading, +25 % answer bus
    load; docs/can.md). U is always in the Modbus registers and the MCAP log."""


@dataclass
class ModbusSection:
    """The Modbus TCP server (the daemon is the server, the controller the client)."""

    enabled: bool = False
    host: str = "127.0.0.1"
    """Bind address; 127.0.0.1 unless the controller is on another host."""
    port: int = 5020
    """TCP port; 0 = any free port (tests)."""
    device_id: int = 1
    """Unit id served (besides 0 and 255, the ids of a directly connected server, docs/modbus.md);
    requests for any other unit id get no response."""
    idle_timeout_s: float = 60.0
    """Close a connection that sends nothing for this long, s; 0 = never."""
    frame_timeout_s: float = 1.0
    """A request frame begun must be complete within this, else the connection is closed, s."""


@dataclass
class TemperaturesSection:
    """Temperature sensors and the checks applied to them."""

    sensors: dict[str, str] = field(
        default_factory=lambda: {"0": "T_x", "1": "T_y", "2": "T_z", "3": "T_wp"}
    )
    """Sensor id (as a string key) → role (T_x, T_y, T_z, T_wp, T_top, T_bottom, T_air)."""
    required: list[str] | None = None
    """Roles a reading needs; None = the ones the grid needs."""
    stale_s: float = 10.0
    """A sensor whose sample counter has not changed for this long is stale, s."""
    plausible_C: list[float] = field(default_factory=lambda: [-10.0, 60.0])
    """Readings outside this range are sensor faults (implausible), °C."""
    valid_range_C: list[float] = field(default_factory=lambda: [10.0, 40.0])
    """Range the compensation is valid for; outside it the reading is not corrected, °C."""
    max_rate_C_per_s: float = 2.0
    """A faster change between two samples is implausible, °C/s."""
    on_fault: str = "reject"
    """``reject``: answer the indicated position with the fault status; ``geometry_only``:
    apply the geometric correction and answer ``not_thermally_corrected``."""


@dataclass
class LimitsSection:
    """Bounds on the size of a correction (length of the correction vector)."""

    warn_um: float = 50.0
    """Larger corrections are applied but counted and logged as warnings, µm."""
    error_um: float = 200.0
    """Larger corrections are refused: answer ``correction_limit`` with the indicated position, µm."""


@dataclass
class McapSection:
    """Session log (MCAP): empty path = off."""

    path: str = ""
    """A directory (rolled files ``session-…-NNN.mcap``) or one ``*.mcap`` file."""
    roll_mb: float = 256.0
    """Roll files at this size, MB (directories only; 0 = never)."""
    roll_s: float = 3600.0
    """Roll files at this age, s (directories only; 0 = never)."""
    flush_s: float = 1.0
    """Cut a chunk at least this often: the most a crash loses, s."""
    compression: str = "zstd"
    """Chunk compression: ``zstd`` (smallest files), ``lz4`` (faster, less CPU and cache per
    chunk) or ``none``."""


@dataclass
class MetricsSection:
    """Counters and latency histogram: Prometheus text on localhost and the MCAP status topic."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = 9108
    """HTTP port of ``/metrics``; 0 = any free port."""
    period_s: float = 1.0
    """Counters are published to /cmm/counters this often, s."""


@dataclass
class LogSection:
    """Structured logs: one line per event on stdout."""

    format: str = "json"
    """``json`` or ``logfmt``."""
    level: str = "info"
    """``debug``, ``info``, ``warning`` or ``error``."""
    max_per_s: float = 20.0
    """Repeated events of one kind are rate-limited to this many lines per second."""
    state_repeat_s: float = 10.0
    """A state line whose only change is its detail text (a stale sensor's age) is repeated at
    most this often, with the count of changes in between, s."""


@dataclass
class DaemonConfig:
    """The whole daemon configuration."""

    grid: GridSection = field(default_factory=GridSection)
    can: CanSection = field(default_factory=CanSection)
    modbus: ModbusSection = field(default_factory=ModbusSection)
    temperatures: TemperaturesSection = field(default_factory=TemperaturesSection)
    limits: LimitsSection = field(default_factory=LimitsSection)
    mcap: McapSection = field(default_factory=McapSection)
    metrics: MetricsSection = field(default_factory=MetricsSection)
    log: LogSection = field(default_factory=LogSection)
    live: LiveSection = field(default_factory=LiveSection)
    source: str = "<defaults>"
    notes: list[str] = field(default_factory=list)
    """Warnings about the file that do not stop it loading (a removed key, :data:`REMOVED_KEYS`)."""

    def check(self) -> DaemonConfig:
        """Validate ranges and cross-field rules; ConfigError listing every problem (one line
        each, naming the key). Returns self."""
        problems = self.problems()
        if problems:
            raise ConfigError(problems)
        return self

    def numeric_values(self) -> dict[str, Any]:
        """``section.key`` → value of every numeric setting (ints, floats, lists of floats;
        None for an optional one left unset)."""
        out: dict[str, Any] = {}
        for section in _SECTIONS:
            for key, hint in _section_types(section).items():
                hint = _unwrap_optional(hint)
                if hint in (int, float) or (
                    get_origin(hint) is list and get_args(hint)[0] is float
                ):
                    out[f"{section}.{key}"] = getattr(getattr(self, section), key)
        return out

    def problems(self, skip: set[str] | None = None) -> list[str]:
        """Every rule violated, one line each; keys in ``skip`` (already reported) are left out."""
        where = self.source
        skip = set(skip or ())
        live_keys = {f"live.{k}" for k in LIVE_RULES}  # ranged by live_problems below
        ranges = range_errors(where, self.numeric_values(), skip | live_keys)
        out = list(ranges.values())
        bad = skip | set(ranges)
        t = self.temperatures
        for key, role in t.sensors.items():
            if not key.isdigit() or not 0 <= int(key) <= 255:
                out.append(f"{where}: temperatures.sensors key {key!r} must be 0..255")
            elif role not in TEMPERATURE_ROLES:
                out.append(
                    f"{where}: temperatures.sensors.{key} = {role!r}; allowed: {TEMPERATURE_ROLES}"
                )
        for role in t.required or []:
            if role not in TEMPERATURE_ROLES:
                out.append(f"{where}: temperatures.required has unknown role {role!r}")
        if t.on_fault not in ("reject", "geometry_only"):
            out.append(
                f"{where}: temperatures.on_fault = {t.on_fault!r}; allowed: reject, geometry_only"
            )
        for name in ("plausible_C", "valid_range_C"):
            lo_hi = getattr(t, name)
            if f"temperatures.{name}" not in bad and not lo_hi[0] < lo_hi[1]:
                out.append(f"{where}: temperatures.{name} = {lo_hi} must be [low, high]")
        lim = self.limits
        if not {"limits.warn_um", "limits.error_um"} & bad and not lim.warn_um <= lim.error_um:
            out.append(
                f"{where}: limits need 0 < warn_um <= error_um, got "
                f"{lim.warn_um} and {lim.error_um}"
            )
        if "can.base_id" not in bad and self.can.base_id % NODE_STRIDE:
            out.append(
                f"{where}: can.base_id = {self.can.base_id:#x}; allowed: a multiple of "
                f"{NODE_STRIDE:#x}"
            )
        elif not {"can.base_id", "can.node_id"} & bad:
            max_node = (STANDARD_ID_MAX + 1 - self.can.base_id) // NODE_STRIDE - 1
            if self.can.node_id > max_node:
                out.append(
                    f"{where}: can.node_id = {self.can.node_id}; allowed: 0 .. {max_node} for "
                    f"base_id {self.can.base_id:#x} (ids must stay 11-bit)"
                )
        if self.log.format not in ("json", "logfmt"):
            out.append(f"{where}: log.format = {self.log.format!r}; allowed: json, logfmt")
        if self.log.level not in ("debug", "info", "warning", "error"):
            out.append(
                f"{where}: log.level = {self.log.level!r}; allowed: debug, info, warning, error"
            )
        if not (self.can.enabled or self.modbus.enabled):
            out.append(f"{where}: enable at least one of can.enabled, modbus.enabled")
        if self.mcap.compression not in MCAP_COMPRESSIONS:
            out.append(
                f"{where}: mcap.compression = {self.mcap.compression!r}; allowed: "
                f"{', '.join(MCAP_COMPRESSIONS)}"
            )
        out += live_problems(self.live, where, skip)
        return out

    def sensor_roles(self) -> dict[int, str]:
        """Sensor id → role."""
        return {int(k): v for k, v in self.temperatures.sensors.items()}


_SECTIONS = [f.name for f in dataclasses.fields(DaemonConfig) if f.name not in ("source", "notes")]


def _section_types(section: str) -> dict[str, Any]:
    cls = type(getattr(DaemonConfig(), section))
    return get_type_hints(cls)


def _unwrap_optional(hint: Any) -> Any:
    """``X`` of ``X | None``; other hints unchanged."""
    args = get_args(hint)
    if type(None) in args and len(args) == 2:
        return next(a for a in args if a is not type(None))
    return hint


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (a flag may be any length)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 1]}…"


def _coerce(where: str, value: Any, hint: Any) -> Any:
    """Check/convert a TOML or flag value to the field's type."""
    origin = get_origin(hint)
    args = get_args(hint)
    if origin is not None and type(None) in args:  # X | None
        if value is None:
            return None
        hint = next(a for a in args if a is not type(None))
        origin, args = get_origin(hint), get_args(hint)
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: {_short(value)} must be true or false")
    if hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise ConfigError(f"{where}: {_short(value)} must be an integer")
    if hint is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError:
                raise ConfigError(f"{where}: {_short(value)} is too large") from None
        raise ConfigError(f"{where}: {_short(value)} must be a number")
    if hint is str:
        if isinstance(value, str):
            return value
        raise ConfigError(f"{where}: {_short(value)} must be a string")
    if origin is list:
        if not isinstance(value, list):
            raise ConfigError(f"{where}: {_short(value)} must be a list")
        return [_coerce(f"{where}[{i}]", v, args[0]) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: {_short(value)} must be a table")
        return {
            str(k): (v if args[1] is Any else _coerce(f"{where}.{k}", v, args[1]))
            for k, v in value.items()
        }
    return value


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> DaemonConfig:
    """Build and validate a config from parsed TOML; unknown sections or keys are errors.

    Every problem is collected (one line each: unknown section/key, wrong type, out of range,
    cross-field rule) and raised together as one :class:`ConfigError`.
    """
    cfg, errors = config_and_problems(data, source)
    if errors:
        raise ConfigError(errors)
    return cfg


def config_and_problems(
    data: dict[str, Any], source: str = "<dict>"
) -> tuple[DaemonConfig, list[str]]:
    """The config built from parsed TOML and every problem found (one line each), without
    raising: what ``--check`` needs to go on checking the files the config names. A value of
    the wrong type keeps the default; one out of range is kept as given (and listed)."""
    cfg = DaemonConfig(source=source)
    errors: list[str] = []
    reported: set[str] = set()
    for section, table in data.items():
        if section not in _SECTIONS:
            errors.append(f"{source}: unknown section [{section}]; allowed: {', '.join(_SECTIONS)}")
            continue
        if not isinstance(table, dict):
            errors.append(f"{source}: [{section}] must be a table")
            continue
        types = _section_types(section)
        obj = getattr(cfg, section)
        for key, value in table.items():
            if f"{section}.{key}" in REMOVED_KEYS:
                _removed(f"{section}.{key}", value, source, cfg.notes, errors)
                continue
            if key not in types:
                errors.append(
                    f"{source}: unknown key {section}.{key}; allowed: {', '.join(sorted(types))}"
                )
                continue
            try:
                setattr(obj, key, _coerce(f"{source}: {section}.{key}", value, types[key]))
            except ConfigError as exc:
                errors.append(str(exc))
                reported.add(f"{section}.{key}")
    errors += cfg.problems(skip=reported)
    return cfg, errors


def _removed(name: str, value: Any, source: str, notes: list[str], errors: list[str]) -> None:
    """A key of :data:`REMOVED_KEYS`: a note when ``value`` is the behaviour left, else an error."""
    kept, why = REMOVED_KEYS[name]
    if value == kept:
        notes.append(f"{source}: {name} is no longer a setting ({why}): delete the line")
    else:
        errors.append(
            f"{source}: {name} = {_short(value)} was removed ({why}; {kept!r} was the default): "
            "delete the line"
        )


def add_override_flags(parser: argparse.ArgumentParser) -> None:
    """Add ``--<section>-<key>`` for every setting (values in TOML syntax for lists/tables)."""
    group = parser.add_argument_group("configuration overrides (each wins over the file)")
    for section in _SECTIONS:
        for key, hint in _section_types(section).items():
            flag = f"--{section}-{key}".replace("_", "-")
            dest = f"cfg__{section}__{key}"
            if hint is bool:
                group.add_argument(flag, dest=dest, action=argparse.BooleanOptionalAction)
            else:
                group.add_argument(flag, dest=dest, metavar="VALUE", default=None)


def _parse_flag(text: str, hint: Any) -> Any:
    if hint is str:
        return text
    if hint in (int, float) or get_origin(hint) is not None or hint is Any:
        try:
            return tomllib.loads(f"v = {text}")["v"]
        except (tomllib.TOMLDecodeError, RecursionError):
            if get_origin(hint) is not None:
                try:
                    return json.loads(text)
                except (json.JSONDecodeError, RecursionError):
                    pass
            return text
    return text


def load_config(path: str | Path | None, args: argparse.Namespace | None = None) -> DaemonConfig:
    """Read ``path`` (None = defaults), then apply the override flags present in ``args``."""
    data, source = _read_with_flags(path, args)
    return config_from_dict(data, source)


def load_config_and_problems(
    path: str | Path | None, args: argparse.Namespace | None = None
) -> tuple[DaemonConfig, list[str]]:
    """:func:`load_config` that lists the problems instead of raising on them (``--check``);
    ConfigError only when the file cannot be read as TOML at all."""
    data, source = _read_with_flags(path, args)
    return config_and_problems(data, source)


def _read_with_flags(
    path: str | Path | None, args: argparse.Namespace | None
) -> tuple[dict[str, Any], str]:
    """The parsed file (empty for None) with the override flags of ``args`` applied, and its
    name; ConfigError (one line) when the file is missing or not TOML."""
    data: dict[str, Any] = {}
    source = "<defaults>"
    if path is not None:
        source = str(path)
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{source}: configuration file not found") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{source}: not valid TOML: {exc}") from None
        except RecursionError:
            raise ConfigError(f"{source}: not valid TOML: nested too deeply") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{source}: cannot read the configuration file ({exc})") from None
    if args is not None:
        for name, value in vars(args).items():
            if not name.startswith("cfg__") or value is None:
                continue
            _, section, key = name.split("__")
            hint = _section_types(section)[key]
            data.setdefault(section, {})[key] = (
                _parse_flag(value, hint) if isinstance(value, str) else value
            )
    return data, source
