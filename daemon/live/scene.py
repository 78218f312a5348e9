"""The ``/cmm/scene`` channel: the correction vectors as ``foxglove.SceneUpdate`` arrows.

Each answered reading whose geometry was corrected becomes an arrow whose tail is the indicated
probe position and which points along the applied correction (corrected − indicated = the error,
true − indicated), drawn ``arrow_mm_per_um`` mm long per µm; its colour says the status (green
``ok``, amber a correction with a term left out, ``not_thermally_corrected`` /
``missing_direction``). A reading the daemon could not correct (``outside_volume``,
``no_temperature`` …, the indicated position sent back unchanged) is a red cube. Positions are
in metres in frame ``cmm`` (the machine frame; mm / 1000), as Foxglove's 3-D panel expects.

Each point is one scene entity with id ``correction/<slot>``; slots cycle through
``scene_keep_arrows``, so the viewer keeps the newest ``scene_keep_arrows`` points and every update
carries only the new ones (its cost does not grow with the history). Entity ``probe`` is a
sphere at the newest point. Metadata on every entity gives ``seq``, ``status`` and the
correction in µm (shown when hovering in Foxglove).

Only imported when the live view is enabled (it imports ``foxglove``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    KeyValuePair,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from msgspec import UNSET

from cmm_comp.protocol.codes import Status
from cmm_comp.protocol.session_topics import Corrected

from .decimate import pick_evenly as pick_evenly

FRAME_ID = "cmm"
"""Frame of every entity: the machine frame, metres."""
APPLIED_STATUSES = frozenset(s.label for s in Status if s.geometric_correction_applied)
"""Statuses whose answer carries the geometric correction (``ok`` and the partial ones)."""
SHAFT_DIAMETER_M = 0.003
HEAD_DIAMETER_M = 0.008
HEAD_LENGTH_MAX_M = 0.012
MARKER_M = 0.008
"""Edge of the cube marking a reading that was not corrected, m."""
PROBE_M = 0.012
"""Diameter of the sphere at the newest point, m."""

_GREEN = (0.15, 0.75, 0.25, 1.0)
_AMBER = (1.0, 0.65, 0.0, 1.0)
_RED = (0.9, 0.1, 0.1, 1.0)
_WHITE = (0.9, 0.9, 0.9, 0.8)


@dataclass(frozen=True)
class ScenePoint:
    """One answered reading as the scene needs it: ``indicated_mm`` (x, y, z), the applied
    correction ``d_um`` (x, y, z; zeros when not applied), ``status`` label, ``seq`` and the
    log time (integer ns)."""

    seq: int
    indicated_mm: tuple[float, float, float]
    d_um: tuple[float, float, float]
    status: str
    t_ns: int

    @property
    def applied(self) -> bool:
        """True when the answer carries the geometric correction."""
        return self.status in APPLIED_STATUSES


def point_from_corrected(obj: Corrected, t_ns: int) -> ScenePoint | None:
    """A :class:`ScenePoint` from a checked ``/cmm/corrected`` message, or None when a position
    or correction is not finite (nothing sensible to draw). The indicated position is
    corrected − d / 1000 for an applied correction, the answered position otherwise; ``t_ns``:
    its log time."""
    d = tuple(0.0 if v is UNSET else v for v in (obj.dx_um, obj.dy_um, obj.dz_um))
    pos = (obj.x_mm, obj.y_mm, obj.z_mm)
    if not all(math.isfinite(v) for v in (*pos, *d)):  # type: ignore[arg-type]
        return None
    if obj.status not in APPLIED_STATUSES:
        d = (0.0, 0.0, 0.0)
    dx, dy, dz = d  # type: ignore[misc]
    indicated = (pos[0] - dx / 1000.0, pos[1] - dy / 1000.0, pos[2] - dz / 1000.0)
    return ScenePoint(obj.seq, indicated, (dx, dy, dz), obj.status, t_ns)


def quaternion_from_x_to(
    direction: tuple[float, float, float],
) -> tuple[float, float, float, float]:
    """Unit quaternion ``(w, x, y, z)`` of the shortest rotation taking +X onto ``direction``
    (any non-zero length): ``normalise(1 + x̂·u, x̂ × u)``; a half turn about Z for −X."""
    norm = math.sqrt(sum(c * c for c in direction))
    ux, uy, uz = (c / norm for c in direction)
    w, x, y, z = 1.0 + ux, 0.0, -uz, uy
    n = math.sqrt(w * w + y * y + z * z)
    if n < 1e-9:  # direction is -X: any half turn about an axis normal to X
        return (0.0, 0.0, 0.0, 1.0)
    return (w / n, x / n, y / n, z / n)


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _position_m(p_mm: tuple[float, float, float]) -> Vector3:
    return Vector3(x=p_mm[0] / 1000.0, y=p_mm[1] / 1000.0, z=p_mm[2] / 1000.0)


def _timestamp(t_ns: int) -> Timestamp:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return Timestamp(sec, nsec)


def arrow_length_m(point: ScenePoint, arrow_mm_per_um: float) -> float:
    """Drawn length of a point's arrow, m: |d| µm × ``arrow_mm_per_um`` mm/µm / 1000."""
    return math.sqrt(sum(c * c for c in point.d_um)) * arrow_mm_per_um / 1000.0


