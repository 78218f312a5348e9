"""Names of the 21 parametric errors and their aliases.

Paper notation (Park, Burdekin & Peggs) ↔ our names ↔ ISO 230-1:

=============  =========  ==========  =======================================
paper          ours       ISO 230-1   meaning
=============  =========  ==========  =======================================
δx(x)          dx_x       EXX         positional error of X
δy(x), δz(x)   dy_x,dz_x  EYX, EZX    straightness of X in Y, in Z
εx(x)          ex_x       EAX         roll of X (rotation about x)
εy(x), εz(x)   ey_x,ez_x  EBX, ECX    pitch/yaw of X (rotation about y, z)
α              alpha      —           squareness XY  (ΔY = −α·x)
β1             beta1      —           squareness XZ  (ΔX = −β1·z)
β2             beta2      —           squareness YZ  (ΔY = −β2·z)
=============  =========  ==========  =======================================

and likewise for axes Y and Z. Linear errors in µm, angular errors and squareness in µrad.
The paper's own file extensions (``.DPX``, ``.DYX``, ``.EXX`` …) are a *different* naming: its
``EXX`` is the roll of X, while ISO 230-1's ``EXX`` is the positional error of X. The seed-file
importer (:mod:`compensation.seedfiles`) uses the paper's meaning; TOML tables use ISO's.
"""

from __future__ import annotations

from dataclasses import dataclass

AXES: tuple[str, str, str] = ("x", "y", "z")
AXIS_INDEX: dict[str, int] = {"x": 0, "y": 1, "z": 2}

#: Order of the six errors of one axis in every (…, 6) array: three linear (µm), three angular (µrad).
SLOT_NAMES: tuple[str, ...] = ("dx", "dy", "dz", "ex", "ey", "ez")

LINEAR: tuple[str, ...] = tuple(f"d{i}_{a}" for a in AXES for i in AXES)
ANGULAR: tuple[str, ...] = tuple(f"e{i}_{a}" for a in AXES for i in AXES)
SQUARENESS: tuple[str, ...] = ("alpha", "beta1", "beta2")
TABLE_COMPONENTS: tuple[str, ...] = LINEAR + ANGULAR
ALL_COMPONENTS: tuple[str, ...] = TABLE_COMPONENTS + SQUARENESS

_ISO_ROT = {"x": "A", "y": "B", "z": "C"}
#: ISO 230-1 name → our name: ``E<direction><axis>`` linear, ``E<A|B|C><axis>`` angular.
ISO_ALIASES: dict[str, str] = {
    **{f"E{i.upper()}{a.upper()}": f"d{i}_{a}" for a in AXES for i in AXES},
    **{f"E{_ISO_ROT[i]}{a.upper()}": f"e{i}_{a}" for a in AXES for i in AXES},
}


@dataclass(frozen=True)
class Component:
    """One parametric error of one axis: ``kind`` is ``"d"`` (linear, µm) or ``"e"`` (angular, µrad)."""

    kind: str
    direction: str  # x | y | z: the direction of the displacement, or the rotation axis
    axis: str  # x | y | z: the moving axis the error belongs to

    @property
    def name(self) -> str:
        return f"{self.kind}{self.direction}_{self.axis}"

    @property
    def slot(self) -> int:
        """Index into the axis' 6-vector ``(dx, dy, dz, ex, ey, ez)``."""
        return AXIS_INDEX[self.direction] + (0 if self.kind == "d" else 3)

    @property
    def is_positional(self) -> bool:
        return self.kind == "d" and self.direction == self.axis

    @property
    def is_straightness(self) -> bool:
        return self.kind == "d" and self.direction != self.axis

    @property
    def is_angular(self) -> bool:
        return self.kind == "e"

    @property
    def unit(self) -> str:
        return "um" if self.kind == "d" else "urad"


def canonical_name(name: str) -> str | None:
    """Our name for ``name`` (ours or an ISO 230-1 alias), or None when unknown."""
    if name in ALL_COMPONENTS:
        return name
    upper = name.upper()
    if upper in ISO_ALIASES:
        return ISO_ALIASES[upper]
    lower = name.lower()
    return lower if lower in ALL_COMPONENTS else None


def parse_component(name: str) -> Component:
    """The table component ``name`` (ours or ISO alias); ValueError naming the allowed ones."""
    canon = canonical_name(name)
    if canon is None or canon not in TABLE_COMPONENTS:
        raise ValueError(
            f"unknown error component {name!r}; allowed: {', '.join(TABLE_COMPONENTS)} "
            "or ISO 230-1 names (EXX, EYX, EAX, …)"
        )
    return Component(kind=canon[0], direction=canon[1], axis=canon[3])
