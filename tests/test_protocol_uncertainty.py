"""U on the wire (issue 13 item 4): the CORRECTION_UNCERTAINTY frame, APPLIED bit 5 and the
Modbus UNCERTAINTY registers.

Oracles: cantools decoding ``protocol/cmm_comp.dbc`` (its own scaling raw · 0.01 and its value
table for the codes 65534/65535), exact rational arithmetic (``fractions.Fraction``) for "the
wire never states less than U", and payloads computed by hand from docs/can.md.
"""

from __future__ import annotations

import math
from fractions import Fraction

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.protocol import (
    AnswerBlock,
    Applied,
    CanIds,
    CorrectionStatus,
    CorrectionUncertainty,
    MessageKind,
    Status,
    dbc_text,
    decode_message,
    encode_correction_uncertainty,
    encode_message,
)
from cmm_comp.protocol.codes import (
    UNCERTAINTY_SATURATED,
    UNCERTAINTY_UNKNOWN,
    um_from_uncertainty_raw,
    uncertainty_raw_from_um,
)

DB = cantools.database.load_string(dbc_text(), database_format="dbc")
U_MSG = DB.get_message_by_name("CORRECTION_UNCERTAINTY")
TOP_UM = Fraction(65533, 100)  # the largest value the field states: 655.33 µm

# U values a daemon may meet: exact zero, tiny, ordinary, near the top of the field, huge,
# NaN, ±inf, negative (a bug upstream: must never become a plausible number)
u_values = st.one_of(
    st.just(0.0),
    st.just(-0.0),
    st.floats(0.0, 1e-6),
    st.floats(0.0, 50.0),
    st.floats(650.0, 660.0),
    st.floats(0.0, 1e300),
    st.sampled_from([math.nan, math.inf, -math.inf, -1e-300, -3.0, 655.33, 655.335, 0.29, 0.57]),
    st.decimals(0, 700, places=2).map(float),  # exactly on (or a rounding away from) the LSB
)


def expected_raw(u: float) -> int:
    """The raw code written from docs/can.md by brute force: the smallest k whose decoded value
    is not below U however a reader scales it (k · 0.01 and k / 100 in floats), searched from
    an exact lower bound; unknown for NaN or negative, saturated when that k exceeds 65533."""
    if math.isnan(u) or u < 0:
        return UNCERTAINTY_UNKNOWN
    if math.isinf(u) or Fraction(u) > TOP_UM + Fraction(1, 100):
        return UNCERTAINTY_SATURATED
    k = max(0, math.floor(Fraction(u) * 100) - 2)
    while not (k * 0.01 >= u and k / 100 >= u):
        k += 1
    return k if k <= 65533 else UNCERTAINTY_SATURATED


@settings(max_examples=1500, deadline=None)
@given(u_values)
def test_raw_is_the_smallest_lsb_count_not_below_U(u: float) -> None:
    raw = uncertainty_raw_from_um(u)
    assert raw == expected_raw(u)
    if raw < UNCERTAINTY_SATURATED:
        assert raw / 100 >= u and raw * 0.01 >= u  # never below U, however a reader scales
        assert Fraction(raw, 100) - Fraction(u) < Fraction(1, 100)  # and at most 1 LSB above


@settings(max_examples=800, deadline=None)
@given(u_values, u_values, u_values, st.integers(0, 0xFFFF))
def test_cantools_decodes_the_daemons_bytes_never_below_U(
    ux: float, uy: float, uz: float, seq: int
) -> None:
    data = encode_correction_uncertainty(seq, (ux, uy, uz))
    assert data == CorrectionUncertainty.from_um(seq, (ux, uy, uz)).encode()
    got = U_MSG.decode(data)  # physical values and the value table's names
    assert got["Seq"] == seq
    for name, u in (("Ux", ux), ("Uy", uy), ("Uz", uz)):
        v = got[name]
        if math.isnan(u) or u < 0:
            assert str(v) == "unknown"
        elif math.isinf(u) or u > 655.34:
            assert str(v) == "saturated"
        elif str(v) != "saturated":  # 655.33 < U ≤ 655.34 may saturate (never understated)
            assert isinstance(v, float) and v >= u and v - u < 0.02
    frame = decode_message(encode_message(CorrectionUncertainty.decode(data), CanIds()), CanIds())
    assert isinstance(frame, CorrectionUncertainty)
    for ours, u in zip(frame.u_um, (ux, uy, uz), strict=True):
        assert math.isnan(ours) if (math.isnan(u) or u < 0) else ours >= u


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 0xFFFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF))
def test_cantools_encodes_raw_values_our_frame_decodes(ux: int, uy: int, uz: int) -> None:
    data = U_MSG.encode({"Seq": 7, "Ux": ux, "Uy": uy, "Uz": uz}, scaling=False)
    assert CorrectionUncertainty.decode(data) == CorrectionUncertainty(7, ux, uy, uz)
    for raw, phys in zip((ux, uy, uz), CorrectionUncertainty.decode(data).u_um, strict=True):
        if raw == 0xFFFF:
            assert math.isnan(phys)
        elif raw == 0xFFFE:
            assert phys == math.inf
        else:
            assert phys == raw / 100


