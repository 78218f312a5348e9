"""Time conversions and the topic schemas of the MCAP session log (docs/formats.md §6)."""

from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from cmm_comp.protocol.session_topics import (
    NS_PER_S,
    TOPIC_SCHEMAS,
    check_message,
    ns_from_can_timestamp,
    ns_from_stamp,
    stamp_from_ns,
)

SPEC_TOPICS = {
    "/cmm/raw": ["seq", "x_mm", "y_mm", "z_mm", "stamp"],
    "/cmm/temperature": ["sensor", "role", "temp_C", "stamp"],
    "/cmm/corrected": ["seq", "x_mm", "y_mm", "z_mm", "status", "stamp"],
    "/cmm/status": ["state", "detail", "grid_sha256", "stamp"],
}


@given(st.integers(min_value=-(2**63), max_value=2**63 - 1))
def test_stamp_round_trip_is_exact(ns: int) -> None:
    stamp = stamp_from_ns(ns)
    assert set(stamp) == {"sec", "nsec"}
    assert 0 <= stamp["nsec"] < NS_PER_S
    assert ns_from_stamp(stamp) == ns
    assert ns_from_stamp(json.loads(json.dumps(stamp))) == ns  # survives JSON too


@given(st.integers(min_value=0, max_value=4_000_000_000 * 1_000_000))
def test_can_timestamp_within_one_ulp(us: int) -> None:
    t_s = us / 1e6  # python-can float seconds at microsecond resolution
    assert abs(ns_from_can_timestamp(t_s) - us * 1000) <= 480  # one ulp near 4e9 s is 477 ns


@given(st.integers(min_value=0, max_value=2**40))
def test_can_timestamp_whole_seconds_exact(sec: int) -> None:
    assert ns_from_can_timestamp(float(sec)) == sec * NS_PER_S


def test_can_timestamp_rejects_nan() -> None:
    with pytest.raises(ValueError, match="not finite"):
        ns_from_can_timestamp(float("nan"))


def test_spec_topics_and_fields_present() -> None:
    for topic, fields in SPEC_TOPICS.items():
        schema = TOPIC_SCHEMAS[topic].schema
        assert set(fields) <= set(schema["required"]), topic
    assert {"/cmm/can_rx", "/cmm/can_tx", "/cmm/modbus", "/cmm/grid", "/cmm/counters"} <= set(
        TOPIC_SCHEMAS
    )


def _walk(node: object) -> list[dict]:
    out = []
    if isinstance(node, dict):
        out.append(node)
        for v in node.values():
            out.extend(_walk(v))
    elif isinstance(node, list):
        for v in node:
            out.extend(_walk(v))
    return out


def test_schemas_are_json_and_times_are_sec_nsec() -> None:
    for topic, sch in TOPIC_SCHEMAS.items():
        assert json.loads(sch.as_bytes()) == sch.schema
        assert sch.schema["$schema"].startswith("https://json-schema.org/")
        for key in sch.schema["required"]:
            assert key in sch.schema["properties"], (topic, key)
        stamp = sch.schema["properties"]["stamp"]
        assert stamp["type"] == "object" and stamp["required"] == ["sec", "nsec"]
        for node in _walk(sch.schema):  # every object lists its required keys as properties
            if node.get("type") == "object" and "required" in node:
                assert set(node["required"]) <= set(node["properties"])


def test_check_message_names_the_problem() -> None:
    good = {"seq": 1, "x_mm": 1.0, "y_mm": 2, "z_mm": 3.0, "stamp": stamp_from_ns(5)}
    assert check_message("/cmm/raw", good) is good
    with pytest.raises(ValueError, match=r"/cmm/raw: required key 'z_mm' is missing"):
        check_message("/cmm/raw", {k: v for k, v in good.items() if k != "z_mm"})
    with pytest.raises(ValueError, match=r"/cmm/raw\.stamp\.nsec: .* above the maximum"):
        check_message("/cmm/raw", {**good, "stamp": {"sec": 0, "nsec": NS_PER_S}})
    with pytest.raises(ValueError, match=r"/cmm/raw\.seq: True is not of type integer"):
        check_message("/cmm/raw", {**good, "seq": True})
    with pytest.raises(ValueError, match="unknown topic '/nope'"):
        check_message("/nope", good)