def entity_for(point: ScenePoint, slot: int, arrow_mm_per_um: float) -> SceneEntity:
    """The scene entity of one point (id ``correction/<slot>``)."""
    identity = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    length_m = arrow_length_m(point, arrow_mm_per_um)
    meta = [
        KeyValuePair(key="seq", value=str(point.seq)),
        KeyValuePair(key="status", value=point.status),
        KeyValuePair(key="d_um", value="[{:.3f}, {:.3f}, {:.3f}]".format(*point.d_um)),
    ]
    arrows: list[ArrowPrimitive] = []
    cubes: list[CubePrimitive] = []
    spheres: list[SpherePrimitive] = []
    if not point.applied:
        cubes.append(
            CubePrimitive(
                pose=Pose(position=_position_m(point.indicated_mm), orientation=identity),
                size=Vector3(x=MARKER_M, y=MARKER_M, z=MARKER_M),
                color=_color(_RED),
            )
        )
    elif length_m > 0.0:
        w, x, y, z = quaternion_from_x_to(point.d_um)
        head = min(0.35 * length_m, HEAD_LENGTH_MAX_M)
        arrows.append(
            ArrowPrimitive(
                pose=Pose(
                    position=_position_m(point.indicated_mm),
                    orientation=Quaternion(x=x, y=y, z=z, w=w),
                ),
                shaft_length=length_m - head,
                shaft_diameter=SHAFT_DIAMETER_M,
                head_length=head,
                head_diameter=HEAD_DIAMETER_M,
                color=_color(_GREEN if point.status == Status.OK.label else _AMBER),
            )
        )
    else:  # corrected, and the correction is exactly zero: a small dot
        spheres.append(
            SpherePrimitive(
                pose=Pose(position=_position_m(point.indicated_mm), orientation=identity),
                size=Vector3(x=SHAFT_DIAMETER_M, y=SHAFT_DIAMETER_M, z=SHAFT_DIAMETER_M),
                color=_color(_GREEN),
            )
        )
    return SceneEntity(
        timestamp=_timestamp(point.t_ns),
        frame_id=FRAME_ID,
        id=f"correction/{slot}",
        metadata=meta,
        arrows=arrows,
        cubes=cubes,
        spheres=spheres,
    )


def probe_entity(point: ScenePoint) -> SceneEntity:
    """Entity ``probe``: a sphere at the newest point's indicated position."""
    return SceneEntity(
        timestamp=_timestamp(point.t_ns),
        frame_id=FRAME_ID,
        id="probe",
        metadata=[KeyValuePair(key="seq", value=str(point.seq))],
        spheres=[
            SpherePrimitive(
                pose=Pose(
                    position=_position_m(point.indicated_mm),
                    orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                ),
                size=Vector3(x=PROBE_M, y=PROBE_M, z=PROBE_M),
                color=_color(_WHITE),
            )
        ],
    )


def scene_update(
    points: list[ScenePoint], first_slot: int, slots: int, arrow_mm_per_um: float
) -> SceneUpdate:
    """One update with an entity per point (slots ``first_slot``, ``first_slot + 1`` … modulo
    ``slots``) and the ``probe`` sphere at the last point."""
    entities = [
        entity_for(p, (first_slot + i) % slots, arrow_mm_per_um) for i, p in enumerate(points)
    ]
    if points:
        entities.append(probe_entity(points[-1]))
    return SceneUpdate(entities=entities)
