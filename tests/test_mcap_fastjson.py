"""The writer's fast path gives exactly the bytes of the general path, or steps aside.

Oracle: the general path (record builder → dict → ``json``, :func:`encoding.encode_message`)
for the message bytes (whole files: ``tests/test_mcap_file.py`` against the ``mcap`` library's
own writer).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.daemon.sessionlog.encoding import encode_message, json_encoder
from cmm_comp.daemon.sessionlog.fastjson import FAST_JSON

DUMPS = json_encoder()
T_NS = st.integers(0, 2**64 - 1)
ANY_FLOAT = st.floats(allow_nan=True, allow_infinity=True)
FLOATS = st.floats(allow_nan=False, allow_infinity=False)
TEXT = st.text(max_size=20)
ODD = st.one_of(  # values a record field must not silently take
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    ANY_FLOAT,
    TEXT,
    st.binary(max_size=3),
    st.just(np.float64(1.5)),
    st.just(np.int64(3)),
    st.just(np.bool_(True)),
    st.tuples(FLOATS, FLOATS),
)


def general(topic: str, rec: tuple, t_ns: int) -> bytes | None:
    """The general path's bytes, or None where it refuses the record (an error record)."""
    try:
        return encode_message(topic, rec, t_ns, DUMPS)
    except Exception:
        return None


def agree(topic: str, rec: tuple, t_ns: int) -> bytes | None:
    fast = FAST_JSON[topic](rec, t_ns)
    slow = general(topic, rec, t_ns)
    if fast is not None:
        assert fast == slow, (rec, fast, slow)
        json.loads(fast)  # and it is JSON
    return fast


FRAME_FIELDS = (
    st.integers(0, 2**29 - 1),
    st.booleans(),
    st.integers(0, 64),
    st.binary(max_size=64),
    st.one_of(st.floats(1e-3, 1.8e10, exclude_max=True), st.just(1.7e9 + 0.123456)),
    st.one_of(st.sampled_from(["vcan0", "test", 'q"uo\\te', "é"]), TEXT),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)
frames = st.one_of(  # with the direction field (what the daemon logs) and without (before it)
    st.tuples(*FRAME_FIELDS, st.sampled_from(["rx", "tx", "tx_echo"])), st.tuples(*FRAME_FIELDS)
)
raws = st.tuples(
    st.integers(0, 2**64 - 1),
    FLOATS,
    FLOATS,
    FLOATS,
    st.tuples(*[st.integers(-1, 1)] * 3),
    st.tuples(*[st.booleans()] * 3),
    st.sampled_from(["can", "modbus"]),
    st.tuples(FLOATS, FLOATS, FLOATS),
    st.one_of(st.none(), st.tuples(FLOATS, FLOATS, FLOATS)),
)
CORRECTED_FIELDS = (
    st.integers(0, 2**64 - 1),
    st.integers(-(2**63), 2**64 - 1),
    st.integers(-(2**63), 2**64 - 1),
    st.integers(-(2**63), 2**64 - 1),
    st.sampled_from(["ok", "outside_volume", 'bad "quote"']),
    st.tuples(FLOATS, FLOATS, FLOATS),
    st.floats(0, 1e7),
    st.integers(0, 255),
    st.sampled_from(["can", "modbus"]),
    st.one_of(st.just(""), TEXT),
)
correcteds = st.tuples(*CORRECTED_FIELDS)
U_UM = st.floats(0.0, 1e6)  # the expanded uncertainty (µm, k = 2): finite, ≥ 0
correcteds_u = st.tuples(  # an answer made with a grid carrying U: U values or None (unknown)
    *CORRECTED_FIELDS,
    st.one_of(st.none(), st.tuples(U_UM, U_UM, U_UM), st.just((0.0, -0.0, 5e-324))),
)


@settings(max_examples=300, deadline=None)
@given(frames, T_NS)
def test_frames_equal_the_general_path(rec: tuple, t_ns: int) -> None:
    for topic in ("/cmm/can_rx", "/cmm/can_tx"):
        assert agree(topic, rec, t_ns) is not None


@settings(max_examples=300, deadline=None)
@given(raws, T_NS)
def test_raw_equal_the_general_path(rec: tuple, t_ns: int) -> None:
    assert agree("/cmm/raw", rec, t_ns) is not None


