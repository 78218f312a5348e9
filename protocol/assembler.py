"""Assemble per-axis frames into X/Y/Z triplets of one instant (same seq), never mixing two.

:class:`TripletAssembler` takes decoded axis frames (:class:`RawAxis` on the daemon side,
:class:`CorrectedAxis` on the controller side) and returns events: a :class:`Triplet` when X, Y
and Z of one seq are all there, and typed reports (never exceptions) for everything else:

- :class:`Duplicate`: an axis arrived twice for a pending seq (first one kept), or a frame
  byte-identical to the one of its axis in a recently finished reading (a retransmission);
- :class:`OutOfOrder`: a frame for a recently dropped seq (superseded or incomplete) of an axis
  that reading lacked, i.e. the missing frame arriving too late to be used;
- :class:`Superseded`: a pending, incomplete seq dropped because a newer seq completed first;
- :class:`Incomplete`: a pending seq dropped because the window of pending seqs was full, or
  by :meth:`TripletAssembler.flush` (e.g. on a timeout the caller measures).

Every complete reading is emitted, whatever its seq: a controller that restarts its counter
(back to 0, or anywhere) is served from its first reading. A frame whose seq is not pending
starts a new reading unless that seq is among the last ``memory`` finished ones and the frame
is a retransmission (:class:`Duplicate`, byte-identical to the frame already used) or the late
missing frame of a dropped reading (:class:`OutOfOrder`). So a seq finished recently is
answered again only when a frame with new content for it arrives (a restarted controller); the
frames of one emitted triplet always share one seq, and a pending reading keeps the first frame
of each axis.

Seqs are uint16 and wrap: "newer" (for superseding) is decided modulo 2**16 relative to the
last finished seq; a completed seq supersedes the incomplete pending seqs at most
``late_horizon`` behind it, never those ahead of it (a counter jump leaves them to the window
or the caller's timeout). Memory is bounded: at most ``window`` pending seqs and ``memory``
remembered finished seqs.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from .codes import SEQ_MODULUS, Axis, seq_distance


class AxisFrame(Protocol):
    """What the assembler needs from a frame: its axis and seq (RawAxis, CorrectedAxis)."""

    @property
    def axis(self) -> Axis: ...

    @property
    def seq(self) -> int: ...


F = TypeVar("F", bound=AxisFrame)


@dataclass(frozen=True, slots=True)
class Triplet(Generic[F]):
    """X, Y and Z frames of reading ``seq``."""

    seq: int
    x: F
    y: F
    z: F


@dataclass(frozen=True, slots=True)
class Incomplete:
    """Pending seq dropped before all axes arrived (window full or flushed)."""

    seq: int
    present: tuple[Axis, ...]
    missing: tuple[Axis, ...]
    reason: str


@dataclass(frozen=True, slots=True)
class Superseded:
    """Pending seq dropped because the newer seq ``by_seq`` completed first."""

    seq: int
    present: tuple[Axis, ...]
    missing: tuple[Axis, ...]
    by_seq: int
    reason: str


@dataclass(frozen=True, slots=True)
class Duplicate:
    """Second frame for the same (seq, axis); ``identical`` if it equals the first."""

    seq: int
    axis: Axis
    identical: bool
    reason: str


@dataclass(frozen=True, slots=True)
class OutOfOrder:
    """Frame for a seq that was already finished; ``newest_seq`` is the last finished seq."""

    seq: int
    axis: Axis
    newest_seq: int
    reason: str


AssemblerEvent = Triplet[F] | Incomplete | Superseded | Duplicate | OutOfOrder
_AXES = (Axis.X, Axis.Y, Axis.Z)


class TripletAssembler(Generic[F]):
    """Collect axis frames into same-seq triplets; see the module docstring for the events.

    ``window``: maximum number of pending (incomplete) seqs kept; ``late_horizon``: how many
    seqs behind a completed one an incomplete pending seq is superseded by it; ``memory``: how
    many finished seqs are remembered to recognise retransmissions and late frames.
    """

    def __init__(self, window: int = 4, late_horizon: int = 256, memory: int = 64) -> None:
        if window < 1:
            raise ValueError(f"window {window} must be >= 1")
        if not 1 <= late_horizon < SEQ_MODULUS // 2:
            raise ValueError(f"late_horizon {late_horizon} out of range 1..{SEQ_MODULUS // 2 - 1}")
        if memory < 1:
            raise ValueError(f"memory {memory} must be >= 1")
        self.window = window
        self.late_horizon = late_horizon
        self.memory = memory
        self._pending: OrderedDict[int, dict[Axis, F]] = OrderedDict()
        # finished seq -> (frames it had, emitted?); oldest first, at most `memory`
        self._finished: OrderedDict[int, tuple[dict[Axis, F], bool]] = OrderedDict()
        self._last_finished: int | None = None
        self._anchor: int | None = None

    @property
    def pending_seqs(self) -> tuple[int, ...]:
        """Seqs waiting for more axes, oldest first."""
        return tuple(self._pending)

    @property
    def last_finished_seq(self) -> int | None:
        """Newest seq emitted or superseded (None before the first one)."""
        return self._last_finished

    def feed(self, frame: F) -> list[AssemblerEvent[F]]:
        """Add one axis frame; return the events it causes (possibly none)."""
        seq, axis = frame.seq, frame.axis
        if type(axis) is not Axis:
            axis = Axis(axis)
        events: list[AssemblerEvent[F]] = []
        if self._anchor is None:
            self._anchor = (seq - self.late_horizon - 1) % SEQ_MODULUS
        parts = self._pending.get(seq)
        if parts is None:
            late = self._late(frame)
            if late is not None:
                events.append(late)
                return events
            parts = self._pending[seq] = {}
            self._sort_pending()
        if axis in parts:
            same = parts[axis] == frame
            why = "identical repeat" if same else "different payload; first kept"
            events.append(Duplicate(seq, axis, same, f"{axis.name} of seq {seq} again: {why}"))
            return events
        parts[axis] = frame
        if len(parts) == 3:
            events.extend(self._complete(seq))
        elif len(self._pending) > self.window:
            old_seq, old = self._pending.popitem(last=False)
            events.append(self._incomplete(old_seq, old, f"window of {self.window} pending full"))
        return events

    def flush(self, reason: str = "flushed") -> list[Incomplete]:
        """Drop all pending seqs (e.g. after a timeout) and report each as Incomplete."""
        events = [self._incomplete(s, parts, reason) for s, parts in self._pending.items()]
        self._pending.clear()
        return events

    # -- internals ------------------------------------------------------------------------

    def _late(self, frame: F) -> Duplicate | OutOfOrder | None:
        """The report for a frame of a recently finished seq that must not start a new
        reading (retransmission, late missing frame), else None."""
        seq, axis = frame.seq, Axis(frame.axis)
        known = self._finished.get(seq)
        if known is None:
            return None
        parts, emitted = known
        first = parts.get(axis)
        if first is None:
            newest = seq if self._last_finished is None else self._last_finished
            msg = (
                f"{axis.name} of seq {seq} after that reading was dropped incomplete "
                f"(newest finished: {newest}); ignored"
            )
            return OutOfOrder(seq, axis, newest, msg)
        if first == frame:
            when = "after its triplet was emitted" if emitted else "after it was dropped"
            msg = f"{axis.name} of seq {seq} {when}: identical repeat; ignored"
            return Duplicate(seq, axis, True, msg)
        return None  # new content for a finished seq: a new reading (controller restart)

    def _remember(self, seq: int, parts: dict[Axis, F], emitted: bool) -> None:
        finished = self._finished
        finished.pop(seq, None)
        finished[seq] = (parts, emitted)
        if len(finished) > self.memory:
            finished.popitem(last=False)

    def _key(self, seq: int) -> int:
        """Age order of pending seqs: distance ahead of the last finished seq (or the anchor)."""
        ref = self._last_finished if self._last_finished is not None else self._anchor
        assert ref is not None
        return seq_distance(seq, ref)

    def _sort_pending(self) -> None:
        if len(self._pending) > 1:
            order = sorted(self._pending, key=self._key)
            for s in order:
                self._pending.move_to_end(s)

    def _complete(self, seq: int) -> list[AssemblerEvent[F]]:
        events: list[AssemblerEvent[F]] = []
        for old_seq in list(self._pending):
            if old_seq == seq or seq_distance(seq, old_seq) > self.late_horizon:
                continue  # newer than seq (or a counter jump): keep waiting
            parts = self._pending.pop(old_seq)
            present, missing = _split(parts)
            msg = f"seq {old_seq} dropped incomplete (missing {_names(missing)}): {seq} completed"
            events.append(Superseded(old_seq, present, missing, seq, msg))
            self._remember(old_seq, parts, False)
        parts = self._pending.pop(seq)
        triplet = Triplet(seq, parts[Axis.X], parts[Axis.Y], parts[Axis.Z])
        events.append(triplet)
        self._last_finished = seq
        self._remember(seq, parts, True)
        self._sort_pending()
        return events

    def _incomplete(self, seq: int, parts: dict[Axis, F], reason: str) -> Incomplete:
        self._remember(seq, parts, False)
        present, missing = _split(parts)
        return Incomplete(seq, present, missing, f"seq {seq} missing {_names(missing)}: {reason}")


def _split(parts: dict[Axis, F]) -> tuple[tuple[Axis, ...], tuple[Axis, ...]]:
    present = tuple(a for a in _AXES if a in parts)
    missing = tuple(a for a in _AXES if a not in parts)
    return present, missing


def _names(axes: tuple[Axis, ...]) -> str:
    return "".join(a.name for a in axes) or "nothing"
