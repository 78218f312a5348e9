"""The calibration plan ``calibration.toml`` (docs/formats.md §10): which machine, which volume
and stylus, how to fit, and the data sets (laser runs, ball plates, multilateration), their files
relative to the plan.

:func:`read_plan` validates every key (one :class:`CalibrationError` naming the plan file and the
key) and checks that every named file exists; the data files themselves are read by
:mod:`.laser`, :mod:`.plate` and :mod:`.multilateration`. The machine part of the plan (model,
volume, stylus, thermal data) is validated by the machine parser itself
(:meth:`Machine.from_dict`), so it obeys exactly the rules of ``machine.toml``.
Units: mm, µm, µrad, °C.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CalibrationError, MachineFileError
from ..parametric_errors import AXES, SQUARENESS, TABLE_COMPONENTS, canonical_name

if TYPE_CHECKING:
    from ..machine import Machine

__all__ = [
    "DEFAULT_NODES",
    "DEFAULT_STEPS",
    "FitSettings",
    "LaserSpec",
    "MultilaterationSpec",
    "Plan",
    "PlateSpec",
    "read_plan",
]

FloatArray = NDArray[np.float64]
PLAN_FORMAT = "cmm-calibration/1"
DEFAULT_NODES = 21
DEFAULT_ORDER = 4
DEFAULT_STEPS = (6, 6, 6)
#: A-priori standard uncertainties (k = 1) of one reading, per kind; the fit re-estimates them
#: from the residuals (variance components) and reports both.
LASER_DEFAULTS = {
    "u_linear_um": 0.2,
    "u_straightness_um": 0.3,
    "u_angle_urad": 0.3,
    "u_squareness_urad": 1.0,
    # a linear run's scale (air-refraction compensation): a compensated laser's ±0.5 ppm as a
    # rectangular bound, 0.5/√3; one unknown scale per run, this its prior (not re-estimated)
    "u_scale_ppm": 0.3,
}
PLATE_PROBE_DEFAULT_UM = 0.3
TRACKER_DEFAULT_UM = 0.3
PRIOR_DEFAULT = 1000.0  # µm / µrad: the weak prior on every error value (what no data sees)
_TOP = {
    "format",
    "name",
    "model",
    "reference_C",
    "volume",
    "probe",
    "thermal",
    "fit",
    "laser",
    "plate",
    "multilateration",
}


@dataclass(frozen=True)
class LaserSpec:
    """One ``[[laser]]`` entry: a CSV of runs, or an ISO 230-2 ``.dat`` file of one axis
    (then ``axis``, the line's other coordinates ``line_mm``, the optic offset and optionally
    the ``cycles`` used)."""

    where: str
    file: Path
    u: Mapping[str, float]
    axis: str | None = None
    line_mm: FloatArray | None = None
    optic_offset_mm: FloatArray | None = None
    cycles: tuple[int, ...] | None = None

    @property
    def is_iso230(self) -> bool:
        return self.file.suffix.lower() == ".dat"


@dataclass(frozen=True)
class PlateSpec:
    """One ``[[plate]]`` entry: calibrated balls (TOML), measured centres (CSV), the stylus."""

    where: str
    balls: Path
    file: Path
    stylus_mm: FloatArray
    probe_um: float


@dataclass(frozen=True)
class MultilaterationSpec:
    """One ``[[multilateration]]`` entry: lengths (CSV), the reflector's stylus, rough station
    positions (one per station, in order of first appearance), the length's u (µm)."""

    where: str
    file: Path
    stylus_mm: FloatArray
    station_guess_mm: FloatArray
    u_um: float


@dataclass(frozen=True)
class FitSettings:
    """How the errors are represented and regularised (``[fit]``).

    ``basis``: ``spline`` (values at ``nodes`` equally spaced nodes per axis, evaluated as the
    machine file evaluates a table: a not-a-knot cubic spline) or ``polynomial`` (``order`` per
    axis, written as ``polynomial = […]``). ``smoothness``: None = estimated from the data
    (marginal likelihood), else the roughness τ (µm, µrad per unit of normalised curvature).
    ``components``: the errors identified (the rest are held at zero). ``reversal``: estimate a
    reversal on positional tables from bidirectional laser runs. ``prior``: the weak prior's
    standard deviation on every value (µm or µrad), what fixes what no data sees."""

    basis: str = "spline"
    nodes: tuple[int, int, int] = (DEFAULT_NODES,) * 3
    order: tuple[int, int, int] = (DEFAULT_ORDER,) * 3
    smoothness: float | None = None
    components: tuple[str, ...] = (*TABLE_COMPONENTS, *SQUARENESS)
    reversal: bool = True
    prior: float = PRIOR_DEFAULT


