"""The uncertainty model of a machine: the ``[uncertainty]`` section of ``machine.toml``
(docs/formats.md §1.11, docs/uncertainty.md), validated and with every default resolved.

Every value is a **standard** uncertainty (k = 1). Units: linear tables µm, angular tables and
squareness µrad, temperatures °C, expansion coefficients µm/(m·°C), positions mm.

Per parametric table the calibration error is one smooth random function along its axis
(:mod:`.fields`)::

    δ(q) = u·Z(q) + u_per_m·(q − q_ref)/1000·ξ₁ + u_relative·value(q)·ξ₂

with Z a unit-variance Gaussian process of squared-exponential correlation
``exp(−Δq²/(2·correlation_mm²))`` and ξ₁, ξ₂ standard normal numbers (one per machine): a
calibration instrument's constant part (reading, alignment, interpolation between targets,
correlated over ``correlation_mm``), its scale part (wavelength, air and material temperature:
exactly linear, fully correlated over the axis) and its gain part (proportional to the value
measured). Its standard uncertainty at q is ``√(u² + (u_per_m·d)² + (u_relative·value)²)``,
d the distance from the reference in m.

Values not given are defaulted (typical laser-interferometer calibration, see
:data:`TABLE_DEFAULTS`); each defaulted value is listed in :attr:`UncertaintyModel.defaulted`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..parametric_errors import AXES, SQUARENESS, TABLE_COMPONENTS, parse_component
from ..toml_checks import TomlChecks

__all__ = [
    "EXPANSION_DEFAULT_FRACTION",
    "PROBE_DEFAULT_UM",
    "SCALE_TEMPERATURE_DEFAULT_C",
    "SQUARENESS_DEFAULT_URAD",
    "TABLE_CLASSES",
    "TABLE_DEFAULTS",
    "TABLE_KEYS",
    "WORKPIECE_TEMPERATURE_DEFAULT_C",
    "TableUncertainty",
    "UncertaintyModel",
    "parse_uncertainty",
    "table_class",
]

FloatArray = NDArray[np.float64]

TABLE_KEYS = ("u", "u_per_m", "u_relative", "correlation_mm")
TABLE_CLASSES = ("positional", "straightness", "angular")

#: Built-in calibration uncertainties (k = 1) per class of table: a laser interferometer's
#: specification ``±(a + b·L + c·reading)`` taken as rectangular (u = limit/√3), rounded.
#: positional: the issue's 0.2 µm + 0.5 µm/m (a ±0.5 ppm system in a controlled room);
#: straightness: ±(0.5 µm + 0.5 % of the reading), u_per_m for the optics' range term;
#: angular: ±(0.5 µrad + 0.2 % of the reading + 0.1 µrad/m).
TABLE_DEFAULTS: dict[str, dict[str, float]] = {
    "positional": {"u": 0.2, "u_per_m": 0.5, "u_relative": 0.0},
    "straightness": {"u": 0.3, "u_per_m": 0.1, "u_relative": 0.003},
    "angular": {"u": 0.3, "u_per_m": 0.06, "u_relative": 0.0012},
}
SQUARENESS_DEFAULT_URAD = 1.0  # squareness from a square, ball bar or laser diagonals
SCALE_TEMPERATURE_DEFAULT_C = 0.1  # a calibrated Pt100 on the scale
EXPANSION_DEFAULT_FRACTION = 0.10  # u of an expansion coefficient: 10 % of its value
WORKPIECE_TEMPERATURE_DEFAULT_C = 0.2  # a contact sensor on the workpiece
PROBE_DEFAULT_UM = 0.5  # one probing, per component, when [probe] random_um is not given
_SECTION_KEYS = {
    "probe_um",
    "squareness",
    "scale_temperature_C",
    "expansion",
    "workpiece_temperature_C",
    "workpiece_expansion",
    "errors",
    *TABLE_CLASSES,
}


def table_class(component: str) -> str:
    """``positional``, ``straightness`` or ``angular`` for a table component (our name)."""
    comp = parse_component(component)
    if comp.is_positional:
        return "positional"
    return "straightness" if comp.is_straightness else "angular"


@dataclass(frozen=True)
class TableUncertainty:
    """Calibration uncertainty (k = 1) of one parametric table, in the table's unit (µm or µrad).

    ``span_mm``: the positions its random function lives on (the tabulated span, else the
    axis travel); outside it the value at the nearest end holds, as for the table itself.
    """

    component: str
    axis: str
    u: float
    u_per_m: float
    u_relative: float
    correlation_mm: float
    span_mm: tuple[float, float]
    reference_mm: float

    def std(self, q_mm: FloatArray, value: FloatArray) -> FloatArray:
        """Standard uncertainty at axis positions ``q_mm`` given the table's ``value`` there."""
        q = np.clip(np.asarray(q_mm, dtype=float), *self.span_mm)
        d_m = (q - self.reference_mm) / 1000.0
        return np.sqrt(self.u**2 + (self.u_per_m * d_m) ** 2 + (self.u_relative * value) ** 2)

    def covariance(
        self, qa_mm: FloatArray, qb_mm: FloatArray, value_a: FloatArray, value_b: FloatArray
    ) -> FloatArray:
        """Covariance of the calibration error between positions ``qa`` and ``qb`` (analytic)."""
        qa = np.clip(np.asarray(qa_mm, dtype=float), *self.span_mm)
        qb = np.clip(np.asarray(qb_mm, dtype=float), *self.span_mm)
        rho = np.exp(-0.5 * ((qa - qb) / self.correlation_mm) ** 2)
        da, db = (qa - self.reference_mm) / 1000.0, (qb - self.reference_mm) / 1000.0
        return (
            self.u**2 * rho
            + self.u_per_m**2 * da * db
            + self.u_relative**2 * np.asarray(value_a) * np.asarray(value_b)
        )

    @property
    def is_zero(self) -> bool:
        return self.u == 0.0 and self.u_per_m == 0.0 and self.u_relative == 0.0


