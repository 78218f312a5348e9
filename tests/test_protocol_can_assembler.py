"""TripletAssembler: interleaving, loss, duplicates, reordering, wraparound, bounded memory."""

from __future__ import annotations

import random

from hypothesis import given, settings
from hypothesis import strategies as st

from cmm_comp.protocol import (
    Axis,
    CorrectedAxis,
    Duplicate,
    Incomplete,
    OutOfOrder,
    RawAxis,
    Status,
    Superseded,
    Triplet,
    TripletAssembler,
)

X, Y, Z = Axis.X, Axis.Y, Axis.Z


def f(axis: Axis, seq: int, pos: int | None = None) -> RawAxis:
    """Frame whose position encodes (seq, axis), so a mixed triplet is detectable."""
    return RawAxis(axis, seq, seq * 10 + int(axis) if pos is None else pos)


def feed_all(asm: TripletAssembler[RawAxis], frames: list[RawAxis]) -> list[object]:
    events: list[object] = []
    for frame in frames:
        events += asm.feed(frame)
    return events


def triplets(events: list[object]) -> list[int]:
    return [e.seq for e in events if isinstance(e, Triplet)]


def test_in_order_triplets() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    events = feed_all(asm, [f(a, s) for s in range(5) for a in (X, Y, Z)])
    assert events == [Triplet(s, f(X, s), f(Y, s), f(Z, s)) for s in range(5)]
    assert asm.pending_seqs == () and asm.last_finished_seq == 4


def test_axis_order_within_a_triplet_does_not_matter() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    assert asm.feed(f(Z, 7)) == [] and asm.feed(f(X, 7)) == []
    assert asm.feed(f(Y, 7)) == [Triplet(7, f(X, 7), f(Y, 7), f(Z, 7))]


def test_interleaved_seqs_are_never_mixed() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    order = [f(X, 1), f(Y, 1), f(X, 2), f(Z, 1), f(Y, 2), f(Z, 2)]
    events = feed_all(asm, order)
    assert events == [
        Triplet(1, f(X, 1), f(Y, 1), f(Z, 1)),
        Triplet(2, f(X, 2), f(Y, 2), f(Z, 2)),
    ]


def test_lost_frame_is_superseded_when_a_newer_seq_completes() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    events = feed_all(asm, [f(X, 1), f(Y, 1), f(X, 2), f(Y, 2), f(Z, 2)])
    assert len(events) == 2
    sup = events[0]
    assert isinstance(sup, Superseded)
    assert (sup.seq, sup.present, sup.missing, sup.by_seq) == (1, (X, Y), (Z,), 2)
    assert "missing Z" in sup.reason and "2 completed" in sup.reason
    assert events[1] == Triplet(2, f(X, 2), f(Y, 2), f(Z, 2))
    # the lost frame arriving after all is late, not a new triplet
    late = asm.feed(f(Z, 1))
    assert len(late) == 1 and isinstance(late[0], OutOfOrder)
    assert (late[0].seq, late[0].axis, late[0].newest_seq) == (1, Z, 2)


def test_duplicates_pending_and_after_emission() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    assert asm.feed(f(X, 3)) == []
    dup = asm.feed(f(X, 3))
    assert dup == [Duplicate(3, X, True, "X of seq 3 again: identical repeat")]
    conflict = asm.feed(f(X, 3, pos=999))
    assert isinstance(conflict[0], Duplicate) and not conflict[0].identical
    events = feed_all(asm, [f(Y, 3), f(Z, 3)])
    assert events == [Triplet(3, f(X, 3), f(Y, 3), f(Z, 3))]  # first X kept
    again = asm.feed(f(Y, 3))
    assert isinstance(again[0], Duplicate) and again[0].identical
    assert "after its triplet was emitted" in again[0].reason


