"""Daemon configuration: a TOML file (``tomllib``) whose every setting a CLI flag can override.

Sections and keys are the dataclasses below; each key's type carries its rule (range, unit,
allowed values: :mod:`cmm_comp.compensation.toml_schema`), checked by pydantic, which lists
every problem at once. ``docs/daemon.md`` "Configuration reference" is generated from these
definitions (:mod:`.config_doc`); ``examples/daemon.toml`` shows them all.
:func:`add_override_flags` adds one ``--<section>-<key>`` flag per setting to an argparse parser
(``--can-interface virtual``, ``--modbus-port 1502``, ``--limits-error-um 100``);
:func:`load_config` reads the file and applies the flags given. Errors name the file, the key
and what is allowed (:class:`ConfigError`, one line per problem); nothing is started on a bad
configuration. NaN and ±inf are never allowed: a NaN period would silence the heartbeat, a NaN
limit would switch a check off.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tomllib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, get_origin, get_type_hints

from cmm_comp.compensation.errors import CmmCompError
from cmm_comp.compensation.thermal import TEMPERATURE_ROLES
from cmm_comp.compensation.toml_schema import (
    Choice,
    Num,
    Problem,
    Rule,
    SchemaError,
    Table,
    Vec,
    shown,
    usable,
    validate,
)
from cmm_comp.protocol.can_ids import NODE_STRIDE, STANDARD_ID_MAX

from .live.settings import LiveSection

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


def _multiple_of_stride(base_id: int) -> Iterable[Problem]:
    if base_id % NODE_STRIDE:
        yield f" = {base_id:#x}; allowed: a multiple of {NODE_STRIDE:#x}"


def _sensor_ids(sensors: dict[str, str]) -> Iterable[Problem]:
    for key, role in sensors.items():
        if not key.isdigit() or not 0 <= int(key) <= 255:
            yield f"{{path}} key {key!r} must be 0..255"
        elif role not in TEMPERATURE_ROLES:
            yield (key,), f" = {role!r}; allowed: {TEMPERATURE_ROLES}"


def _known_roles(roles: list[str] | None) -> Iterable[Problem]:
    for role in roles or []:
        if role not in TEMPERATURE_ROLES:
            yield f"{{path}} has unknown role {role!r}"


def _low_high(pair: list[float]) -> Iterable[Problem]:
    if not pair[0] < pair[1]:
        yield f" = {shown(pair)} must be [low, high]"


_LOW_HIGH = Rule(_low_high, doc="low < high")
_STYLUS = Vec(Num(-2000.0, 2000.0, "mm"), n=3)
_TEMP_C = Vec(Num(-100.0, 300.0, "°C"), n=2)
_SECONDS = Num(0.0, 86400.0, "s", lo_open=True)


@dataclass
class GridSection(Table):
    """The correction grid (a file built by ``cmm-comp grid build``)."""

    path: str = ""
    """Grid file; empty = start without a grid (every answer says ``no_grid``)."""
    stylus_mm: Annotated[list[float], _STYLUS] | None = None
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
class CanSection(Table):
    """The CAN side: any python-can interface."""

    enabled: bool = True
    """Answer readings on the CAN bus."""
    interface: str = "socketcan"
    """python-can interface name: socketcan on a real host; virtual or udp_multicast in tests."""
    channel: str = "can0"
    """python-can channel (``can0``; the group address of udp_multicast)."""
    bitrate: Annotated[int, Num(0, 20_000_000, "bit/s")] = 0
    """Bit rate, bit/s; 0 = leave the interface's setting alone."""
    fd: bool = False
    """Open the bus in CAN FD mode (needed for the one-frame pair RAW_XYZ / CORRECTED_XYZ)."""
    node_id: Annotated[int, Num(0, (STANDARD_ID_MAX + 1) // NODE_STRIDE - 1)] = 0
    """Node number: the daemon's ids are ``base_id + 0x10·node_id`` … ``+ 0xF`` (docs/can.md);
    they must stay 11-bit (0 .. 95 at base_id 0x200)."""
    base_id: Annotated[
        int,
        Num(0, STANDARD_ID_MAX + 1 - NODE_STRIDE),
        Rule(_multiple_of_stride, doc=f"a multiple of {NODE_STRIDE:#x}"),
    ] = 0x200
    """First id of node 0, a multiple of 0x10."""
    options: dict[str, Any] = field(default_factory=dict)
    """Extra keyword arguments for ``can.Bus`` (e.g. ``port`` of udp_multicast)."""
    triplet_timeout_s: Annotated[float, Num(0.0, 10.0, "s", lo_open=True)] = 0.05
    """Pending readings are dropped (answered ``incomplete_reading``) after this long without
    any new axis frame, s."""
    window: Annotated[int, Num(1, 1024)] = 4
    """Pending readings the assembler keeps."""
    send_timeout_s: Annotated[float, Num(0.0, 10.0, "s", lo_open=True)] = 0.01
    """How long sending one frame may block, s."""
    heartbeat_s: Annotated[float, Num(0.0, 60.0, "s", lo_open=True)] = 0.1
    """Heartbeat frame period, s (a heartbeat is also sent on every state change)."""
    reconnect_s: Annotated[float, Num(0.0, 600.0, "s", lo_open=True)] = 0.5
    """Delay before reopening the bus after a bus error, s (doubles up to 10 s)."""
    log_frames: bool = True
    """Log every received and sent frame to MCAP (/cmm/can_rx, /cmm/can_tx)."""
    send_uncertainty: bool = False
    """Send each answer's expanded uncertainty U (k = 2) in a CORRECTION_UNCERTAINTY frame
    between CORRECTED_Z and CORRECTION_STATUS (a fifth frame per reading, +25 % answer bus
    load; docs/can.md). U is always in the Modbus registers and the MCAP log."""

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        max_node = (STANDARD_ID_MAX + 1 - self.base_id) // NODE_STRIDE - 1
        if usable(context, "node_id", "base_id") and self.node_id > max_node:
            yield (
                ("node_id",),
                f" = {self.node_id}; allowed: 0 .. {max_node} for base_id {self.base_id:#x} "
                "(ids must stay 11-bit)",
            )


@dataclass
class ModbusSection(Table):
    """The Modbus TCP server (the daemon is the server, the controller the client)."""

    enabled: bool = False
    """Serve the Modbus registers (docs/modbus.md)."""
    host: str = "127.0.0.1"
    """Bind address; 127.0.0.1 unless the controller is on another host."""
    port: Annotated[int, Num(0, 65535)] = 5020
    """TCP port; 0 = any free port (tests)."""
    device_id: Annotated[int, Num(1, 247)] = 1
    """Unit id served (besides 0 and 255, the ids of a directly connected server, docs/modbus.md);
    requests for any other unit id get no response."""
    idle_timeout_s: Annotated[float, Num(0.0, 86400.0, "s", note="0 = never")] = 60.0
    """Close a connection that sends nothing for this long, s; 0 = never."""
    frame_timeout_s: Annotated[float, Num(0.0, 60.0, "s", lo_open=True)] = 1.0
    """A request frame begun must be complete within this, else the connection is closed, s."""


@dataclass
class TemperaturesSection(Table):
    """Temperature sensors and the checks applied to them."""

    sensors: Annotated[
        dict[str, str], Rule(_sensor_ids, doc=f"ids 0..255, roles {', '.join(TEMPERATURE_ROLES)}")
    ] = field(default_factory=lambda: {"0": "T_x", "1": "T_y", "2": "T_z", "3": "T_wp"})
    """Sensor id (as a string key, 0..255) → role (T_x, T_y, T_z, T_wp, T_top, T_bottom,
    T_air)."""
    required: Annotated[list[str], Rule(_known_roles, doc="roles as in sensors")] | None = None
    """Roles a reading needs; None (not set) = the ones the grid needs."""
    stale_s: Annotated[float, _SECONDS] = 10.0
    """A sensor whose sample counter has not changed for this long is stale, s."""
    plausible_C: Annotated[list[float], _TEMP_C, _LOW_HIGH] = field(
        default_factory=lambda: [-10.0, 60.0]
    )
    """Readings outside this range [low, high] are sensor faults (implausible), °C."""
    valid_range_C: Annotated[list[float], _TEMP_C, _LOW_HIGH] = field(
        default_factory=lambda: [10.0, 40.0]
    )
    """Range [low, high] the compensation is valid for; outside it the reading is not
    corrected, °C."""
    max_rate_C_per_s: Annotated[float, Num(0.0, 1e9, "°C/s", lo_open=True)] = 2.0
    """A faster change between two samples is implausible, °C/s."""
    on_fault: Annotated[str, Choice(("reject", "geometry_only"))] = "reject"
    """``reject``: answer the indicated position with the fault status; ``geometry_only``:
    apply the geometric correction and answer ``not_thermally_corrected``."""


@dataclass
class LimitsSection(Table):
    """Bounds on the size of a correction (length of the correction vector)."""

    warn_um: Annotated[float, Num(0.0, 1e6, "µm", lo_open=True)] = 50.0
    """Larger corrections are applied but counted and logged as warnings, µm."""
    error_um: Annotated[float, Num(0.0, 1e6, "µm", lo_open=True)] = 200.0
    """Larger corrections are refused: answer ``correction_limit`` with the indicated position,
    µm; at least ``warn_um``."""

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        if usable(context, "warn_um", "error_um") and not self.warn_um <= self.error_um:
            yield (f"{{path}} need 0 < warn_um <= error_um, got {self.warn_um} and {self.error_um}")


@dataclass
class McapSection(Table):
    """Session log (MCAP): empty path = off."""

    path: str = ""
    """A directory (rolled files ``session-…-NNN.mcap``) or one ``*.mcap`` file; empty = off."""
    roll_mb: Annotated[float, Num(0.0, 1e6, "MB", note="0 = never")] = 256.0
    """Roll files at this size, MB (directories only; 0 = never)."""
    roll_s: Annotated[float, Num(0.0, 1e7, "s", note="0 = never")] = 3600.0
    """Roll files at this age, s (directories only; 0 = never)."""
    flush_s: Annotated[float, Num(0.0, 3600.0, "s", lo_open=True)] = 1.0
    """Cut a chunk at least this often: the most a crash loses, s."""
    compression: Annotated[str, Choice(MCAP_COMPRESSIONS)] = "zstd"
    """Chunk compression: ``zstd`` (smallest files), ``lz4`` (faster, less CPU and cache per
    chunk) or ``none``."""


@dataclass
class MetricsSection(Table):
    """Counters and latency histogram: Prometheus text on localhost and the MCAP status topic."""

    enabled: bool = True
    """Serve ``/metrics`` (Prometheus text format)."""
    host: str = "127.0.0.1"
    """Bind address of ``/metrics``."""
    port: Annotated[int, Num(0, 65535)] = 9108
    """HTTP port of ``/metrics``; 0 = any free port."""
    period_s: Annotated[float, Num(0.0, 3600.0, "s", lo_open=True)] = 1.0
    """Counters are published to /cmm/counters this often, s."""


@dataclass
class LogSection(Table):
    """Structured logs: one line per event on stdout."""

    format: Annotated[str, Choice(("json", "logfmt"))] = "json"
    """``json`` or ``logfmt``."""
    level: Annotated[str, Choice(("debug", "info", "warning", "error"))] = "info"
    """``debug``, ``info``, ``warning`` or ``error``."""
    max_per_s: Annotated[float, Num(0.0, 1e6, "lines/s", note="0 = unlimited")] = 20.0
    """Repeated events of one kind are rate-limited to this many lines per second."""
    state_repeat_s: Annotated[float, _SECONDS] = 10.0
    """A state line whose only change is its detail text (a stale sensor's age) is repeated at
    most this often, with the count of changes in between, s."""


@dataclass
class DaemonConfig(Table):
    """The whole daemon configuration."""

    NOT_IN_FILE: ClassVar[frozenset[str]] = frozenset({"source", "notes"})

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
    """The file the configuration was read from (not a key of the file)."""
    notes: list[str] = field(default_factory=list)
    """Warnings about the file that do not stop it loading (a removed key, :data:`REMOVED_KEYS`)."""

    @classmethod
    def unknown_key(cls, key: str, value: Any) -> str:
        return f"unknown section [{{path}}]; allowed: {', '.join(cls.toml_keys())}"

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        if usable(context, "can", "modbus") and not (self.can.enabled or self.modbus.enabled):
            yield "enable at least one of can.enabled, modbus.enabled"

    def check(self) -> DaemonConfig:
        """Validate every value and rule; ConfigError listing every problem (one line each,
        naming the key). Returns self."""
        problems = self.problems()
        if problems:
            raise ConfigError(problems)
        return self

    def problems(self) -> list[str]:
        """Every rule the current values break, one line each (for a config built or changed in
        code; a file is checked as it is read)."""
        data = {s: dataclasses.asdict(getattr(self, s)) for s in self.toml_keys()}
        try:
            validate(DaemonConfig, data, self.source)
        except SchemaError as exc:
            return exc.lines
        return []

    def sensor_roles(self) -> dict[int, str]:
        """Sensor id → role."""
        return {int(k): v for k, v in self.temperatures.sensors.items()}


def section_types(section: str) -> dict[str, Any]:
    """Key → type (without its rule) of the section ``section``."""
    cls = type(getattr(DaemonConfig(), section))
    hints = get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)}


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
    raising: what ``--check`` needs to go on checking the files the config names. A key with a
    problem keeps its default; the others are as given."""
    data, notes, removed = _without_removed_keys(data, source)
    try:
        cfg: DaemonConfig = validate(DaemonConfig, data, source)
    except SchemaError as exc:
        problems = removed + exc.lines
    else:
        cfg.source, cfg.notes = source, notes
        return cfg, removed
    usable = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    for _ in range(3):  # drop what is bad, then what the rules skipped still finds bad
        try:
            cfg = validate(DaemonConfig, usable, source, {"rules": False})
        except SchemaError as again:
            for loc in again.locs:
                table = usable.get(loc[0]) if len(loc) > 1 else None
                if isinstance(table, dict):
                    table.pop(loc[1], None)
                else:
                    usable.pop(loc[0], None)  # type: ignore[call-overload]
            continue
        cfg.source, cfg.notes = source, notes
        return cfg, problems
    return DaemonConfig(source=source, notes=notes), problems


def _without_removed_keys(
    data: dict[str, Any], source: str
) -> tuple[dict[str, Any], list[str], list[str]]:
    """``data`` without the keys of :data:`REMOVED_KEYS`, the notes (a removed key giving the
    behaviour left) and the errors (one giving another value)."""
    notes: list[str] = []
    errors: list[str] = []
    out = dict(data)
    for name, (kept, why) in REMOVED_KEYS.items():
        section, key = name.split(".")
        table = out.get(section)
        if not isinstance(table, dict) or key not in table:
            continue
        table = out[section] = dict(table)
        value = table.pop(key)
        if value == kept:
            notes.append(f"{source}: {name} is no longer a setting ({why}): delete the line")
        else:
            errors.append(
                f"{source}: {name} = {shown(value)} was removed ({why}; {kept!r} was the "
                "default): delete the line"
            )
    return out, notes, errors


def add_override_flags(parser: argparse.ArgumentParser) -> None:
    """Add ``--<section>-<key>`` for every setting (values in TOML syntax for lists/tables)."""
    group = parser.add_argument_group("configuration overrides (each wins over the file)")
    for section in DaemonConfig.toml_keys():
        for key, hint in section_types(section).items():
            flag = f"--{section}-{key}".replace("_", "-")
            dest = f"cfg__{section}__{key}"
            if hint is bool:
                group.add_argument(flag, dest=dest, action=argparse.BooleanOptionalAction)
            else:
                group.add_argument(flag, dest=dest, metavar="VALUE", default=None)


def _parse_flag(text: str, hint: Any) -> Any:
    """A flag's text as a TOML value (lists, tables, numbers; JSON for lists and tables too),
    else as the text itself: the check then names the flag's value."""
    if hint is str:
        return text
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
        if get_origin(hint) is not None:
            try:
                return json.loads(text)
            except (json.JSONDecodeError, RecursionError):
                pass
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
            table = data.setdefault(section, {})
            if not isinstance(table, dict):  # `can = 3` in the file: the check names it
                continue
            hint = section_types(section)[key]
            table[key] = _parse_flag(value, hint) if isinstance(value, str) else value
    return data, source