@dataclass(frozen=True)
class UncertaintyModel:
    """The standard uncertainties (k = 1) of a machine's inputs, defaults resolved.

    ``tables`` holds a :class:`TableUncertainty` for every table (and for every component
    without a table that the file gives an uncertainty for); ``squareness_urad`` (α, β1, β2);
    ``scale_temperature_C`` and ``expansion`` per axis (sensor reading, expansion coefficient
    µm/(m·°C)); ``workpiece_*`` likewise; ``probe_um`` one probing, per component.
    ``defaulted`` names every value that was not in the file; ``zero`` the components taken
    as exactly zero (no table, no uncertainty); ``notes`` what is left out.
    """

    tables: dict[str, TableUncertainty]
    squareness_urad: FloatArray
    scale_temperature_C: FloatArray
    expansion: FloatArray
    workpiece_temperature_C: float
    workpiece_expansion: float
    probe_um: float
    defaulted: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    given: dict[str, Any] = field(default_factory=dict)
    zero: tuple[str, ...] = ()
    """Components with neither a table nor an uncertainty: taken as exactly zero."""

    def describe(self) -> dict[str, Any]:
        """JSON-able summary: every value used, the defaulted ones and the notes."""
        return {
            "standard_uncertainties_k1": {
                "tables": {
                    c: {
                        "u": t.u,
                        "u_per_m": t.u_per_m,
                        "u_relative": t.u_relative,
                        "correlation_mm": t.correlation_mm,
                    }
                    for c, t in sorted(self.tables.items())
                },
                "squareness_urad": dict(
                    zip(SQUARENESS, self.squareness_urad.tolist(), strict=True)
                ),
                "scale_temperature_C": dict(
                    zip(AXES, self.scale_temperature_C.tolist(), strict=True)
                ),
                "expansion_um_per_m_C": dict(zip(AXES, self.expansion.tolist(), strict=True)),
                "workpiece_temperature_C": self.workpiece_temperature_C,
                "workpiece_expansion_um_per_m_C": self.workpiece_expansion,
                "probe_um": self.probe_um,
            },
            "defaulted": list(self.defaulted),
            "taken_as_zero": list(self.zero),
            "notes": list(self.notes),
        }


