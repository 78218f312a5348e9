"""Dense measurements from a raw EPICS camonitor stream: every reference sample, time-aligned.

An axis position PV (mm, e.g. ``TARGET_DU:X-PosAct``) and a reference PV (raw units, e.g. the
laser triangulation sensor ``IOC_TEST:ILD_DownSample``) are published at different times, each
stamped by its IOC. :func:`align_streams` turns them into one row per reference sample:

1. **Position at the reference's time.** The position stream is interpolated linearly between its
   samples. The motion is classified per position interval (between two position samples):
   *rest* (slower than ``rest_speed_mm_s``), *steady* (velocity constant
   within ``max_accel_mm_s2`` over the interval and its neighbours: linear interpolation is then
   exact) or *accelerating*. Accelerating samples are left out by default: there the linear
   interpolation errs by up to a·h²/8 and the carriage's start/stop dynamics (friction wind-up)
   are not a property of the position.
2. **Latency.** A timing offset τ between the streams makes an error v·τ that flips sign with the
   direction of travel, exactly like a reversal. τ is the lag that best matches the smoothed
   velocity of the reference (difference quotient over ``smooth_s``) with the position's velocity
   (least squares over the moving part, parabolic refinement); its uncertainty is the spread of
   the same estimate over time blocks. Convention: ``latency_s > 0`` means the reference's
   timestamps are late, so the position used for a reference sample stamped t is the one at t − τ.
3. **Linear map** of the raw reference onto the axis frame: ``ref_mm = gain·raw + offset``, the
   least-squares line over the kept samples (a preliminary fit over the rest samples serves the
   latency estimate). It removes the axis' linear error: the stage's *calibrated linear model*.
4. **Direction** ``dir`` = sign of the last non-zero velocity (samples before the first motion
   are unknown and dropped); **cycle** = the ISO 230-2 cycle of the test-number PV (each
   forward + backward pass, from :func:`.realdata.iso230_points_from_log`), or, without one, a
   new cycle at each start of a forward pass.

Alignment error of a sample: |v|·√(σ_ref² + σ_pos² + σ_τ²) (σ the timestamp jitter of each
stream, the latency's uncertainty), plus the interpolation bound |a|·h²/8.
Units: positions mm, errors µm, time s, velocity mm/s, acceleration mm/s².
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import RealDataError
from .realdata import PvSeries, iso230_points_from_log, read_camonitor_log

__all__ = [
    "AlignedStream",
    "StreamOptions",
    "align_streams",
    "import_camonitor",
    "reversal_um",
    "timestamp_jitter_s",
]

FloatArray = NDArray[np.float64]
Progress = Callable[[str], None]


@dataclass(frozen=True)
class StreamOptions:
    """How to align a camonitor stream (units in the names; defaults fit the ESS target run)."""

    position_pv: str
    reference_pv: str
    axis: str = "x"
    test_pv: str | None = "IOC_TEST:TestNumber"  # ISO 230-2 test number (cycles); None: motion
    command_pv: str | None = "TARGET_DU:X-PosCmd"  # commanded position (checks the direction)
    encoder_pv: str | None = None  # raw encoder counts used as position, mapped onto position_pv
    reference_scale: float | None = None  # fixed mm per raw unit (sign included); None: fitted
    rest_speed_mm_s: float = 1e-3
    max_accel_mm_s2: float = 0.01
    max_speed_mm_s: float | None = None
    keep_accelerating: bool = False
    max_lag_s: float = 1.0
    smooth_s: float = 2.0
    latency_s: float | None = None  # given instead of estimated


@dataclass(eq=False)
class AlignedStream:
    """The aligned samples (kept rows only) and how they were obtained.

    Arrays, one entry per kept reference sample: ``t_s`` (s since the log's first line, the
    reference's clock), ``indicated_mm`` (position at t − latency), ``reference_mm`` (mapped
    reference), ``direction`` (±1), ``cycle`` (1-based), ``velocity_mm_s``, ``accel_mm_s2``,
    ``state`` ("rest" | "steady" | "accelerating"), ``align_error_um`` (1σ timing part plus the
    interpolation bound) and ``indicated_nolag_mm`` (position at t, latency not corrected).
    """

    options: StreamOptions
    t_s: FloatArray
    indicated_mm: FloatArray
    reference_mm: FloatArray
    direction: NDArray[np.int64]
    cycle: NDArray[np.int64]
    velocity_mm_s: FloatArray
    accel_mm_s2: FloatArray
    state: NDArray[np.str_]
    align_error_um: FloatArray
    indicated_nolag_mm: FloatArray
    gain: float
    offset_mm: float
    latency_s: float
    latency_sigma_s: float
    latency_method: str
    latency_split_s: dict[str, float]
    jitter_s: dict[str, float]
    counts: dict[str, int]
    cycles_from: str
    notes: list[str] = field(default_factory=list)

    @property
    def error_um(self) -> FloatArray:
        """Observed error, µm: reference − indicated (true − indicated)."""
        return (self.reference_mm - self.indicated_mm) * 1000.0


def timestamp_jitter_s(time_s: FloatArray) -> float:
    """Timestamp jitter of a periodically sampled stream, s: std of (Δt − median Δt)/√2 over the
    regular intervals (0.5…1.5 × the median; gaps and bursts are left out). 0 for < 3 samples."""
    dt = np.diff(time_s)
    if dt.size < 2:
        return 0.0
    period = float(np.median(dt))
    ok = (dt > 0.5 * period) & (dt < 1.5 * period)
    if ok.sum() < 2:
        return float(np.std(dt) / math.sqrt(2.0))
    return float(np.std(dt[ok] - period) / math.sqrt(2.0))


def isolated_spikes(v: FloatArray) -> NDArray[np.bool_]:
    """Samples far from both neighbours while the neighbours agree (a transport glitch, a
    placeholder value): both steps beyond 100× the 90th percentile of the stream's steps (a
    fast move's step), the step across the sample within it. One such sample of 1e30 in the
    reference made the latency +847 ± 6 ms (truth 50) without a word."""
    out = np.zeros(v.size, dtype=bool)
    if v.size < 5:
        return out
    d = np.abs(np.diff(v))
    limit = 100.0 * float(np.quantile(d, 0.9))
    if not limit > 0.0:  # a constant stream: nothing to measure a spike against
        return out
    out[1:-1] = (d[:-1] > limit) & (d[1:] > limit) & (np.abs(v[2:] - v[:-2]) <= limit)
    return out


def _series(log: Mapping[str, PvSeries], pv: str, what: str) -> tuple[FloatArray, FloatArray, int]:
    """The PV's numeric samples (time, value) without non-finite ones and isolated spikes, and
    the number of spikes left out."""
    if pv not in log:
        raise RealDataError(f"{what} PV {pv!r} not in the log (it has: {', '.join(sorted(log))})")
    s = log[pv]
    ok = np.isfinite(s.value)
    t, v = s.time_s[ok], s.value[ok]
    spikes = isolated_spikes(v)
    t, v = t[~spikes], v[~spikes]
    if t.size < 3:
        raise RealDataError(f"{what} PV {pv!r} has {t.size} numeric sample(s); at least 3 needed")
    return t, v, int(spikes.sum())


@dataclass(frozen=True)
class _Motion:
    """Position samples and per-interval motion: velocity, acceleration, state, direction."""

    t: FloatArray
    x: FloatArray
    v: FloatArray  # (n-1,) interval velocity, mm/s
    a: FloatArray  # (n-1,) acceleration across the interval's neighbours, mm/s²
    rest: NDArray[np.bool_]
    steady: NDArray[np.bool_]
    direction: NDArray[np.int64]  # (n-1,) last non-zero direction up to this interval, 0 unknown

    def at(self, t: FloatArray) -> FloatArray:
        return np.interp(t, self.t, self.x)

    def interval(self, t: FloatArray) -> NDArray[np.intp]:
        """Index of the position interval holding each time (clipped to the ends)."""
        return np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, self.v.size - 1)


def _motion(t: FloatArray, x: FloatArray, opts: StreamOptions) -> _Motion:
    h = np.diff(t)
    keep = h > 0  # duplicate timestamps: keep the later value
    t = np.r_[t[:-1][keep], t[-1]]
    x = np.r_[x[:-1][keep], x[-1]]
    h = np.diff(t)
    v = np.diff(x) / h
    vp, vn = np.r_[v[0], v[:-1]], np.r_[v[1:], v[-1]]
    a = (vn - vp) / np.maximum(2.0 * h, 1e-9)
    slow = np.abs(v) <= opts.rest_speed_mm_s
    rest = slow  # both ends of the interval at one position: the stage stood still in between
    dv = np.maximum(np.abs(vn - v), np.abs(v - vp))
    steady = ~rest & (dv <= opts.max_accel_mm_s2 * h) & ~slow
    moving = np.where(slow, 0, np.sign(v)).astype(np.int64)
    idx = np.where(moving != 0, np.arange(moving.size), -1)
    last = np.maximum.accumulate(idx)
    direction = np.where(last >= 0, moving[np.clip(last, 0, None)], 0)
    return _Motion(t, x, v, a, rest, steady, direction)


def _lag_cost(
    tr: FloatArray,
    r_mm: FloatArray,
    t0: FloatArray,
    t1: FloatArray,
    vp: FloatArray,
    lags: FloatArray,
) -> FloatArray:
    """(lags, n) squared velocity mismatch, (mm/s)²: the position's velocity between its own
    samples t0 → t1 against the reference's over the same interval shifted by each lag. Only the
    densely sampled reference is interpolated (its error a·h²/8 is negligible at 10 Hz)."""
    out = np.empty((lags.size, t0.size))
    for k, lag in enumerate(lags):
        vr = (np.interp(t1 + lag, tr, r_mm) - np.interp(t0 + lag, tr, r_mm)) / (t1 - t0)
        with np.errstate(over="ignore"):  # a position glitch's velocity: an infinite mismatch
            out[k] = (vr - vp) ** 2
    return out


def _parabola_min(lags: FloatArray, cost: FloatArray) -> float:
    k = int(np.argmin(cost))
    if 0 < k < lags.size - 1:
        c0, c1, c2 = cost[k - 1], cost[k], cost[k + 1]
        den = c0 - 2.0 * c1 + c2
        if den > 0:
            return float(lags[k] + 0.5 * (c0 - c2) / den * (lags[1] - lags[0]))
    return float(lags[k])


def _estimate_latency(
    motion: _Motion,
    tr: FloatArray,
    r_mm: FloatArray,
    span: tuple[float, float],
    opts: StreamOptions,
) -> tuple[float, float, str, dict[str, float]]:
    """Lag (s) best matching the velocities within ``span`` (s), its 1σ uncertainty (s), the
    method's words and, for comparison, the same estimate on all moves and on the starts.

    The position's velocity is taken between its own samples ``smooth_s`` apart (no
    interpolation of the sparse stream); the reference is interpolated at those times + lag.
    """
    h = float(np.median(np.diff(motion.t)))
    m = max(1, round(0.5 * opts.smooth_s / h))
    n = motion.t.size
    j = np.arange(m, n - m)
    t0, t1 = motion.t[j - m], motion.t[j + m]
    moving = np.convolve(~motion.rest, np.ones(2 * m), "valid")[: j.size] > 0
    period = float(np.median(np.diff(tr)))
    lo, hi = max(tr[0], span[0]) + opts.max_lag_s, min(tr[-1], span[1]) - opts.max_lag_s
    gap = np.r_[np.diff(tr) > 2.5 * period, False]

    def in_gap(t: FloatArray) -> NDArray[np.bool_]:
        return gap[np.clip(np.searchsorted(tr, t, side="right") - 1, 0, tr.size - 1)]

    # a window holding a reversal holds the backlash take-up: the carriage starts late there
    dirs = np.lib.stride_tricks.sliding_window_view(motion.direction, 2 * m)[: j.size]
    same_dir = dirs.min(axis=1) == dirs.max(axis=1)
    ok = moving & same_dir & (t0 >= lo) & (t1 <= hi) & ~in_gap(t0) & ~in_gap(t1)
    j, t0, t1 = j[ok], t0[ok], t1[ok]
    av = motion.a[j] * motion.v[j]
    stops = av < 0
    if stops.sum() < 10:
        raise RealDataError(
            "the stage hardly moves while the reference is recorded: the latency between the "
            "streams cannot be estimated (give it with --latency)"
        )
    vp = (motion.x[j + m] - motion.x[j - m]) / (t1 - t0)
    step = max(period / 2.0, 1e-3)
    coarse = np.arange(-opts.max_lag_s, opts.max_lag_s + 1e-12, step)
    c_cost = _lag_cost(tr, r_mm, t0[stops], t1[stops], vp[stops], coarse).mean(axis=1)
    centre = float(coarse[int(np.argmin(c_cost))])
    fine = centre + np.linspace(-step, step, 41)
    f_cost = _lag_cost(tr, r_mm, t0, t1, vp, fine)
    best = _parabola_min(fine, f_cost[:, stops].mean(axis=1))
    blocks = np.array_split(np.flatnonzero(stops), 8)
    per_block = [_parabola_min(fine, f_cost[:, b].mean(axis=1)) for b in blocks if b.size > 3]
    if len(per_block) < 2:  # its spread is the 1σ: one block has none (was NaN in summary.json)
        raise RealDataError(
            f"the stage decelerates in only {int(stops.sum())} position samples: too few to "
            "estimate the latency between the streams and its uncertainty (at least 2 time "
            "blocks of 4 are needed; give it with --latency)"
        )
    statistical = float(np.std(per_block, ddof=1) / math.sqrt(len(per_block)))
    split = {"all_moves": _parabola_min(fine, f_cost.mean(axis=1)), "statistical": statistical}
    # model dependence (a positional error or friction also shifts the ramps) counts in the 1σ
    sigma = math.hypot(statistical, split["all_moves"] - best)
    if (av > 0).sum() > 5:
        split["starts"] = _parabola_min(fine, f_cost[:, av > 0].mean(axis=1))
    words = (
        f"lag minimising the mean squared difference between the position's velocity over "
        f"{2 * m * h:g} s (between its own samples) and the reference's over the same interval "
        f"shifted by the lag, on the decelerations ({int(stops.sum())} position samples; "
        f"starts carry the carriage's breakaway delay, reversals the backlash take-up); ±1σ "
        f"from {len(per_block)} time blocks combined with the difference to the estimate on "
        "all moves"
    )
    return best, sigma, words, split


def _fit_map(raw: FloatArray, x: FloatArray, scale: float | None) -> tuple[float, float]:
    """Least-squares ``x ≈ gain·raw + offset`` (gain fixed when ``scale`` is given)."""
    if scale is not None:
        return float(scale), float(np.mean(x - scale * raw))
    if np.ptp(x) <= 0:
        raise RealDataError("the axis does not move in the log: no linear map can be fitted")
    if np.ptp(raw) <= 0:
        raise RealDataError(
            "the reference does not change with the position: no linear map can be fitted "
            "(is the reference PV right?)"
        )
    gain, offset = np.polyfit(raw, x, 1)
    return float(gain), float(offset)


def _has_test_numbers(log: Mapping[str, PvSeries], opts: StreamOptions) -> bool:
    """Whether the cycles come from ISO 230-2 test numbers (else from the motion)."""
    return bool(opts.test_pv and opts.command_pv and opts.test_pv in log and opts.command_pv in log)


def _cycles(
    log: Mapping[str, PvSeries], opts: StreamOptions, t: FloatArray, direction: NDArray[np.int64]
) -> tuple[NDArray[np.int64], str]:
    """Cycle of each sample (1-based, 0 = outside the test) and where the cycles came from."""
    if _has_test_numbers(log, opts) and opts.test_pv and opts.command_pv:
        points = iso230_points_from_log(
            log, opts.test_pv, opts.command_pv, opts.reference_pv, opts.position_pv
        )
        tp = np.array([p.time_s for p in points])
        cyc = np.array([p.cycle for p in points])
        order = np.argsort(tp, kind="stable")
        tp, cyc = tp[order], cyc[order]
        k = np.searchsorted(tp, t, side="left")
        out = np.where(k < tp.size, cyc[np.clip(k, 0, tp.size - 1)], 0)
        return out.astype(np.int64), f"ISO 230-2 test numbers ({opts.test_pv})"
    starts_fwd = (direction == 1) & (np.r_[0, direction[:-1]] == -1)
    cyc = 1 + np.cumsum(starts_fwd)
    return np.where(direction != 0, cyc, 0).astype(
        np.int64
    ), "motion (a new cycle at each start of a forward pass)"


def _read_streams(
    log: Mapping[str, PvSeries], opts: StreamOptions
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, dict[str, float], list[str]]:
    """The reference (times s, raw values) and position (times s, mm) streams, isolated spikes
    left out; the position from the encoder PV when one is given (its counts mapped onto the
    position PV at rest); the timestamp jitter of each (s) and notes for the report."""
    tr, raw, ref_spikes = _series(log, opts.reference_pv, "reference")
    tp, xp, pos_spikes = _series(log, opts.position_pv, "position")
    notes: list[str] = []
    for n, pv in ((ref_spikes, opts.reference_pv), (pos_spikes, opts.position_pv)):
        if n:
            notes.append(f"{pv}: {n} isolated spike(s) left out (far from both neighbours)")
    jitter = {"reference": timestamp_jitter_s(tr), "position": timestamp_jitter_s(tp)}
    if opts.encoder_pv:
        te, enc_counts, enc_spikes = _series(log, opts.encoder_pv, "encoder")
        if enc_spikes:
            notes.append(f"{opts.encoder_pv}: {enc_spikes} isolated spike(s) left out")
        jitter["encoder"] = timestamp_jitter_s(te)
        at_pos = np.interp(tp, te, enc_counts)
        slow = np.abs(np.gradient(xp, tp)) <= opts.rest_speed_mm_s
        g, o = _fit_map(
            at_pos[slow] if slow.sum() > 2 else at_pos, xp[slow] if slow.sum() > 2 else xp, None
        )
        notes.append(
            f"encoder {opts.encoder_pv} mapped onto {opts.position_pv}: {g:.6e} mm/count, {o:+.6f} mm"
        )
        tp, xp = te, g * enc_counts + o
        jitter["position"] = jitter.pop("encoder")
    return tr, raw, tp, xp, jitter, notes


def _kept(
    inside: NDArray[np.bool_],
    direction: NDArray[np.int64],
    cycle: NDArray[np.int64],
    state: NDArray[np.str_],
    v: FloatArray,
    opts: StreamOptions,
) -> tuple[NDArray[np.bool_], dict[str, int]]:
    """The reference samples kept (within the position stream, a known direction, a cycle of
    the test, not accelerating and not too fast unless asked) and how many went where."""
    keep = inside & (direction != 0) & (cycle > 0)
    counts = {
        "reference_samples": int(inside.size),
        "outside_position_stream": int((~inside).sum()),
        "direction_unknown": int((inside & (direction == 0)).sum()),
        "outside_cycles": int((inside & (direction != 0) & (cycle == 0)).sum()),
    }
    if not opts.keep_accelerating:
        counts["accelerating"] = int((keep & (state == "accelerating")).sum())
        keep &= state != "accelerating"
    if opts.max_speed_mm_s is not None:
        counts["too_fast"] = int((keep & (np.abs(v) > opts.max_speed_mm_s)).sum())
        keep &= np.abs(v) <= opts.max_speed_mm_s
    return keep, counts


def _enough_kept(
    keep: NDArray[np.bool_], counts: dict[str, int], latency: str, opts: StreamOptions
) -> None:
    """Raise a RealDataError naming why when fewer than 3 reference samples are kept."""
    if int(keep.sum()) < 3:
        why = ", ".join(f"{k.replace('_', ' ')} {n}" for k, n in counts.items() if n)
        raise RealDataError(
            f"no reference sample is left to keep after aligning the streams with a latency of "
            f"{latency}: {why}; check that {opts.position_pv} is the axis position and "
            f"{opts.reference_pv} the reference, or give --latency"
        )


def align_streams(
    log: Mapping[str, PvSeries], opts: StreamOptions, progress: Progress | None = None
) -> AlignedStream:
    """Align the position and reference streams of ``log`` (see the module docstring).

    Raises:
        RealDataError: a PV is missing or has too few samples, the streams do not overlap, the
            reference does not follow the position, or no sample is left to keep.
    """
    say = progress or (lambda _msg: None)
    tr, raw, tp, xp, jitter, notes = _read_streams(log, opts)
    lo, hi = max(tr[0], tp[0], 0.0), min(tr[-1], tp[-1])
    if hi <= lo:
        raise RealDataError(
            f"the position ({opts.position_pv}) and reference ({opts.reference_pv}) streams "
            "do not overlap in time"
        )
    motion = _motion(tp, xp, opts)
    say(f"aligning {tr.size} reference samples with {tp.size} position samples")
    inside = (tr >= lo) & (tr <= hi)
    at_rest = inside & motion.rest[motion.interval(tr)]
    if at_rest.sum() >= 3 and np.ptp(motion.at(tr[at_rest])) > 0:
        g0, o0 = _fit_map(raw[at_rest], motion.at(tr[at_rest]), opts.reference_scale)
    else:
        g0, o0 = _fit_map(raw[inside], motion.at(tr[inside]), opts.reference_scale)
    cycle, cycles_from = _cycles(log, opts, tr, motion.direction[motion.interval(tr)])
    in_test = tr[cycle > 0]
    if in_test.size < 3:
        raise RealDataError("no reference sample lies within a cycle of the test")
    split: dict[str, float] = {}
    if opts.latency_s is not None:
        latency, sigma, method = float(opts.latency_s), 0.0, "given (--latency)"
    else:
        say("estimating the latency between the streams")
        span = (float(in_test[0]), float(in_test[-1]))
        latency, sigma, method, split = _estimate_latency(motion, tr, g0 * raw + o0, span, opts)
    tq = tr - latency
    inside = (tq >= motion.t[0]) & (tq <= motion.t[-1]) & (tr >= 0.0)
    k = motion.interval(tq)
    state = np.where(motion.rest[k], "rest", np.where(motion.steady[k], "steady", "accelerating"))
    direction = motion.direction[k]
    if not _has_test_numbers(log, opts):  # the motion's cycles, with the aligned directions
        cycle, cycles_from = _cycles(log, opts, tr, direction)
    v, a = np.where(motion.rest[k], 0.0, motion.v[k]), motion.a[k]
    keep, counts = _kept(inside, direction, cycle, state, v, opts)
    _enough_kept(keep, counts, f"{latency * 1000:.1f} ms ({method})", opts)
    x = motion.at(tq[keep])
    gain, offset = _fit_map(raw[keep], x, opts.reference_scale)
    h = float(np.median(np.diff(motion.t)))
    sig_t = math.sqrt(jitter["reference"] ** 2 + jitter["position"] ** 2 + sigma**2)
    align = (np.abs(v[keep]) * sig_t + np.abs(a[keep]) * h * h / 8.0) * 1000.0
    counts["kept"] = int(keep.sum())
    for s in ("rest", "steady", "accelerating"):
        counts[f"kept_{s}"] = int((state[keep] == s).sum())
    return AlignedStream(
        options=opts,
        t_s=tr[keep],
        indicated_mm=x,
        reference_mm=gain * raw[keep] + offset,
        direction=direction[keep],
        cycle=cycle[keep],
        velocity_mm_s=v[keep],
        accel_mm_s2=a[keep],
        state=state[keep],
        align_error_um=align,
        indicated_nolag_mm=motion.at(tr[keep]),
        gain=gain,
        offset_mm=offset,
        latency_s=latency,
        latency_sigma_s=sigma,
        latency_method=method,
        latency_split_s=split,
        jitter_s=jitter,
        counts=counts,
        cycles_from=cycles_from,
        notes=notes,
    )


def import_camonitor(
    path: str | Path, opts: StreamOptions, progress: Progress | None = None
) -> AlignedStream:
    """Read the camonitor log at ``path`` and align its streams (:func:`align_streams`)."""
    if progress is not None:
        size = Path(path).stat().st_size if Path(path).is_file() else 0
        progress(f"reading {path} ({size / 1e6:.1f} MB)")
    log = read_camonitor_log(path)
    return align_streams(log, opts, progress)


def reversal_um(
    x_mm: FloatArray, err_um: FloatArray, direction: NDArray[np.int64], bin_mm: float = 1.0
) -> dict[str, Any]:
    """Reversal (mean error after + minus after − approach), µm, binned along the axis.

    The mean over ``bin_mm`` bins holding both directions of (mean error +) − (mean error −);
    ``None`` when no bin holds both. Returns ``{"reversal_um", "bins", "spread_um"}``.
    """
    b = np.rint(x_mm / bin_mm).astype(np.int64)
    diffs = []
    for key in np.unique(b):
        m = b == key
        fwd, bwd = err_um[m & (direction > 0)], err_um[m & (direction < 0)]
        if fwd.size and bwd.size:
            diffs.append(float(fwd.mean() - bwd.mean()))
    if not diffs:
        return {"reversal_um": None, "bins": 0, "spread_um": None}
    d = np.array(diffs)
    return {"reversal_um": float(d.mean()), "bins": int(d.size), "spread_um": float(d.std())}
