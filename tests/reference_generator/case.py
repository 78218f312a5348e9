"""One simulated session: draw, simulate the two instruments, label the truth.

The forward model, per reference sample stamped t (s):

* the axis reads q(t) (its encoder: the commanded trapezoidal motion, :mod:`.motion`);
* the reference took the sample at t − τ (τ the latency, > 0: its timestamps are late), when the
  carriage truly stood at x(t − τ) = q(t − τ) + Σ machine errors(q, d, t − τ) + machine noise;
* the reference reads r = x + Σ reference errors(x, t − τ) + its noise + a fixed offset, rounded
  to its resolution; the observed error is (r − q(t))·1000 µm (docs/formats.md §2);
* the machine's description may hold a calibrated linear positional error c0 + c1·q (µm), which
  the carriage then also carries (it is in the model, not hidden).

Rows taken while the axis accelerates are left out (as ``cmm-comp import camonitor`` does by
default), and so are the rows of a one-directional session's unrecorded return.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .design import DesignError, SessionDesign, draw_design
from .families import DRAFTS, VARIANTS, Redraw, mode_of
from .machine_effects import MACHINE_EFFECTS, Reversal
from .noise import Noise, draw_noise
from .reference_effects import REFERENCE_EFFECTS, Latency
from .truth import Hidden, SamplePoints, SessionFacts, truth_labels

FloatArray = NDArray[np.float64]
REDRAWS = 40


class UnreachableCase(RuntimeError):
    """No session could carry the family's effects after many draws."""


@dataclass
class Case:
    """A session, its hidden effects and what a correct diagnosis names."""

    family: str
    variant: str
    seed: int
    design: SessionDesign
    noise: Noise
    effects: list[object]
    offset_um: float
    calibrated_um: tuple[float, float]  # (c0 µm, c1 µm/mm) in the description
    t_s: FloatArray
    indicated_mm: FloatArray
    reference_mm: FloatArray
    velocity_mm_s: FloatArray
    direction: FloatArray
    state: NDArray[np.str_]
    group: NDArray[np.str_]
    parts_um: dict[str, FloatArray]  # each effect's contribution at the rows (µm), for tests
    hidden: list[Hidden]
    nothing: list[str]
    redraws: int = 0
    meta: dict[str, object] = field(default_factory=dict)

    @property
    def axis(self) -> str:
        return self.design.axis

    @property
    def n(self) -> int:
        return int(self.t_s.size)

    @property
    def observed_error_um(self) -> FloatArray:
        return (self.reference_mm - self.indicated_mm) * 1000.0

    @property
    def case_id(self) -> str:
        return f"{self.family}/{self.variant}/s{self.seed}"

    @property
    def latency_s(self) -> float:
        return sum(e.latency_s for e in self.effects if isinstance(e, Latency))

    def describe(self) -> dict[str, object]:
        return {
            "case": self.case_id,
            "rows": self.n,
            "design": self.design.describe(),
            "noise": self.noise.describe(),
            "effects": [e.describe() for e in self.effects],  # type: ignore[attr-defined]
            "offset_um": round(self.offset_um, 3),
            "calibrated_linear_um": [round(v, 6) for v in self.calibrated_um],
            "hidden": [h.as_dict() for h in self.hidden],
            "nothing": self.nothing,
            "redraws": self.redraws,
        }


def case_rng(family: str, variant: str, seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(f"{family}|{variant}".encode())])


def _sample_times(d: SessionDesign, rng: np.random.Generator) -> FloatArray:
    """The reference's clock: one sample every 1/rate s, with a little timestamp jitter."""
    n = int(np.floor((d.profile.t_end - d.plan.t_start) * d.rate_hz))
    t = d.plan.t_start + np.arange(n) / d.rate_hz
    return t + rng.normal(0.0, 0.002 / d.rate_hz, n)


def _kept(d: SessionDesign, t: FloatArray) -> tuple[NDArray[np.bool_], NDArray[np.str_]]:
    _, v, direc, acc = d.profile.evaluate(t)
    rec, _ = d.profile.sample_info(t)
    rest = (v == 0.0) & (acc == 0.0)
    steady = (v != 0.0) & (acc == 0.0)
    keep = rec & (steady | (rest & d.rest_recorded))
    if d.plan.mode != "bidirectional":
        keep &= direc == d.plan.sense
    state = np.where(rest, "rest", np.where(steady, "steady", "accelerating"))
    return keep, state