class _Reader(TomlChecks):
    """Validation of the ``[uncertainty]`` table: one :class:`MachineFileError` per problem."""

    def __init__(self, source: str) -> None:
        super().__init__(source)
        self.defaulted: list[str] = []

    def number(self, value: Any, where: str, *, positive: bool = False) -> float:
        """A finite number ≥ 0 (a standard uncertainty); ``positive``: > 0."""
        out = super().number(value, where, positive=positive)
        if out < 0:
            raise self.fail(where, f"a standard uncertainty must be ≥ 0, got {value!r}")
        if out > 1e9:  # 1e300 overflowed the covariance into a traceback (OverflowError)
            raise self.fail(
                where, f"{value!r} is beyond 1e9: no standard uncertainty (check the unit)"
            )
        return out

    def table(self, value: Any, where: str, allowed: set[str]) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(where, f"expected a table, got {value!r}")
        self.check_keys(value, where, allowed)
        return value

    def per_name(
        self, tbl: Mapping[str, Any], key: str, names: tuple[str, ...]
    ) -> dict[str, float] | None:
        """A number for all names, an inline table by name (missing names: None), or absent."""
        if key not in tbl:
            return None
        where = f"uncertainty.{key}"
        value = tbl[key]
        if isinstance(value, Mapping):
            inner = self.table(value, where, set(names))
            return {n: self.number(inner[n], f"{where}.{n}") for n in names if n in inner}
        number = self.number(value, where)
        return dict.fromkeys(names, number)