@dataclass(frozen=True)
class Plan:
    """A validated calibration plan. ``base`` is the machine without errors (model, volume with
    the reference at the lower corner, the calibration stylus, thermal data): the observation
    models take its thermal terms and the output keeps its parts."""

    source: Path
    name: str
    model: str
    base: Machine
    steps: tuple[int, int, int]
    fit: FitSettings
    lasers: tuple[LaserSpec, ...] = ()
    plates: tuple[PlateSpec, ...] = ()
    multilaterations: tuple[MultilaterationSpec, ...] = ()

    @property
    def stylus_mm(self) -> FloatArray:
        return np.asarray(self.base.probe.offset_mm, dtype=float)

    @property
    def folder(self) -> Path:
        return self.source.parent


class _Checks:
    """TOML value checks whose failures are :class:`CalibrationError` naming the plan file
    (``source``) and the key (``where``)."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, problem: str) -> CalibrationError:
        return CalibrationError(f"{self.source}: {where}: {problem}")

    def number(self, value: Any, where: str, *, positive: bool = False) -> float:
        """A finite number (an int or a float, not a bool); ``positive``: > 0."""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(where, f"expected a number, got {value!r}")
        out = float(value)
        if not math.isfinite(out):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        if positive and out <= 0:
            raise self.fail(where, f"must be > 0, got {value!r}")
        return out

    def check_keys(self, table: Mapping[str, Any], where: str, allowed: set[str]) -> None:
        """Refuse keys of ``table`` not in ``allowed`` (all of them named, and the allowed)."""
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise self.fail(where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")

    def vector(self, value: Any, where: str, length: int) -> FloatArray:
        if not isinstance(value, list) or len(value) != length:
            raise self.fail(where, f"expected {length} numbers, got {value!r}")
        return np.array([self.number(v, f"{where}[{i}]") for i, v in enumerate(value)])

    def table(self, data: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
        value = data.get(key, {})
        if not isinstance(value, Mapping):
            raise self.fail(where, f"expected a table, got {value!r}")
        return value

    def entries(self, data: Mapping[str, Any], key: str) -> list[Mapping[str, Any]]:
        value = data.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, Mapping) for v in value):
            raise self.fail(key, f"expected an array of tables [[{key}]]")
        return list(value)

    def file(self, folder: Path, entry: Mapping[str, Any], key: str, where: str) -> Path:
        if key not in entry:
            raise self.fail(where, f"missing key {key!r} (a file name relative to the plan)")
        name = entry[key]
        if not isinstance(name, str) or not name.strip():
            raise self.fail(f"{where}.{key}", f"expected a file name, got {name!r}")
        path = folder / name
        if not path.is_file():
            raise self.fail(f"{where}.{key}", f"no such file: {path}")
        return path

    def per_axis_int(self, value: Any, where: str, lo: int, hi: int) -> tuple[int, int, int]:
        if isinstance(value, Mapping):
            self.check_keys(value, where, set(AXES))
            out = []
            for a in AXES:
                if a not in value:
                    raise self.fail(where, f"missing {a!r}: give x, y and z")
                out.append(self.integer(value[a], f"{where}.{a}", lo, hi))
            return out[0], out[1], out[2]
        if isinstance(value, list):
            if len(value) != 3:
                raise self.fail(where, f"expected 3 integers (x, y, z), got {value!r}")
            n3 = [self.integer(v, f"{where}[{i}]", lo, hi) for i, v in enumerate(value)]
            return n3[0], n3[1], n3[2]
        n = self.integer(value, where, lo, hi)
        return n, n, n

    def integer(self, value: Any, where: str, lo: int, hi: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise self.fail(where, f"expected an integer in {lo}…{hi}, got {value!r}")
        return int(value)


def read_plan(path: str | Path) -> Plan:
    """Read and validate ``calibration.toml`` (docs/formats.md §10)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CalibrationError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read the plan ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{path}: invalid TOML: {exc}") from None
    c = _Checks(str(path))
    c.check_keys(data, "plan", _TOP)
    fmt = data.get("format", PLAN_FORMAT)
    if fmt != PLAN_FORMAT:
        raise c.fail("format", f"unsupported {fmt!r}; this version reads {PLAN_FORMAT!r}")
    if "model" not in data:
        raise c.fail("model", "missing: name the kinematic model (MB1 … CY1)")
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name.strip():
        raise c.fail("name", f"expected a non-empty text, got {name!r}")
    base = _base_machine(c, data, path, name.strip())
    volume = c.table(data, "volume", "volume")
    steps = DEFAULT_STEPS
    if "steps" in volume:
        steps = c.per_axis_int(volume["steps"], "volume.steps", 2, 200)  # type: ignore[assignment]
    folder = path.parent
    plan = Plan(
        source=path,
        name=name.strip(),
        model=base.model,
        base=base,
        steps=steps,
        fit=_fit(c, c.table(data, "fit", "fit")),
        lasers=tuple(_laser(c, folder, e, i) for i, e in enumerate(c.entries(data, "laser"))),
        plates=tuple(_plate(c, folder, e, i) for i, e in enumerate(c.entries(data, "plate"))),
        multilaterations=tuple(
            _trac(c, folder, e, i) for i, e in enumerate(c.entries(data, "multilateration"))
        ),
    )
    if not (plan.lasers or plan.plates or plan.multilaterations):
        raise c.fail("plan", "no data sets: give [[laser]], [[plate]] or [[multilateration]]")
    return plan


