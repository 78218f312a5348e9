"""Ball or hole plates (docs/formats.md §10.3): the calibrated plate (``plate.toml``: ``[[ball]]
id, u_mm, v_mm, w_mm, u_um``) and the measured centres (``plate.csv``: ``placement,ball,x,y,z``
and optionally ``T_x,T_y,T_z,T_wp``), read and checked.

The ball centres are in the plate's own frame (mm) with a standard uncertainty per coordinate
(µm); the measured centres are indicated machine coordinates (mm) probed with the plan's
stylus. Each placement's pose is unknown (estimated by the fit).
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError
from ..parametric_errors import AXES
from .csvtable import TEMPERATURES, PointsFile, read_csv_table
from .plan import PlateSpec

__all__ = ["PlateData", "read_plate"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
MIN_BALLS_PER_PLACEMENT = 3
_INT = re.compile(r"^[+-]?\d+$")


@dataclass(frozen=True)
class PlateData(PointsFile):
    """One ``[[plate]]`` entry: the balls (``ball_ids``, ``ball_mm`` (B, 3) in the plate frame,
    ``ball_u_um`` (B,)) and the N measured centres (``placement`` and ``ball`` indices, ``q_mm``
    (N, 3) indicated, ``lines`` of the CSV). ``placements`` names each placement in order."""

    spec: PlateSpec
    ball_ids: tuple[str, ...]
    ball_mm: FloatArray
    ball_u_um: FloatArray
    placements: tuple[str, ...]
    placement: IntArray
    ball: IntArray
    q_mm: FloatArray
    lines: tuple[int, ...]
    temps_C: dict[str, FloatArray] = field(default_factory=dict)


def _ball_id(value: Any) -> str | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str) and value.strip():
        text = value.strip()
        return str(int(text)) if _INT.match(text) else text
    return None


def _read_balls(spec: PlateSpec) -> tuple[tuple[str, ...], FloatArray, FloatArray]:
    path = spec.balls
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the plate file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{path}: invalid TOML: {exc}") from None
    unknown = sorted(set(data) - {"ball", "name", "note", "material", "expansion"})
    if unknown:
        raise CalibrationError(f"{path}: unknown key(s) {unknown}; a plate has [[ball]] tables")
    balls = data.get("ball")
    if not isinstance(balls, list) or not balls:
        raise CalibrationError(
            f"{path}: ball: expected [[ball]] tables (id, u_mm, v_mm, w_mm, u_um)"
        )
    ids: list[str] = []
    uvw = np.empty((len(balls), 3))
    u_um = np.empty(len(balls))
    for j, b in enumerate(balls):
        where = f"{path}: ball[{j}]"
        if not isinstance(b, Mapping):
            raise CalibrationError(f"{where}: expected a table")
        extra = sorted(set(b) - {"id", "u_mm", "v_mm", "w_mm", "u_um"})
        if extra:
            raise CalibrationError(
                f"{where}: unknown key(s) {extra}; allowed: id, u_mm, v_mm, w_mm, u_um"
            )
        bid = _ball_id(b.get("id"))
        if bid is None:
            raise CalibrationError(
                f"{where}.id: expected an integer or a name, got {b.get('id')!r}"
            )
        if bid in ids:
            raise CalibrationError(
                f"{where}.id: duplicate ball id {bid!r} (also ball[{ids.index(bid)}]): each ball "
                "once"
            )
        ids.append(bid)
        for k, key in enumerate(("u_mm", "v_mm", "w_mm", "u_um")):
            value = b.get(key)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise CalibrationError(f"{where}.{key}: expected a number, got {value!r}")
            if not np.isfinite(value) or (key == "u_um" and value < 0):
                raise CalibrationError(
                    f"{where}.{key}: expected a finite number ≥ 0 for u_um, got {value!r}"
                )
            if k < 3:
                uvw[j, k] = float(value)
            else:
                u_um[j] = float(value)
    return tuple(ids), uvw, u_um


def read_plate(
    spec: PlateSpec, lower_mm: FloatArray, upper_mm: FloatArray, *, need_values: bool = True
) -> PlateData:
    """Read one ``[[plate]]`` entry. Every measured ball must be in ``plate.toml``, once per
    placement; each placement needs ≥ 3 balls; centres within the plan's volume.
    ``need_values`` is accepted for symmetry (the planner uses the centres as the geometry)."""
    del need_values  # the measured centres are the geometry as well as the data
    ids, uvw, u_um = _read_balls(spec)
    table = read_csv_table(spec.file, ("placement", "ball", "x", "y", "z"), TEMPERATURES)
    q = np.column_stack([table.numbers(a) for a in AXES])
    placement_txt = table.text("placement")
    ball_txt = table.text("ball")
    index = {b: j for j, b in enumerate(ids)}
    placements: list[str] = []
    pl = np.empty(len(table), dtype=np.intp)
    ball = np.empty(len(table), dtype=np.intp)
    seen: dict[tuple[int, int], int] = {}
    for i, (p_txt, b_txt) in enumerate(zip(placement_txt, ball_txt, strict=True)):
        bid = _ball_id(b_txt)
        if bid not in index:
            raise table.fail(i, "ball", f"ball {b_txt!r} is not in {spec.balls.name}")
        if p_txt not in placements:
            placements.append(p_txt)
        pl[i] = placements.index(p_txt)
        ball[i] = index[bid]
        key = (int(pl[i]), int(ball[i]))
        if key in seen:
            raise table.fail(
                i,
                "ball",
                f"ball {bid!r} measured twice in placement {p_txt!r} (line "
                f"{table.lines[seen[key]]}): one centre per ball and placement",
            )
        seen[key] = i
    for k, name in enumerate(placements):
        rows = np.flatnonzero(pl == k)
        if rows.size < MIN_BALLS_PER_PLACEMENT:
            raise table.fail(
                int(rows[0]),
                "placement",
                f"placement {name!r} has {rows.size} ball(s); its pose "
                f"needs ≥ {MIN_BALLS_PER_PLACEMENT} balls not on one line",
            )
    table.check_inside(q, lower_mm, upper_mm, "centre")
    temps = table.temperatures()
    return PlateData(
        spec=spec,
        ball_ids=ids,
        ball_mm=uvw,
        ball_u_um=u_um,
        placements=tuple(placements),
        placement=pl,
        ball=ball,
        q_mm=q,
        lines=table.lines,
        temps_C=temps,
    )
