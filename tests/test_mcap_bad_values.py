"""Every kind of bad value in every record type the daemon logs, through both writers: the file
stays readable by the official ``mcap`` reader (summary, index, strict JSON), each bad message
becomes one ``/cmm/log_error`` record and is counted, and every good message logged after it is
in the file. Oracle: the ``mcap`` package's seeking reader and ``json.loads`` with NaN/Infinity
refused, against the list of what the test sent."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from test_mcap_log import T0_NS, sample

from cmm_comp.daemon.sessionlog.process_writer import McapProcessLogger
from cmm_comp.daemon.sessionlog.writer import SessionWriter
from cmm_comp.protocol.session_topics import TOPIC_SCHEMAS, check_message


class Opaque:
    """An arbitrary object (not JSON)."""


def _deep(levels: int) -> list[Any]:
    out: list[Any] = []
    for _ in range(levels):
        out = [out]
    return out


BAD_VALUES: dict[str, Any] = {
    "nan": float("nan"),
    "inf": float("inf"),
    "-inf": float("-inf"),
    "huge_int": 10**30,
    "huge_negative_int": -(10**30),
    "non_str_key": {1: 2.0},
    "tuple_key": {(1, 2): 3},
    "bytes": b"\x00\xff",
    "object": Opaque(),
    "set": {1, 2},
    "none": None,
    "nested_nan": {"a": [1.0, {"b": float("nan")}]},
    "deep": _deep(200),
    "too_deep_to_pickle": _deep(5000),
}
"""Name → value; each one is put into a declared field of every topic (``None`` is bad there:
the schema wants a number, string, ...)."""

FIELD_OF_TOPIC = {
    "/cmm/raw": "x_mm",
    "/cmm/temperature": "temp_C",
    "/cmm/corrected": "latency_us",
    "/cmm/status": "detail",
    "/cmm/can_rx": "arbitration_id",
    "/cmm/can_tx": "dlc",
    "/cmm/modbus": "values",
    "/cmm/grid": "steps",
    "/cmm/counters": "counters",
    "/cmm/log_error": "error",
}

# compact record tuples (records.py layouts) and the positions where None is allowed by design
FRAME = (0x181, False, 8, bytes(range(8)), 1_700_000_000.25, "vcan0", False, False, False)
RAW = (7, 1.0, 2.0, 3.0, (1, -1, 0), (True, True, True), "can", (0.0, 0.0, -120.0), None)
CORRECTED = (7, 1_000_001, 2_000_000, 3_000_000, "ok", (0.1, 0.2, 0.3), 55.0, 3, "can", "")
RECORDS: dict[str, tuple[tuple[Any, ...], set[int], set[int]]] = {
    # topic: (record, positions where None is allowed, where NaN is allowed ("unknown" stamp))
    "/cmm/can_rx": (FRAME, {4}, {4}),
    "/cmm/can_tx": (FRAME, {4}, {4}),
    "/cmm/raw": (RAW, {8}, set()),
    "/cmm/corrected": (CORRECTED, {9}, set()),
}


def _strict_json(data: bytes) -> Any:
    def refuse(token: str) -> None:
        raise ValueError(f"non-JSON constant {token}")

    return json.loads(data, parse_constant=refuse)


def _cases() -> list[tuple[str, Any, str]]:
    """(topic, payload, label): a bad message, each followed by a good one in the test."""
    out: list[tuple[str, Any, str]] = []
    for topic in TOPIC_SCHEMAS:
        for name, bad in BAD_VALUES.items():
            out.append((topic, {**sample(topic, 1), FIELD_OF_TOPIC[topic]: bad}, f"{name}"))
            if name != "none":  # an undeclared key may be null, nothing else bad
                out.append((topic, {**sample(topic, 1), "extra": bad}, f"extra {name}"))
        out.append((topic, {**sample(topic, 1), 5: "int key"}, "int key at top"))
    for topic, (rec, none_ok, nan_ok) in RECORDS.items():
        for pos in range(len(rec)):
            for name, bad in BAD_VALUES.items():
                if (name == "none" and pos in none_ok) or (name == "nan" and pos in nan_ok):
                    continue
                if name == "bytes" and isinstance(rec[pos], bytes):
                    continue  # bytes where bytes belong
                bad_rec = (*rec[:pos], bad, *rec[pos + 1 :])
                out.append((topic, bad_rec, f"record[{pos}] {name}"))
        out.append((topic, rec[:-1], "record too short"))
        out.append((topic, (*rec, 1), "record too long"))
    out.append(("/cmm/raw", sample("/cmm/raw", 1), "log_time_ns float"))  # bad time, see below
    return out


@pytest.mark.parametrize("cls", [SessionWriter, McapProcessLogger])
def test_every_bad_value_in_every_record_type_is_an_error_record(
    tmp_path: Path, cls: type[SessionWriter] | type[McapProcessLogger]
) -> None:
    path = tmp_path / "bad.mcap"
    cases = _cases()
    good: list[tuple[str, int]] = []
    warnings: list[BaseException] = []
    with cls(path, chunk_size=4096, on_error=warnings.append) as lg:
        for i, (topic, payload, label) in enumerate(cases):
            t_ns = T0_NS + 2 * i
            bad_t: Any = float(t_ns) if label == "log_time_ns float" else t_ns
            assert lg.log(topic, payload, bad_t), label
            good_topic = topic if topic != "/cmm/log_error" else "/cmm/status"
            assert lg.log(good_topic, sample(good_topic, i), t_ns + 1)  # right after it
            good.append((good_topic, t_ns + 1))
    st = lg.stats()
    assert lg.error is None  # bad messages never make the log fail
    assert st.encode_errors == len(cases), st.encode_errors_by_topic
    assert st.written == len(good) and st.dropped == len(cases)
    assert sum(st.encode_errors_by_topic.values()) == len(cases)
    assert warnings and all("not JSON-encodable" in str(w) for w in warnings)

    with open(path, "rb") as f:  # the official reader: summary, index, every message
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(good) + len(cases)
        got = [
            (c.topic, m.log_time, _strict_json(m.data))
            for _, c, m in reader.iter_messages(log_time_order=False)
        ]
    errors = [p for topic, _, p in got if topic == "/cmm/log_error"]
    assert [(e["topic"]) for e in errors] == [c[0] for c in cases]
    assert all(e["error"] and e["payload"] for e in errors)
    assert [(topic, t) for topic, t, _ in got if topic != "/cmm/log_error"] == good
    for topic, _, payload in got:
        check_message(topic, payload)
    with open(path, "rb") as f:
        f_meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert int(f_meta["session_end"]["encode_errors"]) == len(cases)
    by_topic = json.loads(f_meta["session_end"]["encode_errors_by_topic"])
    expected: dict[str, int] = {}
    for topic, _, _ in cases:
        expected[topic] = expected.get(topic, 0) + 1
    assert by_topic == expected