def _base_machine(c: _Checks, data: Mapping[str, Any], path: Path, name: str) -> Machine:
    from ..machine import Machine

    volume = dict(c.table(data, "volume", "volume"))
    c.check_keys(volume, "volume", {"x", "y", "z", "steps", "reference"})
    volume.pop("steps", None)  # the plan's steps are the U grid's (2…200), checked above
    probe = c.table(data, "probe", "probe")
    c.check_keys(probe, "probe", {"offset", "random_um"})
    thermal = dict(c.table(data, "thermal", "thermal"))
    c.check_keys(thermal, "thermal", {"expansion", "workpiece_expansion", "workpiece_fixture"})
    thermal["reference_C"] = c.number(data.get("reference_C", 20.0), "reference_C")
    if not -273.15 <= thermal["reference_C"] <= 1000.0:
        raise c.fail("reference_C", f"{thermal['reference_C']} °C is not in -273.15…1000 °C")
    desc = {"name": name, "model": data["model"], "volume": volume, "thermal": thermal}
    if probe:
        desc["probe"] = dict(probe)
    if not isinstance(desc["model"], str):
        raise c.fail("model", f"expected a model name, got {desc['model']!r}")
    try:
        return Machine.from_dict(desc, source=str(path))
    except MachineFileError as exc:
        raise CalibrationError(str(exc)) from None


def _fit(c: _Checks, tbl: Mapping[str, Any]) -> FitSettings:
    c.check_keys(
        tbl, "fit", {"basis", "nodes", "order", "smoothness", "components", "reversal", "prior"}
    )
    basis = tbl.get("basis", "spline")
    if basis not in ("spline", "polynomial"):
        raise c.fail("fit.basis", f"expected 'spline' or 'polynomial', got {basis!r}")
    nodes = c.per_axis_int(tbl.get("nodes", DEFAULT_NODES), "fit.nodes", 2, 201)
    order = c.per_axis_int(tbl.get("order", DEFAULT_ORDER), "fit.order", 1, 8)
    smooth = tbl.get("smoothness", "auto")
    smoothness = None if smooth == "auto" else c.number(smooth, "fit.smoothness", positive=True)
    comps = tbl.get("components", "all")
    if comps == "all":
        components: tuple[str, ...] = (*TABLE_COMPONENTS, *SQUARENESS)
    else:
        if not isinstance(comps, list) or not comps:
            raise c.fail("fit.components", 'expected "all" or a non-empty array of error names')
        found = []
        for i, name in enumerate(comps):
            canon = canonical_name(name) if isinstance(name, str) else None
            if canon is None:
                raise c.fail(
                    f"fit.components[{i}]",
                    f"unknown error {name!r}; allowed: {', '.join(TABLE_COMPONENTS)}, "
                    "alpha, beta1, beta2 or ISO 230-1 names",
                )
            if canon in found:
                raise c.fail(f"fit.components[{i}]", f"{canon} named twice")
            found.append(canon)
        components = tuple(found)
    reversal = tbl.get("reversal", True)
    if not isinstance(reversal, bool):
        raise c.fail("fit.reversal", f"expected true or false, got {reversal!r}")
    return FitSettings(
        basis=basis,
        nodes=nodes,
        order=order,
        smoothness=smoothness,
        components=components,
        reversal=reversal,
        prior=c.number(tbl.get("prior", PRIOR_DEFAULT), "fit.prior", positive=True),
    )