def test_window_bounds_memory_and_reports_incomplete() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler(window=3)
    events = feed_all(asm, [f(X, s) for s in range(10)])
    assert all(isinstance(e, Incomplete) for e in events)
    assert [e.seq for e in events] == list(range(7))  # type: ignore[attr-defined]
    assert "window of 3 pending full" in events[0].reason  # type: ignore[attr-defined]
    assert asm.pending_seqs == (7, 8, 9)
    flushed = asm.flush("timeout 5 ms")
    assert [(e.seq, e.present, e.missing) for e in flushed] == [
        (s, (X,), (Y, Z)) for s in (7, 8, 9)
    ]
    assert asm.pending_seqs == ()


def test_wraparound_at_2_pow_16() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    seqs = [65533, 65534, 65535, 0, 1, 2]
    events = feed_all(asm, [f(a, s) for s in seqs for a in (Z, Y, X)])
    assert triplets(events) == seqs and len(events) == len(seqs)
    # interleaved across the wrap: 65535 incomplete, 0 completes -> 65535 superseded
    asm2: TripletAssembler[RawAxis] = TripletAssembler()
    feed_all(asm2, [f(X, 65534), f(Y, 65534), f(Z, 65534)])
    events = feed_all(asm2, [f(X, 65535), f(X, 0), f(Y, 0), f(Z, 0)])
    assert isinstance(events[0], Superseded) and events[0].seq == 65535
    assert triplets(events) == [0]
    late = asm2.feed(f(Y, 65535))
    assert isinstance(late[0], OutOfOrder)


def test_reordered_triplets_newest_wins() -> None:
    """Seq 5 completes before the last frame of seq 4: 4 is superseded, its Z is late."""
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    events = feed_all(asm, [f(X, 4), f(Y, 4), f(X, 5), f(Y, 5), f(Z, 5), f(Z, 4)])
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["Superseded", "Triplet", "OutOfOrder"]


def test_counter_jump_backwards_resynchronises() -> None:
    """A controller restart (seq back to 0 from 40000) is a jump, not 40000 late frames."""
    asm: TripletAssembler[RawAxis] = TripletAssembler(late_horizon=64)
    feed_all(asm, [f(a, 40000) for a in (X, Y, Z)])
    events = feed_all(asm, [f(a, 0) for a in (X, Y, Z)])
    assert triplets(events) == [0]
    late = asm.feed(f(X, 39990))  # 25546 behind 0 (mod 2**16), beyond the horizon: ahead
    assert late == [] and asm.pending_seqs == (39990,)


def test_startup_out_of_order_does_not_emit_backwards() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    events = feed_all(asm, [f(X, 5), f(X, 3), f(Y, 5), f(Y, 3), f(Z, 5), f(Z, 3)])
    assert triplets(events) == [5]
    assert isinstance(events[0], Superseded) and events[0].seq == 3
    assert isinstance(events[-1], OutOfOrder)


def test_works_for_corrected_frames_too() -> None:
    asm: TripletAssembler[CorrectedAxis] = TripletAssembler()
    frames = [CorrectedAxis(a, 9, 100, Status.OK) for a in (X, Y, Z)]
    events = [e for fr in frames for e in asm.feed(fr)]
    assert events == [Triplet(9, *frames)]


@settings(max_examples=200, deadline=None)
@given(
    n=st.integers(1, 40),
    start=st.integers(0, 65535),
    seed=st.integers(0, 2**32 - 1),
    loss=st.floats(0, 0.3),
    dup=st.floats(0, 0.2),
    window=st.integers(1, 6),
)
def test_invariants_under_loss_duplication_and_local_reordering(
    n: int, start: int, seed: int, loss: float, dup: float, window: int
) -> None:
    """Random lossy, duplicating, locally shuffled stream: triplets are never mixed, come out
    in increasing seq order, and memory stays within the window."""
    rng = random.Random(seed)
    seqs = [(start + i) % 65536 for i in range(n)]
    stream = []
    for s in seqs:
        axes = [X, Y, Z]
        rng.shuffle(axes)
        for a in axes:
            if rng.random() >= loss:
                stream.append(f(a, s))
            if rng.random() < dup:
                stream.append(f(a, s))
    # swap some neighbours (local reordering)
    for i in range(len(stream) - 1):
        if rng.random() < 0.1:
            stream[i], stream[i + 1] = stream[i + 1], stream[i]
    asm: TripletAssembler[RawAxis] = TripletAssembler(window=window)
    emitted: list[int] = []
    for frame in stream:
        for event in asm.feed(frame):
            if isinstance(event, Triplet):
                assert (event.x.axis, event.y.axis, event.z.axis) == (X, Y, Z)
                assert {event.x.seq, event.y.seq, event.z.seq} == {event.seq}
                assert event.x.position_nm == event.seq * 10  # never a frame of another seq
                emitted.append(event.seq)
        assert len(asm.pending_seqs) <= window
    order = [(s - start) % 65536 for s in emitted]
    assert order == sorted(set(order))  # strictly increasing, no seq twice
    if loss == 0 and dup == 0 and stream == sorted(stream, key=lambda fr: (fr.seq - start) % 65536):
        assert emitted == seqs


