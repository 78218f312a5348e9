"""The node data of a correction grid from a machine model (exact error poses at the nodes, and
one sensitivity grid per runtime signal) or from measured node poses; the default node counts.

Units: positions mm, translations µm, rotation sensitivities µrad per signal unit, quaternions
(w, x, y, z). ``CorrectionGrid.build`` and ``CorrectionGrid.from_poses`` construct the grid
from the :class:`.nodes.NodeData` made here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..thermal.lag import signal_filters
from . import quaternion as qt
from .inputs import GridSignal
from .nodes import MAX_NODES, MAX_STEPS_PER_AXIS, MIN_STEPS_PER_AXIS, NodeData, check_steps

__all__ = [
    "DEFAULT_STEPS",
    "MAX_DEFAULT_STEPS",
    "NODES_PER_WAVELENGTH",
    "TABLE_SPACING_FACTOR",
    "MachineLike",
    "default_steps",
    "effect_steps",
    "nodes_from_machine",
    "nodes_from_poses",
    "unresolved_effects",
]

FloatArray = NDArray[np.float64]
ProgressFn = Callable[[float, str], None]

DEFAULT_STEPS = (20, 20, 10)


#: Node spacing relative to the finest error-table spacing of an axis (measured: 20×20×20 meets
#: the 1 % accuracy target on gec-mh2, whose tables are 100 mm apart, 20×20×10 does not).
TABLE_SPACING_FACTOR = 0.6
MAX_DEFAULT_STEPS = 100


#: Nodes per shortest wavelength of an effect's shape (a cyclic error, a table change of high
#: order): the not-a-knot cubic spline through 8 nodes per period follows a sine to ~0.2 %.
NODES_PER_WAVELENGTH = 8


def _wavelengths(machine: Any) -> list[tuple[int, str, float]]:
    """(axis index, cause, shortest wavelength mm) of every effect with a fine shape."""
    out: list[tuple[int, str, float]] = []
    for effect in getattr(machine, "effects", []):
        hook = getattr(effect, "shortest_wavelength_mm", None)
        for axis, wavelength in (hook() if callable(hook) else {}).items():
            if wavelength > 0 and np.isfinite(wavelength):
                out.append(("xyz".index(axis), str(getattr(effect, "cause", "")), wavelength))
    return out


def effect_steps(machine: Any) -> list[int]:
    """Nodes per axis the machine's effects need: :data:`NODES_PER_WAVELENGTH` per shortest
    wavelength (0 where no effect asks for more than the default)."""
    vol = machine.volume
    length = np.asarray(vol.upper_mm, dtype=np.float64) - np.asarray(vol.lower_mm, np.float64)
    need = [0, 0, 0]
    for k, _cause, wavelength in _wavelengths(machine):
        if length[k] > 0:
            n = int(np.ceil(NODES_PER_WAVELENGTH * length[k] / wavelength)) + 1
            need[k] = max(need[k], n)
    return need


def unresolved_effects(machine: Any, steps: Sequence[int]) -> list[dict[str, Any]]:
    """Effects whose shape the node spacing of ``steps`` follows with fewer than
    :data:`NODES_PER_WAVELENGTH` nodes per wavelength: ``{"axis", "cause", "wavelength_mm",
    "nodes_per_wavelength"}`` each (the grid's interpolation misses part of them)."""
    vol = machine.volume
    length = np.asarray(vol.upper_mm, dtype=np.float64) - np.asarray(vol.lower_mm, np.float64)
    out: list[dict[str, Any]] = []
    for k, cause, wavelength in _wavelengths(machine):
        if length[k] <= 0:
            continue
        per = (int(steps[k]) - 1) * wavelength / float(length[k])
        if per < NODES_PER_WAVELENGTH:
            out.append(
                {
                    "axis": "xyz"[k],
                    "cause": cause,
                    "wavelength_mm": float(wavelength),
                    "nodes_per_wavelength": float(per),
                }
            )
    return out


def default_steps(machine: Any) -> tuple[int, int, int]:
    """Nodes per axis when none are given: ``volume.steps`` (or :data:`DEFAULT_STEPS`), raised
    so the node spacing is at most ``TABLE_SPACING_FACTOR`` × the finest spacing of the tabulated
    errors of that axis (at most :data:`MAX_DEFAULT_STEPS`), and so the effects' shortest
    wavelengths get :data:`NODES_PER_WAVELENGTH` nodes each (:func:`effect_steps`, at most
    :data:`MAX_STEPS_PER_AXIS`); beyond :data:`MAX_NODES` the finest axis gives way."""
    vol = machine.volume
    base = list(getattr(vol, "steps", None) or DEFAULT_STEPS)
    lo = np.asarray(vol.lower_mm, dtype=np.float64)
    hi = np.asarray(vol.upper_mm, dtype=np.float64)
    effect_need = effect_steps(machine)
    for table in getattr(machine, "tables", {}).values():
        pos = getattr(table, "position_mm", None)
        axis = getattr(getattr(table, "component", None), "axis", None)
        if pos is None or axis not in ("x", "y", "z") or len(pos) < 2:
            continue
        k = "xyz".index(axis)
        spacing = float(np.min(np.diff(pos)))
        if spacing > 0:
            need = int(np.ceil((hi[k] - lo[k]) / (TABLE_SPACING_FACTOR * spacing))) + 1
            base[k] = max(base[k], min(need, MAX_DEFAULT_STEPS))
    for k, n in enumerate(effect_need):
        base[k] = max(base[k], min(n, MAX_STEPS_PER_AXIS))
    # within the memory budget: the finest axis gives way first (what is left unresolved is
    # recorded in the grid's metadata, see unresolved_effects)
    while base[0] * base[1] * base[2] > MAX_NODES:
        k = int(np.argmax(base))
        base[k] = max(MIN_STEPS_PER_AXIS, int(MAX_NODES // (base[0] * base[1] * base[2] / base[k])))
    return (int(base[0]), int(base[1]), int(base[2]))


class MachineLike(Protocol):
    """What :meth:`CorrectionGrid.build` needs from a machine (see ``compensation.machine``)."""

    name: str
    model: str
    volume: Any

    def pose_error(
        self,
        points_mm: ArrayLike,
        temps_C: Mapping[str, Any] | None = None,
        inputs: Mapping[str, Any] | None = None,
    ) -> Any: ...

    def runtime_signals(self) -> dict[str, float]: ...

    def identity_sha256(self) -> str: ...


def nodes_from_machine(
    machine: MachineLike,
    steps: Sequence[int] | None = None,
    progress: ProgressFn | None = None,
) -> NodeData:
    """Evaluate ``machine`` exactly at every node of its working volume.

    ``steps`` = nodes per axis (default: :func:`default_steps`: the machine's ``volume.steps``
    or :data:`DEFAULT_STEPS`, refined so nodes are no further apart than 0.6× the finest
    tabulated error spacing along each axis — a coarser grid cannot follow the tables).
    For every runtime signal the sensitivity per unit is the central difference of the
    pose at reference ± 1 unit (:func:`_sensitivities`). ``progress(fraction, message)`` is
    called as the work proceeds.
    """
    vol = machine.volume
    steps_ok = check_steps(default_steps(machine) if steps is None else steps)
    lo = np.asarray(vol.lower_mm, dtype=np.float64)
    hi = np.asarray(vol.upper_mm, dtype=np.float64)
    axes = [np.linspace(lo[k], hi[k], steps_ok[k]) for k in range(3)]
    nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    refs = {str(k): float(v) for k, v in machine.runtime_signals().items()}
    n_eval = 1 + 2 * len(refs)
    done = 0

    def evaluate(values: dict[str, float]) -> tuple[FloatArray, FloatArray]:
        nonlocal done
        temps = {k: v for k, v in values.items() if k.startswith("T_")}
        other = {k: v for k, v in values.items() if not k.startswith("T_")}
        pose = machine.pose_error(nodes, temps_C=temps or None, inputs=other or None)
        done += 1
        if progress is not None:
            progress(done / n_eval, f"evaluated machine at {len(nodes)} nodes ({done}/{n_eval})")
        return np.asarray(pose.rotation, float), np.asarray(pose.translation_um, float)

    r0, t0 = evaluate(refs)
    signals, sens_t, sens_r, nonlin = _sensitivities(evaluate, refs, r0, t0, steps_ok)
    meta = {
        "machine": {
            "name": str(machine.name),
            "model": str(machine.model),
            "sha256": machine.identity_sha256(),
        },
        "source": "model",
        "probe_offset_mm": np.asarray(
            getattr(getattr(machine, "probe", None), "offset_mm", np.zeros(3)), float
        ).tolist(),
        "reference_mm": np.asarray(getattr(vol, "reference_mm", lo), float).tolist(),
        "nonlinearity": nonlin,
        "signal_filters": [f.to_header() for f in signal_filters(getattr(machine, "effects", []))],
        "unresolved_effects": unresolved_effects(machine, steps_ok),
    }
    q0 = qt.quaternion_from_matrix(r0)
    return NodeData(
        lo, hi, q0.reshape(*steps_ok, 4), t0.reshape(*steps_ok, 3), signals, sens_t, sens_r, meta
    )


def _sensitivities(
    evaluate: Callable[[dict[str, float]], tuple[FloatArray, FloatArray]],
    refs: dict[str, float],
    r0: FloatArray,
    t0: FloatArray,
    steps: tuple[int, int, int],
) -> tuple[list[GridSignal], FloatArray, FloatArray, dict[str, dict[str, float]]]:
    """Per runtime signal (``refs``: name → reference value) the central difference of the
    pose at reference ± 1 unit about the reference pose ``r0`` (N, 3, 3), ``t0`` (N, 3) µm:
    the signals (needed when they move anything), the sensitivity grids (S, nx, ny, nz, 3) µm
    and µrad per unit, and per signal the largest second difference (µm, µrad) over the nodes,
    i.e. how far from linear it is (the grid's ``nonlinearity`` metadata)."""
    sens_t, sens_r, signals, nonlin = [], [], [], {}
    for name, ref in refs.items():
        rp, tp = evaluate({**refs, name: ref + 1.0})
        rm, tm = evaluate({**refs, name: ref - 1.0})
        # rotation vectors of R(ref ± 1)·R0ᵀ (left, in the workpiece frame), µrad
        wp = qt.rotvec_from_quaternion(qt.quaternion_from_matrix(rp @ np.swapaxes(r0, 1, 2)))
        wm = qt.rotvec_from_quaternion(qt.quaternion_from_matrix(rm @ np.swapaxes(r0, 1, 2)))
        dt = 0.5 * (tp - tm)
        dw = 0.5e6 * (wp - wm)
        nonlin[name] = {
            "translation_um": float(np.abs(tp - 2 * t0 + tm).max()),
            "rotation_urad": float(1e6 * np.abs(wp + wm).max()),
        }
        needed = bool(np.abs(dt).max() > 1e-12 or np.abs(dw).max() > 1e-12)
        signals.append(GridSignal(name, ref, needed))
        sens_t.append(dt.reshape(*steps, 3))
        sens_r.append(dw.reshape(*steps, 3))
    n_sig = len(signals)
    return (
        signals,
        np.array(sens_t).reshape(n_sig, *steps, 3),
        np.array(sens_r).reshape(n_sig, *steps, 3),
        nonlin,
    )


def nodes_from_poses(
    axes_mm: Sequence[ArrayLike],
    q_work_stylus: ArrayLike,
    translation_um: ArrayLike,
    *,
    machine_name: str = "measured",
    machine_model: str = "unknown",
    source_sha256: str = "",
    signals: Sequence[GridSignal] = (),
    sensitivity_translation_um: ArrayLike | None = None,
    sensitivity_rotation_urad: ArrayLike | None = None,
) -> NodeData:
    """Node data from node poses, e.g. captured with the 6-DOF scheme (:mod:`compensation.reports.sixdof`).

    ``axes_mm``: three increasing, equally spaced node coordinate arrays (mm);
    ``q_work_stylus`` (nx, ny, nz, 4) unit quaternions (w, x, y, z) of the error rotation;
    ``translation_um`` (nx, ny, nz, 3) the error translation at stylus offset 0 (µm), i.e.
    the error of the point about which the rotation acts.
    """
    ax = [np.asarray(a, dtype=np.float64) for a in axes_mm]
    if len(ax) != 3:
        raise ValueError(f"axes_mm must hold three node arrays, got {len(ax)}")
    for name, a in zip("xyz", ax, strict=True):
        if a.ndim != 1 or a.size < 2 or not np.all(np.diff(a) > 0):
            raise ValueError(f"axis {name} nodes must be a strictly increasing 1-D array")
        uniform = np.linspace(a[0], a[-1], a.size)
        if np.abs(a - uniform).max() > 1e-9 * max(1.0, abs(a[-1] - a[0])):
            raise ValueError(f"axis {name} nodes must be equally spaced (Squad parameter)")
    meta = {
        "machine": {"name": machine_name, "model": machine_model, "sha256": source_sha256},
        "source": "poses",
    }
    return NodeData(
        [a[0] for a in ax],
        [a[-1] for a in ax],
        q_work_stylus,
        translation_um,
        signals,
        sensitivity_translation_um,
        sensitivity_rotation_urad,
        meta,
    )