def _laser(c: _Checks, folder: Path, e: Mapping[str, Any], i: int) -> LaserSpec:
    where = f"laser[{i}]"
    allowed = {"file", *LASER_DEFAULTS, "axis", "line_mm", "optic_offset_mm", "cycles"}
    c.check_keys(e, where, allowed)
    file = c.file(folder, e, "file", where)
    u = {k: c.number(e.get(k, v), f"{where}.{k}", positive=True) for k, v in LASER_DEFAULTS.items()}
    if file.suffix.lower() != ".dat":
        extra = sorted({"axis", "line_mm", "optic_offset_mm", "cycles"} & set(e))
        if extra:
            raise c.fail(where, f"{extra} apply to an ISO 230-2 .dat file only (the CSV has them)")
        return LaserSpec(where=where, file=file, u=u)
    axis = e.get("axis")
    if axis not in AXES:
        raise c.fail(f"{where}.axis", f"an ISO 230-2 file needs the axis: x, y or z, got {axis!r}")
    line = c.vector(e["line_mm"], f"{where}.line_mm", 3) if "line_mm" in e else None
    optic = (
        c.vector(e["optic_offset_mm"], f"{where}.optic_offset_mm", 3)
        if "optic_offset_mm" in e
        else np.zeros(3)
    )
    cycles = None
    if "cycles" in e:
        raw = e["cycles"]
        if not isinstance(raw, list) or not raw:
            raise c.fail(f"{where}.cycles", f"expected an array of cycle numbers, got {raw!r}")
        cycles = tuple(c.integer(v, f"{where}.cycles[{j}]", 1, 10_000) for j, v in enumerate(raw))
        if len(set(cycles)) != len(cycles):
            raise c.fail(f"{where}.cycles", f"a cycle is named twice: {list(cycles)}")
    return LaserSpec(
        where=where, file=file, u=u, axis=axis, line_mm=line, optic_offset_mm=optic, cycles=cycles
    )


def _plate(c: _Checks, folder: Path, e: Mapping[str, Any], i: int) -> PlateSpec:
    where = f"plate[{i}]"
    c.check_keys(e, where, {"balls", "file", "stylus_mm", "probe_um"})
    if "stylus_mm" not in e:
        raise c.fail(where, "missing key 'stylus_mm' (the stylus the plate was probed with, mm)")
    return PlateSpec(
        where=where,
        balls=c.file(folder, e, "balls", where),
        file=c.file(folder, e, "file", where),
        stylus_mm=c.vector(e["stylus_mm"], f"{where}.stylus_mm", 3),
        probe_um=c.number(
            e.get("probe_um", PLATE_PROBE_DEFAULT_UM), f"{where}.probe_um", positive=True
        ),
    )


def _trac(c: _Checks, folder: Path, e: Mapping[str, Any], i: int) -> MultilaterationSpec:
    where = f"multilateration[{i}]"
    c.check_keys(e, where, {"file", "stylus_mm", "station_guess_mm", "u_um"})
    for key in ("stylus_mm", "station_guess_mm"):
        if key not in e:
            raise c.fail(where, f"missing key {key!r}")
    guesses = e["station_guess_mm"]
    if not isinstance(guesses, list) or not guesses:
        raise c.fail(f"{where}.station_guess_mm", "expected an array of [x, y, z] per station")
    guess = np.array(
        [c.vector(g, f"{where}.station_guess_mm[{j}]", 3) for j, g in enumerate(guesses)]
    )
    return MultilaterationSpec(
        where=where,
        file=c.file(folder, e, "file", where),
        stylus_mm=c.vector(e["stylus_mm"], f"{where}.stylus_mm", 3),
        station_guess_mm=guess,
        u_um=c.number(e.get("u_um", TRACKER_DEFAULT_UM), f"{where}.u_um", positive=True),
    )