def _restart_frames(seqs: list[int], epoch: int) -> list[RawAxis]:
    """A reading per seq; ``epoch`` is encoded in the position so each controller run's
    readings differ from the previous run's with the same seq (the machine moved)."""
    return [f(a, s, pos=epoch * 1_000_000 + s * 10 + int(a)) for s in seqs for a in (X, Y, Z)]


def test_restart_within_256_behind_is_answered_from_its_first_reading() -> None:
    """Controller restarts: seq 0..99, then 0..29 again (within 256 behind the last finished,
    the old rule dropped every one of them as late), then 60..69 (inside the remembered
    finished seqs). Oracle: the spec rule, every complete reading is emitted, with the frames
    of its own run (never a frame of the earlier run with the same seq)."""
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    first = feed_all(asm, _restart_frames(list(range(100)), epoch=1))
    assert triplets(first) == list(range(100))
    again = feed_all(asm, _restart_frames(list(range(30)), epoch=2))
    assert triplets(again) == list(range(30)) and len(again) == 30
    third = feed_all(asm, _restart_frames(list(range(60, 70)), epoch=3))
    assert triplets(third) == list(range(60, 70)) and len(third) == 10
    for ev in again + third:
        assert isinstance(ev, Triplet)
        epoch = ev.x.position_nm // 1_000_000
        assert [fr.position_nm for fr in (ev.x, ev.y, ev.z)] == [
            epoch * 1_000_000 + ev.seq * 10 + k for k in range(3)
        ]
    assert asm.pending_seqs == ()


def test_restart_to_a_recent_seq_with_one_axis_unchanged() -> None:
    """A restarted controller re-sends seq 5 where Y did not move (byte-identical Y frame) and
    X changed: answered with the new X, whatever the position of Y among the frames."""
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    feed_all(asm, [f(a, s) for s in range(8) for a in (X, Y, Z)])
    new_x, new_z = f(X, 5, pos=777), f(Z, 5, pos=778)
    events = feed_all(asm, [new_x, f(Y, 5), new_z])
    assert events == [Triplet(5, new_x, f(Y, 5), new_z)]


def test_a_retransmitted_frame_of_an_answered_reading_starts_nothing() -> None:
    """A byte-identical repeat of a frame already used is a Duplicate: no pending reading is
    opened for it, so no second (incomplete) answer ever follows."""
    asm: TripletAssembler[RawAxis] = TripletAssembler()
    feed_all(asm, [f(a, s) for s in range(3) for a in (X, Y, Z)])
    for s in range(3):
        for a in (X, Y, Z):
            ev = asm.feed(f(a, s))
            assert len(ev) == 1 and isinstance(ev[0], Duplicate) and ev[0].identical
    assert asm.pending_seqs == () and asm.flush() == []


def test_memory_of_finished_seqs_is_bounded() -> None:
    asm: TripletAssembler[RawAxis] = TripletAssembler(memory=8)
    feed_all(asm, [f(a, s) for s in range(100) for a in (X, Y, Z)])
    assert len(asm._finished) == 8
    assert asm.feed(f(X, 10)) == [] and asm.pending_seqs == (10,)  # forgotten: a new reading
