"""Hypothesis fuzz of frame decoding into the daemon: never crashes; every frame either leads
to an answer, counts a fault, is a temperature sample / probing direction / pending axis, or
is one of the daemon's own frames (udp_multicast echo)."""

from __future__ import annotations

from collections.abc import Iterator

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_daemon_support import base_config, channel

from cmm_comp.daemon.can_endpoint import CanEndpoint
from cmm_comp.daemon.service import DaemonService
from cmm_comp.protocol import CanIds

IDS = CanIds()
BLOCK = IDS.block_start

frames = st.builds(
    lambda off, ext, data, rtr, err, far: can.Message(
        arbitration_id=(0x7FF if far else BLOCK + off),
        is_extended_id=ext,
        data=b"" if rtr else data,
        is_remote_frame=rtr,
        is_error_frame=err,
        dlc=len(data) if not rtr else 0,
    ),
    st.integers(0, 15),
    st.booleans(),
    st.binary(min_size=0, max_size=8),
    st.booleans(),
    st.booleans(),
    st.booleans(),
)
# bias towards well-formed raw axis frames of the same few seqs, so triplets complete
raw_axis = st.builds(
    lambda axis, seq, pos, flags: can.Message(
        arbitration_id=BLOCK + axis,
        is_extended_id=False,
        data=pos.to_bytes(5, "little", signed=True) + seq.to_bytes(2, "little") + bytes([flags]),
    ),
    st.integers(0, 2),
    st.integers(0, 3),
    st.integers(-(2**39), 2**39 - 1) | st.integers(0, 900_000_000),
    st.integers(0, 255),
)


def _activity(d: DaemonService) -> int:
    m = d.metrics
    return (
        sum(m.faults.values())
        + m.answered
        + m.get("temperature_samples")
        + m.get("temperature_repeats")
        + m.get("own_frames_ignored")
    )


def _pending(endpoint: CanEndpoint) -> dict[int, tuple[int, ...]]:
    """Pending seq → axes received (a white-box view of the assembler)."""
    return {s: tuple(sorted(p)) for s, p in endpoint._assembler._pending.items()}


@pytest.fixture(scope="module")
def daemon() -> Iterator[tuple[DaemonService, CanEndpoint]]:
    """A daemon (Modbus side only, so no CAN thread races the test) and a CAN endpoint whose
    receive path the test drives synchronously."""
    cfg = base_config(channel())
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    cfg.metrics.enabled = False
    with DaemonService(cfg, events_stream=None) as d:
        assert d.engine is not None
        endpoint = CanEndpoint(cfg.can, d.engine, d.state, d.heartbeat, d.metrics, d.events, None)
        assert endpoint._open()
        try:
            yield d, endpoint
        finally:
            endpoint.stop()


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(msgs=st.lists(st.one_of(frames, raw_axis), min_size=1, max_size=40))
def test_fuzzed_frames_never_crash(daemon, msgs: list[can.Message]) -> None:
    d, endpoint = daemon
    for msg in msgs:
        before = _activity(d)
        pending_before = _pending(endpoint)
        probes_before = dict(endpoint._probe)
        endpoint.on_message_received(msg)  # the receive path, synchronously
        progressed = _activity(d) > before
        pending = _pending(endpoint) != pending_before
        probe = dict(endpoint._probe) != probes_before or msg.arbitration_id == BLOCK + 3
        assert progressed or pending or probe, msg
    assert endpoint.last_error is None
    assert d.metrics.faults.get("internal_error", 0) == 0