def simulate(
    d: SessionDesign,
    effects: list[object],
    noise: Noise,
    rng: np.random.Generator,
    offset_um: float,
    calibrated_um: tuple[float, float],
) -> dict[str, object]:
    """The rows of the session (see the module's docstring), each effect's part (µm), and for the
    truth's separability rule the axis' position and last direction at each sample instant
    (``sample_q_mm``, ``sample_direction``: the latency's own shift left out)."""
    t_all = _sample_times(d, rng)
    keep, state = _kept(d, t_all)
    t = t_all[keep]
    q, v, direc, _ = d.profile.evaluate(t)
    _, group = d.profile.sample_info(t)
    tau = sum(e.latency_s for e in effects if isinstance(e, Latency))
    ts = t - tau
    qs, _, ds, _ = d.profile.evaluate(ts)
    parts: dict[str, FloatArray] = {}
    machine = (calibrated_um[0] + calibrated_um[1] * qs).astype(float)
    for e in effects:
        if isinstance(e, MACHINE_EFFECTS):
            part = e.error_um(qs, ds, ts)
            parts[e.family] = parts.get(e.family, 0.0) + part
            machine = machine + part
    x_true = qs + (machine + noise.machine_um(rng, t.size)) / 1000.0
    reading = x_true.copy()
    for e in effects:
        if isinstance(e, REFERENCE_EFFECTS):
            part = e.error_um(x_true, ts)
            parts[e.family] = parts.get(e.family, 0.0) + part
            reading = reading + part / 1000.0
    reading += (noise.reference_um(rng, ts) + offset_um) / 1000.0
    res_mm = noise.resolution_um / 1000.0
    reading = np.round(reading / res_mm) * res_mm
    if tau:
        parts["latency"] = (qs - q) * 1000.0
    return {
        "t_s": t,
        "indicated_mm": q,
        "reference_mm": reading,
        "velocity_mm_s": v,
        "direction": direc,
        "state": state[keep],
        "group": group,
        "parts_um": parts,
        "sample_q_mm": qs,
        "sample_direction": ds,
    }


def session_facts(
    d: SessionDesign, effects: list[object], rows: dict[str, object], offset_um: float
) -> SessionFacts:
    """What the truth rules need, measured on the written rows."""
    state = np.asarray(rows["state"])
    speeds = np.abs(np.asarray(rows["velocity_mm_s"]))[state == "steady"]
    distinct = np.unique(np.round(np.log(speeds), 2)) if speeds.size else np.array([])
    reversal = sum(abs(e.reversal_um) for e in effects if isinstance(e, Reversal))
    ref = np.asarray(rows["reference_mm"]) - offset_um / 1000.0
    return SessionFacts(
        axis=d.axis,
        bidirectional=bool(np.unique(np.asarray(rows["direction"])).size == 2),
        rest_rows=int(np.sum(state == "rest")),
        n_speeds=int(distinct.size),
        reversal_um=float(reversal),
        ref_centre_mm=float(0.5 * (np.min(ref) + np.max(ref))),
    )


def draw_case(family: str, variant: str, seed: int) -> Case:
    """The session ``family``/``variant`` number ``seed`` (deterministic)."""
    if family not in VARIANTS:
        raise ValueError(f"unknown family {family!r}; known: {', '.join(VARIANTS)}")
    if variant not in VARIANTS[family]:
        raise ValueError(f"{family}: unknown variant {variant!r}; known: {VARIANTS[family]}")
    rng = case_rng(family, variant, seed)
    noise = draw_noise(rng)
    for attempt in range(REDRAWS):
        draft = DRAFTS[family](variant, rng, noise.total_sigma_um)
        try:
            design = draw_design(rng, draft.constraints)
            effects = draft.build(design, rng)
        except (DesignError, Redraw):
            continue
        offset = float(rng.uniform(-50.0, 50.0))
        calibrated = (0.0, 0.0)
        if rng.random() < 0.5:
            calibrated = (float(rng.uniform(-5, 5)), float(rng.uniform(-0.2, 0.2) * _sgn(rng)))
        rows = simulate(design, effects, noise, rng, offset, calibrated)
        facts = session_facts(design, effects, rows, offset)
        if mode_of(variant) == "bidirectional" and not facts.bidirectional:
            continue
        q_s = np.asarray(rows.pop("sample_q_mm"), dtype=float)
        parts = rows["parts_um"]
        assert isinstance(parts, dict)
        step_um = parts.get("reversal", np.zeros_like(q_s))  # the reversal's ±r/2, signed
        points = SamplePoints(
            q_s,
            q_s + np.asarray(step_um, dtype=float) / 1000.0,
            np.asarray(rows.pop("sample_direction"), dtype=float),
            noise.total_sigma_um,
            np.asarray(rows["t_s"], dtype=float),
        )
        hidden, nothing = truth_labels(effects, facts, points)
        return Case(
            family=family,
            variant=variant,
            seed=seed,
            design=design,
            noise=noise,
            effects=effects,
            offset_um=offset,
            calibrated_um=calibrated,
            hidden=hidden,
            nothing=nothing,
            redraws=attempt,
            meta={"facts": facts.__dict__},
            **rows,  # type: ignore[arg-type]
        )
    raise UnreachableCase(f"{family}/{variant} seed {seed}: no session in {REDRAWS} draws")


def _sgn(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0