def parse_uncertainty(
    data: Mapping[str, Any] | None,
    *,
    source: str,
    tables: Mapping[str, Any],
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    reference_mm: FloatArray,
    expansion: FloatArray,
    workpiece_expansion: float | None,
    probe_random_um: float,
) -> UncertaintyModel:
    """Validate the ``[uncertainty]`` table ``data`` (None: absent) of a machine with these
    ``tables`` (component → :class:`..tables.ErrorTable`), volume, thermal data and probe;
    resolve the defaults and record which values were defaulted. :class:`MachineFileError`
    (naming ``source`` and the key) on any problem."""
    r = _Reader(source)
    sec = r.table(data or {}, "uncertainty", _SECTION_KEYS)
    notes: list[str] = []

    # ---- per-table calibration uncertainty
    classes: dict[str, Mapping[str, Any]] = {}
    for cls in TABLE_CLASSES:
        if cls in sec:
            classes[cls] = r.table(sec[cls], f"uncertainty.{cls}", set(TABLE_KEYS))
    explicit: dict[str, Mapping[str, Any]] = {}
    errors_tbl = sec.get("errors", {})
    if not isinstance(errors_tbl, Mapping):
        raise r.fail(
            "uncertainty.errors", f"expected tables [uncertainty.errors.<name>], got {errors_tbl!r}"
        )
    for key, value in errors_tbl.items():
        where = f"uncertainty.errors.{key}"
        canon = r.error_component(key, where, explicit)
        explicit[canon] = r.table(value, where, set(TABLE_KEYS))
    out_tables: dict[str, TableUncertainty] = {}
    for comp in TABLE_COMPONENTS:
        table = tables.get(comp)
        if table is None and comp not in explicit:
            continue
        cls = table_class(comp)
        axis = comp[-1]
        k = AXES.index(axis)
        span = getattr(table, "span_mm", None) if table is not None else None
        if span is None or span[1] <= span[0]:
            span = (float(lower_mm[k]), float(upper_mm[k]))
        own = explicit.get(comp, {})
        values: dict[str, float] = {}
        for key in ("u", "u_per_m", "u_relative"):
            where = f"uncertainty.errors.{comp}.{key}"
            if key in own:
                values[key] = r.number(own[key], where)
            elif key in classes.get(cls, {}):
                values[key] = r.number(classes[cls][key], f"uncertainty.{cls}.{key}")
            elif table is None:
                values[key] = 0.0  # an unmeasured error: only what the file says
            else:
                values[key] = TABLE_DEFAULTS[cls][key]
                r.defaulted.append(where)
        where = f"uncertainty.errors.{comp}.correlation_mm"
        if "correlation_mm" in own:
            corr = r.number(own["correlation_mm"], where, positive=True)
        elif "correlation_mm" in classes.get(cls, {}):
            corr = r.number(
                classes[cls]["correlation_mm"], f"uncertainty.{cls}.correlation_mm", positive=True
            )
        else:
            corr = _default_correlation_mm(table, span)
            r.defaulted.append(where)
        out_tables[comp] = TableUncertainty(
            component=comp,
            axis=axis,
            u=values["u"],
            u_per_m=values["u_per_m"],
            u_relative=values["u_relative"],
            correlation_mm=corr,
            span_mm=(float(span[0]), float(span[1])),
            reference_mm=float(reference_mm[k]),
        )
    missing = [c for c in TABLE_COMPONENTS if c not in out_tables]
    if missing:
        notes.append(
            f"no table and no uncertainty for {', '.join(missing)}: taken as exactly zero "
            "(give [uncertainty.errors.<name>] u = … to account for an unmeasured error)"
        )

    # ---- squareness
    sq_given = r.per_name(sec, "squareness", SQUARENESS) or {}
    squareness = np.zeros(3)
    for j, name in enumerate(SQUARENESS):
        if name in sq_given:
            squareness[j] = sq_given[name]
        else:
            squareness[j] = SQUARENESS_DEFAULT_URAD
            r.defaulted.append(f"uncertainty.squareness.{name}")

    # ---- thermal: scales (only axes with a thermal term need defaults)
    temp_given = r.per_name(sec, "scale_temperature_C", AXES) or {}
    exp_given = r.per_name(sec, "expansion", AXES) or {}
    u_temp, u_exp = np.zeros(3), np.zeros(3)
    for k, axis in enumerate(AXES):
        has_term = float(expansion[k]) != 0.0
        if axis in temp_given:
            u_temp[k] = temp_given[axis]
        elif has_term:
            u_temp[k] = SCALE_TEMPERATURE_DEFAULT_C
            r.defaulted.append(f"uncertainty.scale_temperature_C.{axis}")
        if axis in exp_given:
            u_exp[k] = exp_given[axis]
        elif has_term:
            u_exp[k] = EXPANSION_DEFAULT_FRACTION * abs(float(expansion[k]))
            r.defaulted.append(f"uncertainty.expansion.{axis}")
    if not np.any(np.asarray(expansion) != 0.0) and not exp_given:
        notes.append("the machine has no scale expansion terms: scale temperatures not used")

    # ---- thermal: workpiece
    wp_temp = wp_exp = 0.0
    has_wp = bool(workpiece_expansion)
    if "workpiece_temperature_C" in sec:
        wp_temp = r.number(sec["workpiece_temperature_C"], "uncertainty.workpiece_temperature_C")
    elif has_wp:
        wp_temp = WORKPIECE_TEMPERATURE_DEFAULT_C
        r.defaulted.append("uncertainty.workpiece_temperature_C")
    if "workpiece_expansion" in sec:
        wp_exp = r.number(sec["workpiece_expansion"], "uncertainty.workpiece_expansion")
    elif has_wp:
        wp_exp = EXPANSION_DEFAULT_FRACTION * abs(float(workpiece_expansion or 0.0))
        r.defaulted.append("uncertainty.workpiece_expansion")
    if not has_wp:
        notes.append(
            "the machine has no workpiece expansion term: the workpiece's expansion is not "
            "corrected and not part of the uncertainty"
        )

    # ---- probing
    if "probe_um" in sec:
        probe = r.number(sec["probe_um"], "uncertainty.probe_um")
    elif probe_random_um > 0:
        probe = probe_random_um / 2.0
        notes.append("probe_um from [probe] random_um (a 2σ value): σ = random_um / 2")
    else:
        probe = PROBE_DEFAULT_UM
        r.defaulted.append("uncertainty.probe_um")
    notes.append(
        "the random parts of the tables ([errors.*] random, random_band: 2σ bands) are "
        "independent at every probing"
    )
    return UncertaintyModel(
        tables=out_tables,
        squareness_urad=squareness,
        scale_temperature_C=u_temp,
        expansion=u_exp,
        workpiece_temperature_C=wp_temp,
        workpiece_expansion=wp_exp,
        probe_um=probe,
        defaulted=tuple(r.defaulted),
        notes=tuple(notes),
        given=dict(sec),
        zero=tuple(missing),
    )


def _default_correlation_mm(table: Any, span: tuple[float, float]) -> float:
    """The mean spacing of a tabulated table's positions (the calibration targets), else a
    quarter of the span (a polynomial or curve: the paper's few-point curve input)."""
    pos = getattr(table, "position_mm", None) if table is not None else None
    if pos is not None and len(pos) >= 2 and getattr(table, "polynomial", None) is None:
        return float((pos[-1] - pos[0]) / (len(pos) - 1))
    return float(span[1] - span[0]) / 4.0