@settings(max_examples=300, deadline=None)
@given(correcteds, T_NS)
def test_corrected_equal_the_general_path(rec: tuple, t_ns: int) -> None:
    assert agree("/cmm/corrected", rec, t_ns) is not None


@settings(max_examples=300, deadline=None)
@given(correcteds_u, T_NS)
def test_corrected_with_uncertainty_equal_the_general_path(rec: tuple, t_ns: int) -> None:
    fast = agree("/cmm/corrected", rec, t_ns)
    assert fast is not None
    obj = json.loads(fast)
    u = rec[10]
    assert [obj["ux_um"], obj["uy_um"], obj["uz_um"]] == ([None] * 3 if u is None else list(u))


@pytest.mark.parametrize(
    "u",
    [
        (math.nan, 1.0, 1.0),
        (1.0, math.inf, 1.0),
        (1.0, 1.0, -1e-9),
        (1, 2.0, 3.0),  # an int: the general path writes 1.0, the fast path steps aside
        (1.0, 2.0),
        (None, None, None),  # unknown is None for the whole U, not per component
        np.array([1.0, 2.0, 3.0]),
    ],
)
def test_bad_uncertainty_never_takes_the_fast_path(u: object) -> None:
    rec = (1, 0, 0, 0, "ok", (0.0,) * 3, 1.0, 33, "can", "", u)
    assert FAST_JSON["/cmm/corrected"](rec, 5) is None
    slow = general("/cmm/corrected", rec, 5)
    if slow is not None:  # only the int is writable (as a float), never NaN/inf/negative
        assert json.loads(slow)["ux_um"] == 1.0


@settings(max_examples=400, deadline=None)
@given(st.data(), T_NS)
def test_any_odd_field_is_equal_or_left_to_the_general_path(data: st.DataObject, t_ns: int) -> None:
    topic, strat = data.draw(
        st.sampled_from(
            [
                ("/cmm/can_rx", frames),
                ("/cmm/raw", raws),
                ("/cmm/corrected", correcteds),
                ("/cmm/corrected", correcteds_u),
            ]
        )
    )
    rec = list(data.draw(strat))
    k = data.draw(st.integers(0, len(rec) - 1))
    rec[k] = data.draw(ODD)
    agree(topic, tuple(rec), t_ns)


@pytest.mark.parametrize(
    ("topic", "rec"),
    [
        ("/cmm/raw", (1, math.nan, 0.0, 0.0, (0, 0, 0), (True,) * 3, "can", (0.0,) * 3, None)),
        ("/cmm/raw", (1, 1, 0.0, 0.0, (0, 0, 0), (True,) * 3, "can", (0.0,) * 3, None)),
        ("/cmm/raw", (True, 1.0, 0.0, 0.0, (0, 0, 0), (True,) * 3, "can", (0.0,) * 3, None)),
        ("/cmm/raw", (1, 1.0, 0.0, 0.0, (0, 0, 2), (True,) * 3, "can", (0.0,) * 3, None)),
        ("/cmm/raw", (1, 1.0, 0.0, 0.0, (0, 0, 0), (1, 1, 1), "can", (0.0,) * 3, None)),
        ("/cmm/corrected", (1, 0, 0, 2**64, "ok", (0.0,) * 3, 1.0, 1, "can", "")),
        ("/cmm/corrected", (1, 0, 0, 0, "ok", (0.0,) * 3, math.inf, 1, "can", "")),
        ("/cmm/corrected", (-1, 0, 0, 0, "ok", (0.0,) * 3, 1.0, 1, "can", "")),
        ("/cmm/can_rx", (0x200, False, 8, b"\0" * 8, math.nan, "c", False, False, False)),
        ("/cmm/can_rx", (2**29, False, 8, b"\0" * 8, 1.0, "c", False, False, False)),
        ("/cmm/can_rx", (0x200, 0, 8, b"\0" * 8, 1.0, "c", False, False, False)),
        ("/cmm/can_rx", (0x200, False, 8, b"\0" * 8, 1.0, "c", False, False)),
        ("/cmm/can_rx", (0x200, False, 8, b"\0" * 8, 1.0, "c", False, False, False, "echo")),
        ("/cmm/can_rx", (0x200, False, 8, b"\0" * 8, 1.0, "c", False, False, False, None)),
    ],
)
def test_bad_records_never_take_the_fast_path(topic: str, rec: tuple) -> None:
    assert FAST_JSON[topic](rec, 5) is None
