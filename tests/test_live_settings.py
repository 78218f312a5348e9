"""The ``[live]`` configuration section: defaults, one clear line per bad value (NaN, inf,
out of range, wrong type, unknown key), every problem listed, and the loopback-only host policy."""

from __future__ import annotations

import math
import tomllib

import pytest

from cmm_comp.daemon.live import (
    LiveConfigError,
    LiveSection,
    LiveSink,
    LiveStartError,
    live_section_from_table,
)


def test_defaults_are_off_and_loopback() -> None:
    s = live_section_from_table(None)
    assert s == LiveSection()
    assert (s.enabled, s.host, s.port, s.queue, s.update_rate_hz, s.scene_rate_hz) == (
        False,
        "127.0.0.1",
        8765,
        4096,
        10.0,
        10.0,
    )
    assert list(s.rules({})) == []


def test_a_table_from_toml() -> None:
    table = tomllib.loads(
        """
        [live]
        enabled = true
        port = 0
        scene_rate_hz = 5
        queue = 100
        arrow_mm_per_um = 2
        """
    )["live"]
    s = live_section_from_table(table, "d.toml")
    assert s.enabled and s.port == 0 and s.queue == 100
    assert s.scene_rate_hz == 5.0 and isinstance(s.scene_rate_hz, float)
    assert s.arrow_mm_per_um == 2.0


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("scene_rate_hz", math.nan, r"live\.scene_rate_hz = nan; allowed: > 0 and <= 1000 Hz"),
        ("scene_rate_hz", math.inf, r"live\.scene_rate_hz = inf"),
        ("scene_rate_hz", 0.0, r"live\.scene_rate_hz = 0\.0"),
        ("arrow_mm_per_um", -1.0, r"live\.arrow_mm_per_um = -1\.0; allowed: > 0"),
        ("arrow_mm_per_um", -math.inf, r"live\.arrow_mm_per_um = -inf"),
        ("port", 70000, r"live\.port = 70000; allowed: 0 \.\. 65535"),
        ("port", -1, r"live\.port = -1"),
        ("queue", 0, r"live\.queue = 0; allowed: 1 \.\. 1000000 messages"),
        ("scene_keep_arrows", 10**9, r"live\.scene_keep_arrows = 1000000000"),
        ("scene_max_new_arrows", 0, r"live\.scene_max_new_arrows = 0"),
        ("port", "8765", r"live\.port: '8765' must be an integer"),
        ("port", 8765.0, r"live\.port: 8765\.0 must be an integer"),
        ("enabled", 1, r"live\.enabled: 1 must be true or false"),
        ("scene_rate_hz", True, r"live\.scene_rate_hz: True must be a number"),
        ("scene_rate_hz", 10**400, r"live\.scene_rate_hz: .* is too large"),
        ("host", 127, r"live\.host: 127 must be a string"),
        ("sender", "fork", r"live\.sender = 'fork'; allowed: process, thread"),
        ("colour", "red", r"unknown key live\.colour; allowed: allow_remote, arrow_mm_per_um"),
    ],
)
def test_each_bad_value_is_one_line_naming_key_and_rule(
    key: str, value: object, match: str
) -> None:
    with pytest.raises(LiveConfigError, match=match) as err:
        live_section_from_table({key: value}, "d.toml")
    assert len(err.value.lines) == 1
    assert err.value.lines[0].startswith("d.toml: ")


def test_every_problem_is_listed() -> None:
    with pytest.raises(LiveConfigError) as err:
        live_section_from_table(
            {"port": 1e9, "queue": -5, "scene_rate_hz": math.nan, "host": "10.0.0.5", "x": 1}
        )
    text = "\n".join(err.value.lines)
    assert len(err.value.lines) == 5, text
    for key in ("live.port", "live.queue", "live.scene_rate_hz", "live.host", "live.x"):
        assert key in text


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.20", "::", "2001:db8::1"])
def test_a_remote_host_needs_allow_remote(host: str) -> None:
    with pytest.raises(LiveConfigError, match=r"not a loopback address.*allow_remote = true"):
        live_section_from_table({"host": host})
    s = live_section_from_table({"host": host, "allow_remote": True})
    assert s.host == host


@pytest.mark.parametrize("host", ["127.0.0.1", "127.1.2.3", "::1", "localhost"])
def test_loopback_hosts_are_accepted(host: str) -> None:
    assert live_section_from_table({"host": host}).host == host


@pytest.mark.parametrize("host", ["", "example.com", "127.0.0.1:8765", "ws://127.0.0.1"])
def test_a_host_must_be_an_address(host: str) -> None:
    with pytest.raises(LiveConfigError, match="is not an IP address"):
        live_section_from_table({"host": host})


def test_the_sink_refuses_a_remote_host_it_was_not_allowed() -> None:
    """A section built in code (not through the checks) is checked again by the sink."""
    with pytest.raises(LiveStartError, match="not a loopback address"):
        LiveSink(LiveSection(enabled=True, host="0.0.0.0"))


def test_a_section_built_in_code_is_checked_with_the_configuration() -> None:
    """A section made in code (not read from a file) gets the same lines from ``check()``."""
    from cmm_comp.daemon.config import DaemonConfig

    cfg = DaemonConfig(source="w", live=LiveSection(port=-1, scene_rate_hz=math.nan))
    assert cfg.problems() == [
        "w: live.port = -1; allowed: 0 .. 65535",
        "w: live.scene_rate_hz = nan; allowed: > 0 and <= 1000 Hz",
    ]
