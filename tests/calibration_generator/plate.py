"""A ball plate (``plate.toml`` + ``plate.csv``), measured in placements of unknown pose.

Physics: the plate's balls sit at true centres ``b`` in the plate frame (u, v in the plate's plane,
w its normal). The calibration certificate gives centres that differ from the true ones by the
certificate's own error, N(0, u_um) per coordinate (the reference is imperfect, as a real one is).
A placement puts the plate at a rigid pose (R, t) in the machine's workpiece frame: a nominal
plane (XY, XZ or YZ) and orientation (0°, 90°, 180° or 270° about the normal), a misalignment of
up to ~1° about each axis and a shift of up to ±20 mm, unknown to the identification.

Measuring ball i means finding the indicated position q whose true stylus-tip position is the
placed centre: ``q + e(q, stylus)/1000 = R·b_i + t`` (solved by fixed-point iteration, the error
being µm on mm positions). A ball centre is fitted from points probed all around the ball, so the
machine's reversal shifts opposite points oppositely and cancels in the centre; what remains is
the probing error, white N(0, probe_um) per coordinate.

Units: mm, µm; the plate frame in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .machine import TrueMachine

FloatArray = NDArray[np.float64]

#: plane → columns (u, v, w) of the nominal rotation plate frame → machine frame
PLANE_FRAMES = {
    "XY": np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    "XZ": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
    "YZ": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
}
PLANE_AXES = {"XY": (0, 1, 2), "XZ": (0, 2, 1), "YZ": (1, 2, 0)}  # in-plane a, b; normal
PLATE_PLANS = ("full_reach", "reach_limited")


@dataclass(frozen=True)
class PlateDesign:
    """Balls per side, the largest plate, the placements' planes and orientations, the plan.

    ``plan`` is how the placements are laid out along each in-plane axis:

    * ``"full_reach"`` (the PTB ball-plate practice): as many positions as it takes for the
      ball centres to reach within ``reach_margin`` × travel of both ends of the axis (5 % of
      the travel left unreached at most), neighbours overlapping by ``overlap`` × side; the
      end positions are pushed against the ends (their misalignment kept, their shift bounded
      so that the end ball stays within the margin);
    * ``"reach_limited"``: the middle of the axis, or (``tile``) two positions when the axis is
      at least 1.8 plate sides long — the ball centres then span 60–99 % of an axis and the
      rest is reached by no plate (kept to measure what a plan short of the ends costs).
    """

    def __post_init__(self) -> None:
        if self.plan not in PLATE_PLANS:
            raise ValueError(f"unknown plate plan {self.plan!r}; allowed: {PLATE_PLANS}")

    balls_per_side: int = 5
    max_side_mm: float = 800.0
    planes: tuple[str, ...] = ("XY", "XZ", "YZ")
    orientations_deg: tuple[float, ...] = (0.0, 90.0)
    #: "full_reach" (default, the lab's plan: the balls reach the ends of every in-plane axis)
    #: or "reach_limited" (the former plan: the middle, or two positions on long axes only)
    plan: str = "full_reach"
    reach_margin: float = 0.025  # full_reach: the most of an axis' travel left at either end
    overlap: float = 0.1  # full_reach: the least overlap of neighbouring positions, of the side
    tile: bool = True  # reach_limited: two positions along an axis ≥ 1.8 plate sides
    probe_um: float = 0.30
    certificate_um: tuple[float, float] = (0.2, 0.5)  # u of the calibrated centres, drawn


@dataclass
class Plate:
    """The plate: ids, certificate centres (mm), their u (µm) and the true centres (mm)."""

    ids: list[int]
    calibrated_mm: FloatArray
    u_um: FloatArray
    true_mm: FloatArray
    side_mm: float


@dataclass
class Placement:
    """A placement: plate-to-machine rotation, translation (mm), plane and orientation."""

    rotation: FloatArray
    translation_mm: FloatArray
    plane: str
    orientation_deg: float


def random_plate(rng: np.random.Generator, side_mm: float, design: PlateDesign) -> Plate:
    """An n × n plate of the given side: nominal grid + manufacturing deviations."""
    n = design.balls_per_side
    g = np.linspace(0.0, side_mm, n)
    uu, vv = np.meshgrid(g, g, indexing="ij")
    nominal = np.stack([uu.ravel(), vv.ravel(), np.zeros(n * n)], axis=1)
    made = nominal + rng.normal(0.0, 0.02, nominal.shape)  # as made: ±20 µm off the drawing
    calibrated = np.round(made, 5)  # the certificate: 0.01 µm digits
    u_um = np.round(rng.uniform(*design.certificate_um, n * n), 2)
    true = calibrated + rng.normal(0.0, 1.0, nominal.shape) * u_um[:, None] / 1000.0
    ids = [int(i) for i in rng.permutation(np.arange(1, n * n + 1))]
    return Plate(ids=ids, calibrated_mm=calibrated, u_um=u_um, true_mm=true, side_mm=side_mm)


def _small_rotation(rng: np.random.Generator, max_deg: float) -> FloatArray:
    a = np.deg2rad(rng.uniform(-max_deg, max_deg, 3))
    cx, sx, cy, sy, cz, sz = (
        np.cos(a[0]),
        np.sin(a[0]),
        np.cos(a[1]),
        np.sin(a[1]),
        np.cos(a[2]),
        np.sin(a[2]),
    )
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rx @ ry @ rz


def plate_side_mm(machine: TrueMachine, design: PlateDesign) -> float:
    """The plate's side: 80 % of the shortest in-plane travel of the planes used, capped."""
    span = machine.upper_mm - machine.lower_mm
    shortest = min(min(span[PLANE_AXES[p][0]], span[PLANE_AXES[p][1]]) for p in design.planes)
    return float(np.floor(min(0.8 * shortest, design.max_side_mm) / 10.0) * 10.0)


