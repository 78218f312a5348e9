"""Daemon configuration: the example file loads, flags override every key, errors name the key."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_daemon_support import ROOT

from cmm_comp.cli.daemon import add_parsers
from cmm_comp.daemon.config import ConfigError, load_config
from cmm_comp.daemon.temperatures import TemperatureTable
from cmm_comp.protocol.codes import Status

EXAMPLE = ROOT / "examples" / "daemon.toml"


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_parsers(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


def test_example_config_loads_and_flags_override() -> None:
    cfg = load_config(EXAMPLE)
    assert cfg.can.interface == "socketcan"
    assert cfg.grid.stylus_mm is None  # unset: the grid's probe offset (issue 25)
    # the example binds the machine and requires signed grids (issue 12: no silent foreign grid)
    assert cfg.grid.machine and cfg.grid.public_key
    assert not cfg.grid.allow_unsigned and not cfg.grid.allow_any_machine
    args = _parse(
        [
            "daemon",
            "--config",
            str(EXAMPLE),
            "--can-interface",
            "virtual",
            "--modbus-port",
            "0",
            "--no-can-log-frames",
            "--grid-stylus-mm",
            "[1, 2, 3]",
            "--limits-error-um",
            "120",
            "--temperatures-sensors",
            '{"7" = "T_air"}',
            "--can-options",
            "{port = 45000}",
        ]
    )
    cfg = load_config(args.config, args)
    assert cfg.can.interface == "virtual" and cfg.modbus.port == 0
    assert cfg.can.log_frames is False
    assert cfg.grid.stylus_mm == [1.0, 2.0, 3.0]
    assert cfg.limits.error_um == 120.0
    assert cfg.sensor_roles() == {7: "T_air"}
    assert cfg.can.options == {"port": 45000}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[cann]\nx = 1\n", r"unknown section \[cann\]"),
        ("[can]\nbitrat = 5\n", r"unknown key can\.bitrat"),
        ("[can]\nbitrate = 'fast'\n", r"can\.bitrate: 'fast' must be an integer"),
        ('[temperatures]\nsensors = {"0" = "T_q"}\n', r"temperatures\.sensors\.0 = 'T_q'"),
        ("[temperatures]\non_fault = 'ignore'\n", r"on_fault = 'ignore'; allowed"),
        ("[limits]\nwarn_um = 10.0\nerror_um = 5.0\n", r"warn_um <= error_um"),
        ("[grid\n", r"not valid TOML"),
    ],
)
def test_bad_config_names_the_key(tmp_path, text: str, match: str) -> None:
    path = tmp_path / "d.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_config(path)


def test_missing_config_file(tmp_path) -> None:
    with pytest.raises(ConfigError, match="configuration file not found"):
        load_config(tmp_path / "nope.toml")


def test_temperature_table_rules() -> None:
    cfg = load_config(EXAMPLE).temperatures
    cfg.stale_s = 1.0
    table = TemperatureTable(cfg, {0: "T_x", 1: "T_wp"})
    assert table.update(9, 20.0, 1, True, 0.0) is None  # unknown sensor
    table.update(0, 20.4, 1, True, 0.0)
    v = table.inputs(("T_x", "T_wp"), 0.1)
    assert v.status == Status.NO_TEMPERATURE and v.temps_C == {"T_x": 20.4}
    table.update(1, 20.0, 1, True, 0.0)
    assert table.inputs(("T_x", "T_wp"), 0.5).status is None
    table.update(0, 20.4, 1, True, 0.9)  # same counter: not a new sample
    v = table.inputs(("T_x",), 1.5)
    assert v.status == Status.STALE_TEMPERATURE and "unchanged" in v.detail
    table.update(0, 20.5, 2, True, 2.0)
    assert table.inputs(("T_x",), 2.1).status is None
    table.update(0, 28.0, 3, True, 2.2)  # 7.5 °C in 0.2 s
    v = table.inputs(("T_x",), 2.3)
    assert v.status == Status.IMPLAUSIBLE_TEMPERATURE and "jumped" in v.detail
    table.update(0, -100.0, 4, True, 10.0)
    assert "plausible" in table.inputs(("T_x",), 10.0).detail
    table.update(0, 20.0, 5, False, 20.0)
    assert table.inputs(("T_x",), 20.0).status == Status.NO_TEMPERATURE


_OPS = st.lists(
    st.one_of(
        st.tuples(  # a sample: sensor, temperature, counter step, valid, time step
            st.just("update"),
            st.integers(0, 2),
            st.floats(19.0, 21.0),
            st.integers(0, 1),
            st.booleans(),
            st.floats(0.0, 0.8),
        ),
        st.tuples(st.just("inputs"), st.integers(0, 2), st.floats(0.0, 1.5)),
    ),
    max_size=40,
)


@given(ops=_OPS)
def test_temperature_verdict_reuse_equals_a_fresh_check(ops) -> None:
    """inputs() reuses its last all-usable verdict; the oracle is the same rules evaluated
    afresh (``_check``) after every step, at every time, for every set of roles."""
    cfg = load_config(EXAMPLE).temperatures
    cfg.stale_s = 1.0
    cfg.max_rate_C_per_s = 1e9
    table = TemperatureTable(cfg, {0: "T_x", 1: "T_y", 2: "T_wp"})
    role_sets = [("T_x",), ("T_x", "T_y"), ("T_x", "T_y", "T_wp")]
    counters = [0, 0, 0]
    now = 0.0
    for op in ops:
        if op[0] == "update":
            _, sensor, temp, step, valid, dt = op
            now += dt
            counters[sensor] = (counters[sensor] + step) & 0xFFFF
            table.update(sensor, temp, counters[sensor], valid, now)
        else:
            _, which, dt = op
            t = now + dt
            required = role_sets[which]
            got = table.inputs(required, t)
            assert got == table._check(required, t)


# --------------------------------------------------------------------------- numeric ranges
# The allowed ranges as documented (examples/daemon.toml, docs/daemon.md "Configuration"),
# written out here independently of daemon/config_checks.py: key -> (kind, zero allowed).
# Every key's lower bound is >= 0, so -1 is never allowed for a scalar; NaN, inf, a huge value
# and a string never are. List keys get the probe value as their first element.
NUMERIC_KEYS: dict[str, tuple[str, bool]] = {
    "grid.stylus_mm": ("list3", True),
    "can.bitrate": ("int", True),
    "can.node_id": ("int", True),
    "can.base_id": ("int", True),
    "can.triplet_timeout_s": ("float", False),
    "can.window": ("int", False),
    "can.send_timeout_s": ("float", False),
    "can.heartbeat_s": ("float", False),
    "can.reconnect_s": ("float", False),
    "modbus.port": ("int", True),
    "modbus.device_id": ("int", False),  # 1..247 (docs/modbus.md; 0 and 255 always served)
    "modbus.idle_timeout_s": ("float", True),  # 0 = never
    "modbus.frame_timeout_s": ("float", False),
    "temperatures.stale_s": ("float", False),
    "temperatures.plausible_C": ("pair", True),
    "temperatures.valid_range_C": ("pair", True),
    "temperatures.max_rate_C_per_s": ("float", False),
    "limits.warn_um": ("float", False),
    "limits.error_um": ("float", False),
    "mcap.roll_mb": ("float", True),
    "mcap.roll_s": ("float", True),
    "mcap.flush_s": ("float", False),
    "metrics.port": ("int", True),
    "metrics.period_s": ("float", False),
    "log.max_per_s": ("float", True),
    "log.state_repeat_s": ("float", False),
    "live.port": ("int", True),  # 0 = any free port
    "live.queue": ("int", False),
    "live.update_rate_hz": ("float", False),
    "live.max_per_update": ("int", False),
    "live.scene_rate_hz": ("float", False),
    "live.scene_keep_arrows": ("int", False),
    "live.scene_max_new_arrows": ("int", False),
    "live.arrow_mm_per_um": ("float", False),
}
PROBES = {"nan": "nan", "inf": "inf", "-1": "-1", "0": "0", "huge": None, "string": "'fast'"}


def _toml_value(key: str, probe: str) -> str:
    kind, _ = NUMERIC_KEYS[key]
    text = PROBES[probe] or ("1000000000000000" if kind == "int" else "1e300")
    if kind == "list3":
        return f"[{text}, 0.0, 0.0]"
    if kind == "pair":
        return f"[{text}, 35.0]"
    return text


def _allowed(key: str, probe: str) -> bool:
    kind, zero_ok = NUMERIC_KEYS[key]
    if probe == "0":
        return zero_ok
    if probe == "-1":
        return kind in ("list3", "pair")  # -1 mm stylus offset, -1 °C lower bound are fine
    return False


def _toml(keys: dict[str, str]) -> str:
    sections: dict[str, list[str]] = {}
    for key, value in keys.items():
        section, name = key.split(".")
        sections.setdefault(section, []).append(f"{name} = {value}")
    return "".join(f"[{s}]\n" + "\n".join(lines) + "\n" for s, lines in sections.items())


def test_every_numeric_setting_has_a_documented_range() -> None:
    """A new numeric key must be added to this table (and so get a range): the definitions'
    numeric keys (int and float fields, lists of floats) are exactly the table's, and each
    has a range rule."""
    from cmm_comp.compensation.toml_schema import Num, Vec, rule_of
    from cmm_comp.daemon.config import DaemonConfig, section_types

    numeric = set()
    for section in DaemonConfig.toml_keys():
        cls = type(getattr(DaemonConfig(), section))
        for key, hint in section_types(section).items():
            if "int" in str(hint) or "float" in str(hint):
                numeric.add(f"{section}.{key}")
                assert isinstance(rule_of(cls, key), Num | Vec), (section, key)
    assert numeric == set(NUMERIC_KEYS)


@pytest.mark.parametrize("probe", list(PROBES))
@pytest.mark.parametrize("key", list(NUMERIC_KEYS))
def test_numeric_setting_probe(tmp_path, key: str, probe: str) -> None:
    path = tmp_path / "d.toml"
    path.write_text(_toml({key: _toml_value(key, probe)}))
    if _allowed(key, probe):
        load_config(path)
        return
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert len(info.value.lines) == 1, info.value.lines
    assert key in info.value.lines[0] and str(path) in info.value.lines[0]


def _check(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "cmm_comp.cli", "daemon", "--check", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def _config_lines(stderr: str) -> list[str]:
    """``--check``'s stderr lines about the configuration's values: ``--check`` also checks the
    files it names, and these configurations name no grid, which is one more line."""
    lines = stderr.strip().splitlines()
    no_grid = [line for line in lines if "grid.path is empty" in line]
    assert len(no_grid) == 1, lines
    assert "correct nothing: every answer says no_grid" in no_grid[0]
    return [line for line in lines if line not in no_grid]


@pytest.mark.parametrize("probe", list(PROBES))
def test_check_lists_every_bad_key_once(tmp_path, probe: str) -> None:
    """The real CLI: every numeric key set to one bad probe value at once → exit 2 and exactly
    one stderr line per bad key (naming it), no traceback."""
    bad = {k: _toml_value(k, probe) for k in NUMERIC_KEYS if not _allowed(k, probe)}
    path = tmp_path / "d.toml"
    path.write_text(_toml(bad))
    proc = _check(["--config", str(path)])
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    lines = _config_lines(proc.stderr)
    assert len(lines) == len(bad), lines
    for key in bad:
        assert sum(f" {key}" in line for line in lines) == 1, (key, lines)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a = " + "[" * 3000 + "]" * 3000 + "\n", "nested too deeply"),
        ("[grid]\nstylus_mm = [0, 0\n", "not valid TOML"),
        ("[can]\nheartbeat = 0.1\n", "unknown key can.heartbeat; allowed: "),
        ("[modbus]\nport = 5020.5\n", "modbus.port: 5020.5 must be an integer"),
        ("can = 3\n", r"\[can\] must be a table"),
        ("\xff = 1\n", "not valid TOML"),
    ],
)
def test_malformed_toml_is_one_line(tmp_path, text: str, match: str) -> None:
    path = tmp_path / "d.toml"
    path.write_text(text, encoding="utf-8")
    proc = _check(["--config", str(path)])
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    # not TOML at all: one line, nothing else can be checked; otherwise the files are too
    toml_ok = "not valid TOML" not in match and "nested" not in match
    lines = _config_lines(proc.stderr) if toml_ok else proc.stderr.strip().splitlines()
    assert len(lines) == 1 and re.search(match, lines[0]), lines


def test_bad_flags_are_checked_like_the_file() -> None:
    proc = _check(["--can-heartbeat-s", "nan", "--modbus-port", "70000", "--can-node-id", "200"])
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = _config_lines(proc.stderr)
    assert len(lines) == 3, lines
    assert "can.heartbeat_s = nan" in lines[0] or any("can.heartbeat_s = nan" in x for x in lines)
    assert any("modbus.port = 70000; allowed: 0 .. 65535" in x for x in lines)
    assert any("can.node_id = 200" in x for x in lines)


def test_node_id_range_depends_on_base_id(tmp_path) -> None:
    """Ids base_id + 0x10·node_id … + 0xF must stay 11-bit (docs/can.md: nodes 0..95 at 0x200)."""
    path = tmp_path / "d.toml"
    path.write_text("[can]\nnode_id = 95\n")
    assert load_config(path).can.node_id == 95
    path.write_text("[can]\nnode_id = 96\n")
    with pytest.raises(ConfigError, match=r"can\.node_id = 96; allowed: 0 \.\. 95"):
        load_config(path)
    path.write_text("[can]\nbase_id = 0x205\n")
    with pytest.raises(ConfigError, match=r"can\.base_id = 0x205; allowed: a multiple of 0x10"):
        load_config(path)
