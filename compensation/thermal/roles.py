"""Temperature role names: the one definition every layer uses (docs/formats.md §2, §5).

A role names what a temperature sensor measures, and is the key of that temperature in every
``temps_C`` mapping (model, grid, daemon, simulator, measurement files). Values are °C.
"""

from __future__ import annotations

__all__ = [
    "AIR",
    "BOTTOM",
    "LAGGED_ROLES",
    "SCALE_ROLES",
    "STRUCTURE_ROLES",
    "TEMPERATURE_ROLES",
    "TOP",
    "WORKPIECE",
    "is_temperature",
    "scale_role",
]

#: Scale (axis) temperatures, in axis order x, y, z.
SCALE_ROLES: tuple[str, str, str] = ("T_x", "T_y", "T_z")
#: The workpiece temperature (its expansion about the fixture point).
WORKPIECE = "T_wp"
#: Top and bottom of the structure: their difference bends the axes (thermal gradient).
TOP = "T_top"
BOTTOM = "T_bottom"
#: Ambient air (default driver of the squareness drift).
AIR = "T_air"

#: Every temperature role, in the order of the file formats' columns.
TEMPERATURE_ROLES: tuple[str, ...] = (*SCALE_ROLES, WORKPIECE, TOP, BOTTOM, AIR)
#: Roles that describe the machine's structure (every role but the workpiece).
STRUCTURE_ROLES: tuple[str, ...] = tuple(r for r in TEMPERATURE_ROLES if r != WORKPIECE)
#: Roles the thermal-lag filter acts on (the scale temperatures).
LAGGED_ROLES: tuple[str, ...] = SCALE_ROLES


def scale_role(axis: str) -> str:
    """The scale-temperature role of ``axis`` (``"x"`` → ``"T_x"``)."""
    return f"T_{axis}"


def is_temperature(name: str) -> bool:
    """Whether a runtime signal name is a temperature (°C): every role and any other ``T_*``."""
    return name.startswith("T_")