def test_hand_computed_frame_and_the_dbc_text() -> None:
    """seq 0x1234, Ux 1.234 µm → 124 (0x007C, rounded up), Uy 0 → 0, Uz unknown → 0xFFFF;
    node 0 id 0x20C (docs/can.md)."""
    frame = CorrectionUncertainty.from_um(0x1234, (1.234, 0.0, math.nan))
    msg = encode_message(frame, CanIds())
    assert msg.arbitration_id == 0x20C and not msg.is_extended_id
    assert bytes(msg.data) == bytes.fromhex("3412 7c00 0000 ffff")
    assert CanIds(node_id=2).id_of(MessageKind.CORRECTION_UNCERTAINTY) == 0x22C
    assert U_MSG.frame_id == 0x20C and U_MSG.length == 8 and U_MSG.senders == ["Daemon"]
    for name in ("Ux", "Uy", "Uz"):
        sig = U_MSG.get_signal_by_name(name)
        assert (sig.start, sig.length, sig.byte_order, sig.is_signed) == (
            16 * ("xyz".index(name[1].lower()) + 1),
            16,
            "little_endian",
            False,
        )
        assert sig.scale == 0.01 and sig.unit == "um"
        assert {int(k): str(v) for k, v in sig.choices.items()} == {
            65534: "saturated",
            65535: "unknown",
        }
        assert "k = 2 per component" in (sig.comment or "")
    assert CorrectionUncertainty(0, 1, 2, UNCERTAINTY_SATURATED).known is False
    assert CorrectionUncertainty(0, 1, 2, 65533).known is True


def test_applied_bit_5_is_in_the_dbc_and_older_decoders_ignore_it() -> None:
    status = CorrectionStatus(9, Status.OK, Applied.GEOMETRY | Applied.UNCERTAINTY, 12, 34)
    data = status.encode()
    assert data[3] == 0x21
    sig = DB.get_message_by_name("CORRECTION_STATUS").get_signal_by_name("Applied")
    assert (sig.start, sig.length) == (24, 6)
    assert DB.get_message_by_name("CORRECTION_STATUS").decode(data)["Applied"] == 0x21
    # the 5-bit signal of the old DBC reads the same frame as geometry only
    old = dbc_text().replace(
        "SG_ Applied : 24|6@1+ (1,0) [0|63]", "SG_ Applied : 24|5@1+ (1,0) [0|31]"
    )
    old_db = cantools.database.load_string(old, database_format="dbc")
    assert old_db.get_message_by_name("CORRECTION_STATUS").decode(data)["Applied"] == 0x01
    assert CorrectionStatus.decode(data).applied == Applied.GEOMETRY | Applied.UNCERTAINTY


@pytest.mark.parametrize(
    "u", [(0.0, 1e-9, 3.21), (655.33, 655.331, 1e6), (math.nan, math.inf, -1.0), None]
)
def test_modbus_registers_carry_the_can_frames_values(
    u: tuple[float, float, float] | None,
) -> None:
    block = AnswerBlock.from_physical(5, Status.OK, (1, 2, 3), Applied.GEOMETRY, 10.0, 1.0, u)
    frame = CorrectionUncertainty.decode(encode_correction_uncertainty(5, u))
    assert block.uncertainty_registers() == [frame.ux_10nm, frame.uy_10nm, frame.uz_10nm]
    assert block.uncertainty_known == frame.known
    if u is None:
        assert block.uncertainty_registers() == [0xFFFF] * 3
    got = block.uncertainty_um
    want = [um_from_uncertainty_raw(r) for r in block.uncertainty_registers()]
    assert [g if not math.isnan(g) else "nan" for g in got] == [
        w if not math.isnan(w) else "nan" for w in want
    ]
