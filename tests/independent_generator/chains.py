"""First-order rigid-body chains of the ten kinematic models, written from the physics.

Each model (docs/formats.md §1.2, paper section 2) stacks three carriages. *Tool* axes carry the
stylus (base → tip); *workpiece* axes carry the table (base → table).

* A tool carriage of axis ``a`` that rotates by the small vector ε (µrad) about its own origin
  moves the tip by ``ε × r`` where ``r`` is the arm from the carriage's origin to the tip: the
  travel of every tool axis *after* ``a`` in the chain plus the stylus offset ``p``.
* A table of axis ``w`` that rotates by ε carries the workpiece with it, so the tip seen from the
  workpiece moves by ``−ε × r``; ``r`` is the tip's position in that table's frame: the travel of
  every tool axis, of ``w`` itself and of every table axis *below* it (nearer the base), plus ``p``.
* A linear error δ (straightness, positional) adds to the error directly, on either side
  (a table's linear errors are those of the relative motion, docs/conventions.md).
* Squareness (first order, docs/conventions.md): ΔY −= α·x, ΔX −= β1·z, ΔY −= β2·z.

Positions in arms are ``u = q − reference`` (mm); errors are µm, angles µrad, so an angular
term is ``ε[µrad] · r[mm] / 1000`` µm. Error = true − indicated.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

AXES = ("x", "y", "z")
AXIS_INDEX = {"x": 0, "y": 1, "z": 2}

#: model code → (tool axes base → stylus, workpiece axes base → table)
MODELS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "MB1": (("y", "x", "z"), ()),
    "MB2": (("x", "y", "z"), ()),
    "FB1": (("x", "z"), ("y",)),
    "FB2": (("y", "z"), ("x",)),
    "MH1": (("y", "z", "x"), ()),
    "MH2": (("x", "z", "y"), ()),
    "FH1": (("y", "z"), ("x",)),
    "FH2": (("x", "z"), ("y",)),
    "CX1": (("z",), ("x", "y")),
    "CY1": (("z",), ("y", "x")),
}

LINEAR_COMPONENTS = tuple(f"d{i}_{j}" for j in AXES for i in AXES)
ANGULAR_COMPONENTS = tuple(f"e{i}_{j}" for j in AXES for i in AXES)
SQUARENESS = ("alpha", "beta1", "beta2")


def _unit(axis: str) -> FloatArray:
    e = np.zeros(3)
    e[AXIS_INDEX[axis]] = 1.0
    return e


def carriage_arms(
    model: str, u_mm: FloatArray, stylus_mm: FloatArray
) -> dict[str, tuple[FloatArray, float]]:
    """Axis → (arm (N, 3) mm from that carriage's rotation point to the tip, sign ±1).

    ``u_mm`` (N, 3) positions from the reference, ``stylus_mm`` (N, 3) tip offsets. The sign is
    +1 for a tool carriage (the tip rotates with it) and −1 for a table (the part rotates).
    """
    tool, work = MODELS[model]
    u = np.asarray(u_mm, dtype=float)
    p = np.broadcast_to(np.asarray(stylus_mm, dtype=float), u.shape)

    def travel(axes: tuple[str, ...]) -> FloatArray:
        out = np.zeros_like(u)
        for a in axes:
            k = AXIS_INDEX[a]
            out[:, k] += u[:, k]
        return out

    arms: dict[str, tuple[FloatArray, float]] = {}
    for i, a in enumerate(tool):
        arms[a] = (travel(tool[i + 1 :]) + p, 1.0)
    for i, w in enumerate(work):
        arms[w] = (travel(tool) + travel(work[: i + 1]) + p, -1.0)
    return arms


def rotation_um(
    model: str, axis: str, rot_urad: FloatArray, u_mm: FloatArray, stylus_mm: FloatArray
) -> FloatArray:
    """Tip error (N, 3) µm from a small rotation vector ``rot_urad`` (N, 3) µrad of ``axis``' carriage."""
    arm, sign = carriage_arms(model, u_mm, stylus_mm)[axis]
    return sign * np.cross(np.asarray(rot_urad, dtype=float), arm) / 1000.0


def squareness_um(u_mm: FloatArray, squareness_urad: Mapping[str, FloatArray]) -> FloatArray:
    """First-order squareness error (N, 3) µm; ``squareness_urad`` maps alpha/beta1/beta2 to (N,) or scalars."""
    u = np.asarray(u_mm, dtype=float)
    out = np.zeros_like(u)
    alpha = squareness_urad.get("alpha", 0.0)
    beta1 = squareness_urad.get("beta1", 0.0)
    beta2 = squareness_urad.get("beta2", 0.0)
    out[:, 1] -= np.asarray(alpha) * u[:, 0] / 1000.0
    out[:, 0] -= np.asarray(beta1) * u[:, 2] / 1000.0
    out[:, 1] -= np.asarray(beta2) * u[:, 2] / 1000.0
    return out


def chain_error_um(
    model: str,
    u_mm: FloatArray,
    stylus_mm: FloatArray,
    components: Mapping[str, FloatArray],
) -> FloatArray:
    """Tip error (N, 3) µm of component values already evaluated at the points.

    ``components`` maps names ``dI_J`` (µm), ``eI_J`` (µrad) and ``alpha``/``beta1``/``beta2``
    (µrad) to (N,) arrays or scalars; absent names are zero.
    """
    u = np.asarray(u_mm, dtype=float)
    n = u.shape[0]
    out = np.zeros((n, 3))
    arms = carriage_arms(model, u, stylus_mm)
    sq: dict[str, FloatArray] = {}
    for name, value in components.items():
        v = np.broadcast_to(np.asarray(value, dtype=float), (n,))
        if name in SQUARENESS:
            sq[name] = v
        elif name in LINEAR_COMPONENTS:
            out[:, AXIS_INDEX[name[1]]] += v
        elif name in ANGULAR_COMPONENTS:
            arm, sign = arms[name[3]]
            rot = v[:, None] * _unit(name[1])[None, :]
            out += sign * np.cross(rot, arm) / 1000.0
        else:
            raise ValueError(f"unknown component {name!r}")
    if sq:
        out += squareness_um(u, sq)
    return out


def component_axis(name: str) -> str | None:
    """The axis whose position a component is a function of (None for squareness)."""
    if name in LINEAR_COMPONENTS or name in ANGULAR_COMPONENTS:
        return name[3]
    return None
