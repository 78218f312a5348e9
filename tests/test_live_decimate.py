"""Decimation of the live view (daemon/live/decimate.py): per update at most ``max_per_update``
messages of ``/cmm/raw`` and of ``/cmm/corrected``, evenly picked, the newest kept, answers that
are not ``ok`` kept besides; every other topic whole; exact counts. Oracles: brute-force
properties of the picks, and seqs worked out by hand for one update seen by a client."""

from __future__ import annotations

import itertools

from test_live import T0_NS, connect, corr_rec, raw_rec, settings

from cmm_comp.daemon.live import LiveSink
from cmm_comp.daemon.live.decimate import is_not_ok, kept, pick_evenly


def test_pick_evenly_is_even_and_keeps_the_newest() -> None:
    for count in range(0, 80):
        for k in range(1, 14):
            got = pick_evenly(count, k)
            assert len(got) == min(count, k)
            assert got == sorted(set(got)) and all(0 <= i < count for i in got)
            if count:
                assert got[-1] == count - 1
            if count > k > 1:
                assert got[0] == 0
                gaps = [b - a for a, b in itertools.pairwise(got)]
                assert max(gaps) - min(gaps) <= 1  # as even as integers allow


def test_kept_adds_the_newest_answers_not_ok() -> None:
    ok = corr_rec(0, (0, 0, 0), "ok", (0.0, 0.0, 0.0))
    bad = corr_rec(0, (0, 0, 0), "outside_volume", (0.0, 0.0, 0.0))
    payloads = [bad if i in (3, 7, 8, 60) else ok for i in range(100)]
    assert kept("/cmm/corrected", payloads, 2) == {0, 99, 8, 60}  # + the newest 2 not ok
    assert kept("/cmm/corrected", payloads, 4) == {0, 33, 66, 99, 3, 7, 8, 60}
    assert kept("/cmm/raw", payloads, 4) == {0, 33, 66, 99}
    assert kept("/cmm/raw", payloads[:4], 4) is None  # few enough: all
    assert kept("/cmm/temperature", payloads, 1) is None  # never decimated
    assert kept("/cmm/counters", payloads, 1) is None
    assert is_not_ok({"status": "no_temperature"}) and not is_not_ok({"status": "ok"})
    assert is_not_ok(("short",)) and is_not_ok(None)  # unreadable: shown, not hidden


def test_one_update_sends_the_picked_messages_and_counts_the_rest() -> None:
    """100 readings arrive between two updates (10 batches); ``max_per_update = 3``."""
    with LiveSink(settings(max_per_update=3)).start() as sink:
        with connect(sink, ["/cmm/raw", "/cmm/corrected", "/cmm/temperature"]) as client:
            for b in range(10):
                seqs = range(10 * b, 10 * b + 10)
                sink.log_many("/cmm/raw", [raw_rec(s, 1.0, 2.0, 3.0) for s in seqs], T0_NS + b)
                status = ["outside_volume" if s in (10, 20) else "ok" for s in seqs]
                corr = [corr_rec(s, (1, 2, 3), st, (0.5, 0.0, 0.0)) for s, st in zip(seqs, status, strict=True)]  # fmt: skip
                sink.log_many("/cmm/corrected", corr, T0_NS + b)
            temps = [{"sensor": str(i), "role": "T_x", "temp_C": 20.0} for i in range(6)]
            sink.log_many("/cmm/temperature", temps, T0_NS)
            sink.tick()
            got = client.receive(3 + 5 + 6)
        s = sink.stats()
    seqs_of: dict[str, list[int]] = {}
    for m in got:
        seqs_of.setdefault(m.topic, []).append(m.json().get("seq", -1))
    # pick_evenly(100, 3): 0, round(49.5) = 50 (to even), 99
    assert seqs_of["/cmm/raw"] == [0, 50, 99]
    assert seqs_of["/cmm/corrected"] == [0, 10, 20, 50, 99]  # + the two not ok
    assert len(seqs_of["/cmm/temperature"]) == 6  # whole
    assert (s.offered, s.sent, s.decimated, s.not_encoded, s.dropped, s.queue_len) == (
        206, 14, 192, 0, 0, 0
    )  # fmt: skip
    assert s.counters()["live_decimated"] == 192