def _centres(lo: float, hi: float, side: float, tile: bool) -> list[float]:
    """reach_limited: plate-centre coordinates along one in-plane axis: the middle, or two
    positions when the axis is long."""
    if not tile or hi - lo < 1.8 * side:
        return [(lo + hi) / 2.0]
    return [lo + 0.55 * side, hi - 0.55 * side]


def _reach_positions(
    lo: float, hi: float, side: float, design: PlateDesign
) -> list[tuple[float, str]]:
    """full_reach: (plate-centre coordinate, which end it must reach: "lo", "hi", "both" or
    "") along one in-plane axis (mm): enough positions, evenly spaced, for the ball centres to
    reach within ``reach_margin`` of both ends, neighbours overlapping by ``overlap`` × side."""
    margin = design.reach_margin * (hi - lo)
    usable = hi - lo - 2.0 * margin
    if side >= usable + 1.0:  # one position reaches both ends (1 mm: a 1° tilt's shortening)
        return [((lo + hi) / 2.0, "both")]
    n = 1 + int(np.ceil((usable - side) / ((1.0 - design.overlap) * side) - 1e-9))
    first, last = lo + margin / 2.0 + side / 2.0, hi - margin / 2.0 - side / 2.0
    ends = ["lo"] + [""] * (n - 2) + ["hi"]
    return list(zip(np.linspace(first, last, n).tolist(), ends, strict=True))


def _axis_positions(
    lo: float, hi: float, side: float, design: PlateDesign
) -> list[tuple[float, str]]:
    if design.plan == "reach_limited":
        return [(c, "") for c in _centres(lo, hi, side, design.tile)]
    return _reach_positions(lo, hi, side, design)


def _shift_to_reach(
    ends_mm: FloatArray, lo: float, hi: float, anchor: str, margin_mm: float
) -> float | None:
    """The smallest shift (mm) along one axis that keeps the plate's corners ``ends_mm`` inside
    [lo + 1, hi − 1] and, for an end position, its end ball within ``margin_mm`` of that end;
    None when impossible (draw again)."""
    low, high = lo + 1.0 - ends_mm.min(), hi - 1.0 - ends_mm.max()
    if anchor in ("lo", "both"):
        high = min(high, lo + margin_mm - ends_mm.min())
    if anchor in ("hi", "both"):
        low = max(low, hi - margin_mm - ends_mm.max())
    if low > high:
        return None
    return float(np.clip(0.0, low, high))


