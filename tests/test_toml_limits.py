"""Every limit the hand-written checks enforced before issue 26 (listed here from that code, not
from the new definitions) holds with the definitions pydantic checks: the limit itself loads,
just beyond it is refused with one line naming the file and the key. Also: every problem of a
file at once, strict types, and one ``cmm-comp: error:`` line per problem at the CLI."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from cmm_comp.compensation.errors import MachineFileError
from cmm_comp.compensation.machine import Machine
from cmm_comp.daemon.config import ConfigError, config_from_dict

MINIMAL = """format = "cmm-machine/1"
name = "tiny"
model = "FB1"
[volume]
x = [0.0, 500.0]
y = [0.0, 400.0]
z = [0.0, 300.0]
"""

# ---------------------------------------------------------------------------------- daemon
# daemon/config_checks.py NUMERIC_RULES and daemon/live/settings.py LIVE_RULES as they were:
# key -> (lo, hi, lo_open). Lists (stylus, temperature pairs) apply the rule to each element.
OLD_DAEMON_RANGES: dict[str, tuple[float, float, bool]] = {
    "grid.stylus_mm": (-2000.0, 2000.0, False),
    "can.bitrate": (0, 20_000_000, False),
    "can.node_id": (0, 127, False),
    "can.base_id": (0, 0x7F0, False),
    "can.triplet_timeout_s": (0.0, 10.0, True),
    "can.window": (1, 1024, False),
    "can.send_timeout_s": (0.0, 10.0, True),
    "can.heartbeat_s": (0.0, 60.0, True),
    "can.reconnect_s": (0.0, 600.0, True),
    "modbus.port": (0, 65535, False),
    "modbus.device_id": (1, 247, False),
    "modbus.idle_timeout_s": (0.0, 86400.0, False),
    "modbus.frame_timeout_s": (0.0, 60.0, True),
    "temperatures.stale_s": (0.0, 86400.0, True),
    "temperatures.plausible_C": (-100.0, 300.0, False),
    "temperatures.valid_range_C": (-100.0, 300.0, False),
    "temperatures.max_rate_C_per_s": (0.0, 1e9, True),
    "limits.warn_um": (0.0, 1e6, True),
    "limits.error_um": (0.0, 1e6, True),
    "mcap.roll_mb": (0.0, 1e6, False),
    "mcap.roll_s": (0.0, 1e7, False),
    "mcap.flush_s": (0.0, 3600.0, True),
    "metrics.port": (0, 65535, False),
    "metrics.period_s": (0.0, 3600.0, True),
    "log.max_per_s": (0.0, 1e6, False),
    "log.state_repeat_s": (0.0, 86400.0, True),
    "live.port": (0, 65535, False),
    "live.queue": (1, 1_000_000, False),
    "live.update_rate_hz": (0.0, 1000.0, True),
    "live.max_per_update": (1, 100_000, False),
    "live.scene_rate_hz": (0.0, 1000.0, True),
    "live.scene_keep_arrows": (1, 100_000, False),
    "live.scene_max_new_arrows": (1, 10_000, False),
    "live.arrow_mm_per_um": (0.0, 1e6, True),
}


def _daemon(key: str, value: float) -> dict:
    section, name = key.split(".")
    data: dict = {section: {}}
    if key == "grid.stylus_mm":
        data[section][name] = [value, 0.0, 0.0]
    elif key.endswith("_C"):  # a [low, high] pair: the probed value is one end
        data[section][name] = [value, 299.0] if value < 299.0 else [-99.0, value]
    else:
        data[section][name] = value
    if key == "limits.warn_um":
        data[section]["error_um"] = 1e6
    if key == "limits.error_um":
        data[section]["warn_um"] = min(value, 50.0) if value > 0 else 50.0
    if key == "can.node_id":
        data[section]["base_id"] = 0
    if key == "can.base_id":
        data[section]["node_id"] = 0
    return data


def _beyond(lo: float, hi: float) -> tuple[float, float]:
    if isinstance(hi, int):
        return lo - 1, hi + 1
    return lo - abs(lo) * 1e-9 - 1e-9, hi * (1 + 1e-9)


@pytest.mark.parametrize("key", list(OLD_DAEMON_RANGES))
def test_daemon_ranges_as_before(key: str) -> None:
    lo, hi, lo_open = OLD_DAEMON_RANGES[key]
    if key == "can.base_id":
        hi = 0x7F0  # also a multiple of 0x10
    config_from_dict(_daemon(key, hi), "d.toml")
    if not lo_open:
        config_from_dict(_daemon(key, lo), "d.toml")
    below, above = _beyond(lo, hi)
    for bad in (above, lo if lo_open else below, math.nan, math.inf):
        with pytest.raises(ConfigError) as info:
            config_from_dict(_daemon(key, bad), "d.toml")
        assert len(info.value.lines) == 1, info.value.lines
        assert info.value.lines[0].startswith(f"d.toml: {key}"), info.value.lines


def test_daemon_rules_between_keys_as_before() -> None:
    for data, line in (
        (
            {"temperatures": {"plausible_C": [40.0, 35.0]}},
            "d.toml: temperatures.plausible_C = [40.0, 35.0] must be [low, high]",
        ),
        (
            {"limits": {"warn_um": 10.0, "error_um": 5.0}},
            "d.toml: limits need 0 < warn_um <= error_um, got 10.0 and 5.0",
        ),
        (
            {"can": {"base_id": 0x700, "node_id": 16}},
            "d.toml: can.node_id = 16; allowed: 0 .. 15 for base_id 0x700 (ids must stay 11-bit)",
        ),
        ({"can": {"base_id": 0x208}}, "d.toml: can.base_id = 0x208; allowed: a multiple of 0x10"),
        (
            {"temperatures": {"sensors": {"256": "T_x"}}},
            "d.toml: temperatures.sensors key '256' must be 0..255",
        ),
        (
            {"temperatures": {"required": ["T_q"]}},
            "d.toml: temperatures.required has unknown role 'T_q'",
        ),
        (
            {"can": {"enabled": False}},
            "d.toml: enable at least one of can.enabled, modbus.enabled",
        ),
        (
            {"mcap": {"compression": "gzip"}},
            "d.toml: mcap.compression = 'gzip'; allowed: zstd, lz4, none",
        ),
    ):
        with pytest.raises(ConfigError) as info:
            config_from_dict(data, "d.toml")
        assert info.value.lines == [line]


def test_daemon_types_are_strict() -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict(
            {
                "can": {"fd": 1, "bitrate": 500000.0, "heartbeat_s": "0.1", "channel": 0},
                "temperatures": {"required": ["T_x", 3]},
            },
            "d.toml",
        )
    assert info.value.lines == [
        "d.toml: can.channel: 0 must be a string",
        "d.toml: can.bitrate: 500000.0 must be an integer",
        "d.toml: can.fd: 1 must be true or false",
        "d.toml: can.heartbeat_s: '0.1' must be a number",
        "d.toml: temperatures.required[1]: 3 must be a string",
    ]


# ---------------------------------------------------------------------------------- machine
# compensation/formats/machine_parser.py, uncertainty/model.py and machine.py as they were:
# (fragment at the limit, the same beyond it, the key path named).
OLD_MACHINE_LIMITS = [
    ("[volume]\nx = [-1e6, 1e6]", "[volume]\nx = [-1e6, 1.000001e6]", "volume.x[1]"),
    ("[volume]\nx = [0.0, 1e-3]", "[volume]\nx = [0.0, 0.0]", "volume.x"),
    ("[volume]\nsteps = [2, 1000, 5]", "[volume]\nsteps = [2, 1001, 5]", "volume.steps[1]"),
    ("[volume]\nsteps = [2, 2, 2]", "[volume]\nsteps = [1, 2, 2]", "volume.steps[0]"),
    ("[volume]\nsteps = [2, 2, 2]", "[volume]\nsteps = [2, 2]", "volume.steps"),
    (
        "[volume]\nreference = [0.0, 0.0, 0.0]",
        "[volume]\nreference = [0.0, nan, 0.0]",
        "volume.reference[1]",
    ),
    (
        "[probe]\noffset = [0.0, 0.0, -1e6]",
        "[probe]\noffset = [0.0, 0.0, -1.000001e6]",
        "probe.offset[2]",
    ),
    ("[probe]\nrandom_um = 1e9", "[probe]\nrandom_um = 1.000001e9", "probe.random_um"),
    ("[probe]\nrandom_um = 0.0", "[probe]\nrandom_um = -0.1", "probe.random_um"),
    ("[thermal]\nreference_C = -273.15", "[thermal]\nreference_C = -273.16", "thermal.reference_C"),
    ("[thermal]\nreference_C = 1000.0", "[thermal]\nreference_C = 1000.001", "thermal.reference_C"),
    (
        "[thermal]\nexpansion = { y = -1e6 }",
        "[thermal]\nexpansion = { y = -1.000001e6 }",
        "thermal.expansion.y",
    ),
    (
        "[thermal]\nworkpiece_expansion = 1e6",
        "[thermal]\nworkpiece_expansion = 1.000001e6",
        "thermal.workpiece_expansion",
    ),
    (
        "[thermal]\nworkpiece_fixture = [1e6, 0, 0]",
        "[thermal]\nworkpiece_fixture = [1.000001e6, 0, 0]",
        "thermal.workpiece_fixture[0]",
    ),
    ("[squareness]\nalpha = 1e6", "[squareness]\nalpha = 1.000001e6", "squareness"),
    (
        "[squareness]\nrandom = { beta1 = 1e6 }",
        "[squareness]\nrandom = { beta1 = 1.000001e6 }",
        "squareness random",
    ),
    ("[squareness]\nbeta2 = 0.0", "[squareness]\nbeta2 = inf", "squareness.beta2"),
    # a table's values within the volume: ±1e9 µm (linear), ±1e6 µrad (angular)
    (
        "[errors.dx_x]\nposition = [0.0, 500.0]\nvalue = [0.0, 1e9]",
        "[errors.dx_x]\nposition = [0.0, 500.0]\nvalue = [0.0, 1.000001e9]",
        "errors.dx_x",
    ),
    (
        "[errors.ez_x]\npolynomial = [1e6]",
        "[errors.ez_x]\npolynomial = [1.000001e6]",
        "errors.ez_x",
    ),
    (
        "[errors.dy_x]\npolynomial = [0.0]\nrandom_band = 1e9",
        "[errors.dy_x]\npolynomial = [0.0]\nrandom_band = 1.000001e9",
        "errors.dy_x",
    ),
    (
        "[errors.dy_x]\npolynomial = [0.0]\nrandom_band = 0.0",
        "[errors.dy_x]\npolynomial = [0.0]\nrandom_band = -0.1",
        "errors.dy_x.random_band",
    ),
    (
        "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [0.0, 1.0]\nrandom = [0.0, 0.0]",
        "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [0.0, 1.0]\nrandom = [0.0, -0.1]",
        "errors.dx_x.random[1]",
    ),
    (
        "[errors.dx_x]\npolynomial = [" + ", ".join(["0.0"] * 11) + "]",
        "[errors.dx_x]\npolynomial = [" + ", ".join(["0.0"] * 12) + "]",
        "errors.dx_x.polynomial",
    ),
    (
        "[errors.dx_x]\npolynomial = [0.0]",
        "[errors.dx_x]\npolynomial = []",
        "errors.dx_x.polynomial",
    ),
    (
        "[errors.dx_x]\ncurve = { position = [0.0, 1.0, 2.0], value = [0.0, 1.0, 0.0], order = 2 }",
        "[errors.dx_x]\ncurve = { position = [0.0, 1.0, 2.0], value = [0.0, 1.0, 0.0], order = 3 }",
        "errors.dx_x.curve",
    ),
    (
        "[errors.dx_x]\ncurve = { position = [0.0, 1.0, 2.0], value = [0.0, 1.0, 0.0], order = 2 }",
        "[errors.dx_x]\ncurve = { position = [0.0, 1.0, 2.0], value = [0.0, 1.0, 0.0], order = 2.0 }",
        "errors.dx_x.curve.order",
    ),
    (
        "[errors.dx_x]\nposition = [0.0, 1.0]\nvalue = [0.0, 0.0]",
        "[errors.dx_x]\nposition = [1.0, 1.0]\nvalue = [0.0, 0.0]",
        "errors.dx_x.position",
    ),
    # [uncertainty]: every value 0 … 1e9, correlation_mm > 0
    (
        "[uncertainty]\nprobe_um = 1e9",
        "[uncertainty]\nprobe_um = 1.000001e9",
        "uncertainty.probe_um",
    ),
    ("[uncertainty]\nprobe_um = 0.0", "[uncertainty]\nprobe_um = -0.1", "uncertainty.probe_um"),
    (
        "[uncertainty]\nsquareness = 1e9",
        "[uncertainty]\nsquareness = 1.000001e9",
        "uncertainty.squareness",
    ),
    (
        "[uncertainty]\nexpansion = { z = 1e9 }",
        "[uncertainty]\nexpansion = { z = -1.0 }",
        "uncertainty.expansion.z",
    ),
    (
        "[uncertainty]\nworkpiece_temperature_C = 0.0",
        "[uncertainty]\nworkpiece_temperature_C = nan",
        "uncertainty.workpiece_temperature_C",
    ),
    (
        "[uncertainty.errors.dx_x]\ncorrelation_mm = 1e-9",
        "[uncertainty.errors.dx_x]\ncorrelation_mm = 0.0",
        "uncertainty.errors.dx_x.correlation_mm",
    ),
    (
        "[uncertainty.angular]\nu_relative = 1e9",
        "[uncertainty.angular]\nu_relative = 2e9",
        "uncertainty.angular.u_relative",
    ),
]


def _machine(tmp_path: Path, fragment: str) -> Path:
    text = MINIMAL
    header = fragment.split("\n", 1)[0]
    if header == "[volume]":  # replace a key of the minimal [volume]
        key = fragment.split("\n")[1].split(" =")[0]
        lines = [ln for ln in text.splitlines() if not ln.startswith(f"{key} =")]
        text = "\n".join(lines) + "\n" + fragment.split("\n", 1)[1] + "\n"
    else:
        text += fragment + "\n"
    path = tmp_path / "m.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    ("ok", "bad", "where"), OLD_MACHINE_LIMITS, ids=[w for *_, w in OLD_MACHINE_LIMITS]
)
def test_machine_limits_as_before(tmp_path: Path, ok: str, bad: str, where: str) -> None:
    Machine.from_toml(_machine(tmp_path, ok))
    path = _machine(tmp_path, bad)
    with pytest.raises(MachineFileError) as info:
        Machine.from_toml(path)
    assert len(info.value.lines) == 1, info.value.lines
    line = info.value.lines[0]
    assert line.startswith(f"{path}: {where}") or f"{path}: unknown" in line, line
    assert where in line, line


def test_a_table_of_more_values_than_allowed_is_refused(tmp_path: Path) -> None:
    n = 100_001
    values = ", ".join(["0.0"] * n)
    path = _machine(tmp_path, f"[errors.dx_y]\nposition = [{values}]\nvalue = [{values}]")
    with pytest.raises(MachineFileError) as info:
        Machine.from_toml(path)
    assert len(info.value.lines) == 2  # position and value, each named once and shortened
    assert all("allowed: at most 100000 values" in x and len(x) < 300 for x in info.value.lines)


def test_every_problem_of_a_machine_file_at_once(tmp_path: Path) -> None:
    """Six unrelated problems planted in one file: six lines, each naming its key."""
    # a top-level scalar (colour) is kept, not a problem
    text = (
        "colour = 'red'\n"
        + MINIMAL.replace("x = [0.0, 500.0]", "x = [500.0, 0.0]")
        + (
            "[probe]\nrandom_um = -1.0\n"
            "[thermal]\nexpansion = { x = 'ten' }\n"
            "[errors.dq_x]\npolynomial = [0.0]\n"
            "[errors.dx_x]\npostion = [0.0]\nvalue = [1.0]\n"
            "[uncertainty]\nprobe_um = 1e300\n"
        )
    )
    path = tmp_path / "m.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(MachineFileError) as info:
        Machine.from_toml(path)
    keys = [
        "volume.x",
        "probe.random_um",
        "thermal.expansion.x",
        "errors.dq_x",
        "errors.dx_x.postion",
        "uncertainty.probe_um",
    ]
    assert len(info.value.lines) == len(keys), info.value.lines
    for key in keys:
        assert sum(key in line for line in info.value.lines) >= 1, (key, info.value.lines)
    assert all(line.startswith(f"{path}: ") for line in info.value.lines)


def test_cli_prints_one_error_line_per_problem_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cmm_comp.cli.main import main

    path = tmp_path / "m.toml"
    path.write_text(
        MINIMAL + "[probe]\nrandom_um = -1.0\n[thermal]\nreference_C = 2000.0\n", encoding="utf-8"
    )
    out = tmp_path / "map.csv"
    assert main(["map", str(path), "--out", str(out), "--steps", "3", "3", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"cmm-comp: error: {path}: probe.random_um = -1.0; allowed: 0 .. 1e+09 µm",
        f"cmm-comp: error: {path}: thermal.reference_C = 2000.0; allowed: -273.15 .. 1000 °C",
    ]
    assert not out.exists()


def test_daemon_check_lists_each_problem_of_the_bound_machine(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from cmm_comp.cli.main import main

    machine = tmp_path / "m.toml"
    machine.write_text(
        MINIMAL + "[probe]\nrandom_um = -1.0\n[arm_deflection]\nphi1 = nan\n", "utf-8"
    )
    config = tmp_path / "d.toml"
    grid = tmp_path / "none.grid"
    config.write_text(
        f'[grid]\npath = "{grid}"\nmachine = "{machine}"\nallow_unsigned = true\n', "utf-8"
    )
    assert main(["daemon", "--check", "--config", str(config), "--can-interface", "virtual"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    bound = [line for line in err if "grid.machine:" in line]
    assert bound == [
        f"cmm-comp: {config}: grid.machine: {machine}: probe.random_um = -1.0; allowed: 0 .. 1e+09 µm",
        f"cmm-comp: {config}: grid.machine: {machine}: arm_deflection.phi1 = nan; allowed: a finite number µrad/m",
    ], err
