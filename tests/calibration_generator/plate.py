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


@dataclass(frozen=True)
class PlateDesign:
    """Balls per side, the largest plate, the placements' planes and orientations."""

    balls_per_side: int = 5
    max_side_mm: float = 800.0
    planes: tuple[str, ...] = ("XY", "XZ", "YZ")
    orientations_deg: tuple[float, ...] = (0.0, 90.0)
    tile: bool = True  # more positions along an axis much longer than the plate
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
    """Plate-centre coordinates along one in-plane axis: the middle, or two ends when long."""
    if not tile or hi - lo < 1.8 * side:
        return [(lo + hi) / 2.0]
    return [lo + 0.55 * side, hi - 0.55 * side]


def placements(
    rng: np.random.Generator, machine: TrueMachine, side_mm: float, design: PlateDesign
) -> list[Placement]:
    """Placements of every plane × orientation (× tiles), each with a random misalignment."""
    lo, hi = machine.lower_mm, machine.upper_mm
    out: list[Placement] = []
    centre_plate = np.array([side_mm / 2.0, side_mm / 2.0, 0.0])
    for plane in design.planes:
        a, b, w = PLANE_AXES[plane]
        for ca in _centres(lo[a], hi[a], side_mm, design.tile):
            for cb in _centres(lo[b], hi[b], side_mm, design.tile):
                for deg in design.orientations_deg:
                    for _ in range(100):
                        th = np.deg2rad(deg)
                        rz = np.array(
                            [[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]]
                        )
                        rot = _small_rotation(rng, 1.0) @ PLANE_FRAMES[plane] @ rz
                        centre = np.empty(3)
                        centre[a], centre[b] = ca, cb
                        depth = 0.15 if plane == "XY" else 0.5  # XY: low on the table
                        centre[w] = lo[w] + rng.uniform(depth - 0.1, depth + 0.1) * (hi[w] - lo[w])
                        centre += rng.uniform(-20.0, 20.0, 3)
                        t = centre - rot @ centre_plate
                        ends = (
                            rot
                            @ np.array(
                                [[0, 0, 0], [side_mm, side_mm, 0], [side_mm, 0, 0], [0, side_mm, 0]]
                            ).T
                        ).T + t
                        if np.all(ends >= lo + 1.0) and np.all(ends <= hi - 1.0):
                            out.append(Placement(rot, t, plane, deg))
                            break
                    else:
                        raise RuntimeError(f"a {side_mm} mm plate does not fit the {plane} plane")
    return out


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
