"""CorrectionEngine.correct_many: a batch gives the same answers, bit for bit, as correcting
each reading on its own (the oracle the endpoint's batching must never leave)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_daemon_support import base_config, channel

from cmm_comp.daemon.engine import BATCH_MIN, CorrectionEngine, Reading
from cmm_comp.daemon.service import DaemonService

NOW_S = 1000.0


@pytest.fixture(scope="module")
def engine() -> Iterator[CorrectionEngine]:
    """The engine of a daemon (Modbus side only: no CAN thread), temperatures set at NOW_S."""
    cfg = base_config(channel())
    cfg.can.enabled = False
    cfg.modbus.enabled = True
    cfg.modbus.port = 0
    cfg.metrics.enabled = False
    cfg.limits.warn_um = 5.0  # some answers carry a warning detail
    with DaemonService(cfg, events_stream=None) as d:
        assert d.engine is not None
        for sensor, temp in enumerate((20.7, 21.1, 19.6, 20.3)):
            d.temperatures.update(sensor, temp, 1, True, NOW_S)
        yield d.engine


reading = st.builds(
    Reading,
    seq=st.integers(0, 0xFFFF),
    position_nm=st.tuples(
        st.integers(-50_000_000, 950_000_000),  # a few outside the NPL volume
        st.integers(-50_000_000, 1_200_000_000),
        st.integers(-50_000_000, 450_000_000),
    ),
    directions=st.tuples(*[st.sampled_from((-1, 0, 1))] * 3),
    valid=st.sampled_from(((True, True, True),) * 6 + ((True, False, True),)),
    probe=st.sampled_from((None,) * 5 + ((0.0, 0.0, 1.0), (0.6, 0.8, 0.0))),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rs=st.lists(reading, min_size=0, max_size=300))
def test_batch_equals_one_at_a_time(engine: CorrectionEngine, rs: list[Reading]) -> None:
    one_by_one = [engine.correct(r, NOW_S) for r in rs]
    batch = engine.correct_many(rs, NOW_S)
    assert batch == one_by_one


def test_a_plain_batch_takes_the_vectorised_path(engine: CorrectionEngine, monkeypatch) -> None:
    """Plain in-volume readings go through one grid call per batch (not correct_point), and
    still equal the one-at-a-time answers."""
    rs = [Reading(i, (100_000_000 + 7_000_000 * i, 500_000_000, 200_000_000)) for i in range(40)]
    expected = [engine.correct(r, NOW_S) for r in rs]
    assert all(a.status.label == "ok" for a in expected)
    loaded = engine.grids.current
    assert loaded is not None and len(rs) >= BATCH_MIN

    def no_single(*a, **kw):
        raise AssertionError("correct_point called inside a plain batch")

    monkeypatch.setattr(loaded.grid, "correct_point", no_single)
    assert engine.correct_many(rs, NOW_S) == expected


def test_applied_flags_follow_the_grid_after_swaps(engine: CorrectionEngine) -> None:
    """The Applied flags are cached per input pattern for the current grid: after a swap they
    are the new grid's, also when the new grid object takes a freed grid's memory (and id).
    Oracle: the flags' definition from the temperature roles the grid declares. Grids alternate
    with a period of 3 so that a reused address belongs to a grid declaring other roles."""
    import dataclasses
    import gc

    from cmm_comp.protocol.codes import Applied

    slot = engine.grids
    original = slot.current
    assert original is not None
    roles = tuple(original.temperature_roles)
    assert {"T_x", "T_wp"} <= set(roles)
    declared = (roles, ("T_x",), ("T_wp",))
    required = engine.config.temperatures.required
    engine.config.temperatures.required = list(roles)  # the same temperatures every time
    r = Reading(1, (300_000_000, 500_000_000, 200_000_000))
    try:
        for k in range(9):
            slot._current = None  # the previous grid is freed: its address may be reused
            gc.collect()
            grid = dataclasses.replace(original, temperature_roles=declared[k % 3])
            slot._current = grid
            answer = engine.correct(r, NOW_S)
            assert answer.status.label == "ok", answer
            scale = bool(set(grid.temperature_roles) & {"T_x", "T_y", "T_z"})
            assert bool(answer.applied & Applied.SCALE_THERMAL) == scale, (k, answer.applied)
            wp = "T_wp" in grid.temperature_roles
            assert bool(answer.applied & Applied.WORKPIECE_THERMAL) == wp, (k, answer.applied)
            del grid, answer
    finally:
        slot._current = original
        engine.config.temperatures.required = required