def placements(
    rng: np.random.Generator, machine: TrueMachine, side_mm: float, design: PlateDesign
) -> list[Placement]:
    """Placements of every plane × position (:class:`PlateDesign` ``plan``) × orientation, each
    with a random misalignment."""
    lo, hi = machine.lower_mm, machine.upper_mm
    out: list[Placement] = []
    for plane in design.planes:
        a, b, _ = PLANE_AXES[plane]
        for ca, end_a in _axis_positions(lo[a], hi[a], side_mm, design):
            for cb, end_b in _axis_positions(lo[b], hi[b], side_mm, design):
                for deg in design.orientations_deg:
                    target = {a: (ca, end_a), b: (cb, end_b)}
                    out.append(_one_placement(rng, machine, side_mm, design, plane, deg, target))
    return out


def _one_placement(
    rng: np.random.Generator,
    machine: TrueMachine,
    side_mm: float,
    design: PlateDesign,
    plane: str,
    deg: float,
    target: dict[int, tuple[float, str]],
) -> Placement:
    """One placement: nominal plane and orientation, in-plane centre ``target[axis][0]``, a
    random misalignment (≤ 1° per axis, ±20 mm); an end position (``target[axis][1]``) shifted
    back so that its end ball stays within the plan's margin of that end."""
    lo, hi = machine.lower_mm, machine.upper_mm
    w = PLANE_AXES[plane][2]
    centre_plate = np.array([side_mm / 2.0, side_mm / 2.0, 0.0])
    corners = np.array([[0, 0, 0], [side_mm, side_mm, 0], [side_mm, 0, 0], [0, side_mm, 0]]).T
    for _ in range(100):
        th = np.deg2rad(deg)
        rz = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
        rot = _small_rotation(rng, 1.0) @ PLANE_FRAMES[plane] @ rz
        centre = np.empty(3)
        for k, (c, _) in target.items():
            centre[k] = c
        depth = 0.15 if plane == "XY" else 0.5  # XY: low on the table
        centre[w] = lo[w] + rng.uniform(depth - 0.1, depth + 0.1) * (hi[w] - lo[w])
        centre += rng.uniform(-20.0, 20.0, 3)
        t = centre - rot @ centre_plate
        if design.plan == "full_reach":
            for k, (_, anchor) in target.items():
                margin = design.reach_margin * (hi[k] - lo[k])
                shift = _shift_to_reach((rot @ corners)[k] + t[k], lo[k], hi[k], anchor, margin)
                if shift is None:
                    break
                t[k] += shift
        ends = (rot @ corners).T + t
        if np.all(ends >= lo + 1.0) and np.all(ends <= hi - 1.0):
            return Placement(rot, t, plane, deg)
    raise RuntimeError(f"a {side_mm} mm plate does not fit the {plane} plane")


def indicated_for_true(
    machine: TrueMachine, true_mm: FloatArray, stylus_mm: FloatArray
) -> FloatArray:
    """Indicated positions whose true tip positions are ``true_mm`` (fixed point, exact)."""
    q = np.array(true_mm, dtype=float)
    for _ in range(6):
        q = true_mm - machine.error_um(q, stylus_mm) / 1000.0
    return q


def measure_placement(
    machine: TrueMachine,
    rng: np.random.Generator,
    plate: Plate,
    placement: Placement,
    stylus_mm: FloatArray,
    probe_um: float,
) -> FloatArray:
    """Measured centres (n, 3) mm, indicated machine coordinates, in the plate's ball order."""
    placed = (placement.rotation @ plate.true_mm.T).T + placement.translation_mm
    q = indicated_for_true(machine, placed, stylus_mm)
    return q + rng.normal(0.0, probe_um / 1000.0, q.shape)


def plate_toml(plate: Plate, note: str = "") -> str:
    """``plate.toml`` text: one ``[[ball]]`` per ball, certificate centres and u."""
    lines = [f"# ball plate certificate {note}".rstrip(), f"# {len(plate.ids)} balls", ""]
    order = np.argsort(plate.ids)
    for i in order:
        u, v, w = plate.calibrated_mm[i]
        lines += [
            "[[ball]]",
            f"id = {plate.ids[i]}",
            f"u_mm = {u:.5f}",
            f"v_mm = {v:.5f}",
            f"w_mm = {w:.5f}",
            f"u_um = {plate.u_um[i]:.2f}",
            "",
        ]
    return "\n".join(lines)
