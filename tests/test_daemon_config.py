"""Daemon configuration: the example file loads, flags override every key, errors name the key."""

from __future__ import annotations

import argparse

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
    assert cfg.can.interface == "socketcan" and cfg.grid.stylus_mm == [0.0, 0.0, -120.0]
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
