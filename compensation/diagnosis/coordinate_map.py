"""The session's own map between the axis' position and the reference's reading
(:func:`through_map`): a term of one coordinate evaluated as the best version of it the other
coordinate can carry — the twins of :mod:`.sources` are compared through it."""

from __future__ import annotations

import itertools
from dataclasses import replace
from typing import Any

import numpy as np

from ..parametric_errors import AXIS_INDEX
from .candidate import Candidate
from .residuals import FloatArray, Residuals

__all__ = ["through_map"]


def _pass_duration_s(
    t: FloatArray | None, direction: FloatArray, coord: FloatArray
) -> float | None:
    """The median duration of a pass (a run of one direction of travel, broken where the
    direction changes or the position jumps back: a return not recorded), or None."""
    if t is None or float(np.ptp(t)) <= 0:
        return None
    order = np.argsort(t, kind="stable")
    dd, tt, xx = direction[order], t[order], coord[order]
    step = np.abs(np.diff(xx))
    typical = float(np.median(step[step > 0])) if np.any(step > 0) else 0.0
    breaks = (np.diff(dd) != 0) | (step > 20.0 * typical if typical > 0 else False)
    cuts = np.r_[0, np.flatnonzero(breaks) + 1, len(dd)]
    spans = [tt[b - 1] - tt[a] for a, b in itertools.pairwise(cuts) if b - a > 1]
    return float(np.median(spans)) if spans and np.median(spans) > 0 else None


class _ErrorMap:
    """The observed error ē (µm) along one coordinate ``own`` (mm) of a session, per direction
    of travel and per window of a pass and a half in time (:func:`through_map`)."""

    def __init__(
        self, own: FloatArray, err: FloatArray, direction: FloatArray, t: FloatArray | None
    ) -> None:
        window = _pass_duration_s(t, direction, own)
        self.window = 1.5 * window if window is not None else None
        self.t = t
        self.chunk = (
            np.zeros(len(own), dtype=int)
            if self.window is None or t is None
            else np.floor((t - float(np.min(t))) / self.window).astype(int)
        )
        self.groups: dict[tuple[float, int], tuple[FloatArray, FloatArray]] = {}
        for g in np.unique(direction):
            for c in np.unique(self.chunk):
                sel = (direction == g) & (np.abs(self.chunk - c) <= 1)
                order = np.argsort(own[sel], kind="stable")
                self.groups[(float(g), int(c))] = (own[sel][order], err[sel][order])
        self.dirs = np.unique(direction)

    def ebar(
        self, q: FloatArray, times: FloatArray | None, own_err: FloatArray, own_dir: FloatArray
    ) -> FloatArray:
        """ē at coordinates ``q`` (mm) observed at ``times`` (s), each point's own direction
        giving its own error ``own_err`` (µm), the other directions interpolated."""
        t, chunk, groups = self.t, self.chunk, self.groups
        if self.window is None or times is None or t is None:
            qc = np.zeros(len(q), dtype=int)
        else:
            qc = np.floor((times - float(np.min(t))) / self.window).astype(int)
        qc = np.clip(qc, int(np.min(chunk)), int(np.max(chunk)))
        out = np.zeros(len(q))
        for c in np.unique(qc):
            sel = qc == c
            # a point's own direction gives its own error (interpolating among the passes of
            # a window would mix in other passes' noise and drift: the map would no longer
            # be exact where a position has one reading); the other directions interpolated
            means = [
                np.where(
                    own_dir[sel] == g, own_err[sel], np.interp(q[sel], *groups[(float(g), int(c))])
                )
                for g in self.dirs
                if len(groups[(float(g), int(c))][0])
            ]
            out[sel] = np.mean(means, axis=0)
        return out


def through_map(cand: Candidate, res: Residuals) -> Candidate:
    """``cand`` (a term of one coordinate) evaluated through the session's own map between the
    axis' position x and the reference's reading r: a position-locked term at x + ē/1000, a
    reading-locked one at r − ē/1000, ē the observed error at that coordinate — the mean, over
    the directions of travel, of each direction's error interpolated linearly at it from that
    direction's points within a pass and a half in time (the neighbouring passes; at a
    measured point its own direction gives its own error).

    That is the best version of a cyclic error of the *other* instrument that a function of
    this coordinate can be: in a one-directional session the map is exact (a position has one
    reading) and the two hypotheses are the same term; with both directions one position has
    two readings, a reversal apart, and only one hypothesis fits both (docs/formats.md §4, the
    right source). Without the map, the phase a reading-locked error takes in position
    coordinates, 2π·e(x)/p, would itself tell them apart in a one-directional session, and so
    would the slow drift of e over the hours of a session — neither is the separation the
    contract names."""
    k = AXIS_INDEX[cand.keys["axis"]]
    locked = cand.locked_to
    own = res.q_mm[:, k] if locked == "position" else res.ref_mm[:, k]
    err = (res.ref_mm[:, k] - res.q_mm[:, k]) * 1000.0
    direction = res.signals.get(f"dir_{'xyz'[k]}", np.zeros(res.n))
    emap = _ErrorMap(own, err, direction, res.data.t_s)

    sign = 1.0 if locked == "position" else -1.0

    def mapped(r: Residuals) -> Residuals:
        # the reading as the coordinate (its noise out, :mod:`.reading`), as ``err`` above
        col = (r.q_mm if locked == "position" else r.ref_mm).copy()
        own_err = (r.ref_mm[:, k] - r.q_mm[:, k]) * 1000.0
        own_dir = r.signals.get(f"dir_{'xyz'[k]}", np.zeros(r.n))
        col[:, k] = col[:, k] + sign * emap.ebar(col[:, k], r.data.t_s, own_err, own_dir) / 1000.0
        if locked == "reference":
            return replace(r, reading_mm=col)
        data = r.data.subset(slice(None))
        data.indicated_mm = col
        return replace(r, data=data)

    def wrap(c: Candidate) -> Candidate:
        inner = c

        def design(r: Residuals, theta: Any) -> FloatArray:
            return inner.design_uncached(mapped(r), theta)

        return replace(
            c,
            design_fn=design,
            design_many=None,
            design_component=None,
            rich=None,
            _cache={},
            _statics={},
        )

    out = wrap(cand)
    out.rich = wrap(cand.rich) if cand.rich is not None else None
    return out
