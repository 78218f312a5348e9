"""The uncertainty model of a machine: the ``[uncertainty]`` section of ``machine.toml``
(docs/formats.md §1.11, docs/uncertainty.md): its keys and rules (:class:`UncertaintySection`,
checked with the rest of the file, :mod:`..formats.machine_schema`) and the model with every
default resolved (:func:`resolve_uncertainty`).

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
from typing import Annotated, Any

import numpy as np
from numpy.typing import NDArray

from ..parametric_errors import (
    AXES,
    SQUARENESS,
    TABLE_COMPONENTS,
    bad_component_keys,
    canonical_name,
    parse_component,
)
from ..toml_schema import Num, Rule, Spread, Table

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
    "UncertaintySection",
    "resolve_uncertainty",
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

#: A standard uncertainty: finite, ≥ 0 and at most 1e9 (1e300 overflowed the covariance).
STANDARD_U = Num(0.0, 1e9, note="a standard uncertainty, k = 1: check the unit")


def _u(unit: str) -> Num:
    """:data:`STANDARD_U` in ``unit``."""
    return Num(STANDARD_U.lo, STANDARD_U.hi, unit, note=STANDARD_U.note)


@dataclass
class TableUncertaintySection(Table):
    """``[uncertainty.errors.<name>]`` or ``[uncertainty.<class>]``: one table's (or every table
    of a class's) calibration uncertainty, in the table's unit (µm or µrad)."""

    u: Annotated[float, STANDARD_U] | None = None
    """Constant part (unit of the table)."""
    u_per_m: Annotated[float, STANDARD_U] | None = None
    """Scale part per m from the reference."""
    u_relative: Annotated[float, STANDARD_U] | None = None
    """Gain part: a fraction of the table's value."""
    correlation_mm: Annotated[float, Num(0.0, 1e9, "mm", lo_open=True)] | None = None
    """Over how many mm the constant part stays alike."""


@dataclass
class SquarenessUncertainty(Table):
    """u of α, β1, β2 (µrad), one number for all three or by name."""

    alpha: Annotated[float, _u("µrad")] | None = None
    beta1: Annotated[float, _u("µrad")] | None = None
    beta2: Annotated[float, _u("µrad")] | None = None


@dataclass
class AxisUncertainty(Table):
    """A value per axis (x, y, z), one number for all three or by axis."""

    x: Annotated[float, STANDARD_U] | None = None
    y: Annotated[float, STANDARD_U] | None = None
    z: Annotated[float, STANDARD_U] | None = None


@dataclass
class UncertaintySection(Table):
    """``[uncertainty]`` of ``machine.toml``: standard uncertainties (k = 1) of the machine's
    inputs; a value not given is defaulted (:func:`resolve_uncertainty`)."""

    probe_um: Annotated[float, _u("µm")] | None = None
    """Probing error of one point, each component (σ), µm."""
    squareness: Annotated[SquarenessUncertainty, Spread(SQUARENESS, _u("µrad"))] | None = None
    """u of α, β1, β2, µrad: a number or ``{alpha, beta1, beta2}``."""
    scale_temperature_C: Annotated[AxisUncertainty, Spread(AXES, _u("°C"))] | None = None
    """u of the temperature each scale sensor reads, °C: a number or ``{x, y, z}``."""
    expansion: Annotated[AxisUncertainty, Spread(AXES, _u("µm/(m·°C)"))] | None = None
    """u of each scale's expansion coefficient, µm/(m·°C): a number or ``{x, y, z}``."""
    workpiece_temperature_C: Annotated[float, _u("°C")] | None = None
    """u of the workpiece sensor, °C."""
    workpiece_expansion: Annotated[float, _u("µm/(m·°C)")] | None = None
    """u of the workpiece coefficient, µm/(m·°C)."""
    errors: Annotated[dict[str, TableUncertaintySection], Rule(bad_component_keys, raw=True)] = (
        field(default_factory=dict)
    )
    """Per table (our names or ISO 230-1 aliases)."""
    positional: TableUncertaintySection | None = None
    """For every positional table without its own entry."""
    straightness: TableUncertaintySection | None = None
    """For every straightness table without its own entry."""
    angular: TableUncertaintySection | None = None
    """For every angular table without its own entry."""


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


def resolve_uncertainty(
    section: UncertaintySection | None,
    *,
    tables: Mapping[str, Any],
    lower_mm: FloatArray,
    upper_mm: FloatArray,
    reference_mm: FloatArray,
    expansion: FloatArray,
    workpiece_expansion: float | None,
    probe_random_um: float,
    given: Mapping[str, Any] | None = None,
) -> UncertaintyModel:
    """The uncertainty model of a machine with these ``tables`` (component →
    :class:`..tables.ErrorTable`), volume, thermal data and probe, from its checked
    ``[uncertainty]`` section (None: absent): every value not given defaulted and recorded."""
    sec = section or UncertaintySection()
    defaulted: list[str] = []
    notes: list[str] = []

    # ---- per-table calibration uncertainty
    explicit = {str(canonical_name(k)): v for k, v in sec.errors.items()}
    out_tables: dict[str, TableUncertainty] = {}
    for comp in TABLE_COMPONENTS:
        table = tables.get(comp)
        if table is None and comp not in explicit:
            continue
        cls = table_class(comp)
        by_class: TableUncertaintySection | None = getattr(sec, cls)
        axis = comp[-1]
        k = AXES.index(axis)
        span = getattr(table, "span_mm", None) if table is not None else None
        if span is None or span[1] <= span[0]:
            span = (float(lower_mm[k]), float(upper_mm[k]))
        own = explicit.get(comp)
        values: dict[str, float] = {}
        for key in TABLE_KEYS:
            value = getattr(own, key) if own is not None else None
            if value is None and by_class is not None:
                value = getattr(by_class, key)
            if value is None and key == "correlation_mm":
                value = _default_correlation_mm(table, span)
                defaulted.append(f"uncertainty.errors.{comp}.{key}")
            elif value is None and table is None:
                value = 0.0  # an unmeasured error: only what the file says
            elif value is None:
                value = TABLE_DEFAULTS[cls][key]
                defaulted.append(f"uncertainty.errors.{comp}.{key}")
            values[key] = float(value)
        out_tables[comp] = TableUncertainty(
            component=comp,
            axis=axis,
            span_mm=(float(span[0]), float(span[1])),
            reference_mm=float(reference_mm[k]),
            **values,
        )
    missing = [c for c in TABLE_COMPONENTS if c not in out_tables]
    if missing:
        notes.append(
            f"no table and no uncertainty for {', '.join(missing)}: taken as exactly zero "
            "(give [uncertainty.errors.<name>] u = … to account for an unmeasured error)"
        )

    # ---- squareness
    squareness = np.zeros(3)
    for j, name in enumerate(SQUARENESS):
        value = getattr(sec.squareness, name) if sec.squareness is not None else None
        if value is None:
            value = SQUARENESS_DEFAULT_URAD
            defaulted.append(f"uncertainty.squareness.{name}")
        squareness[j] = value

    # ---- thermal: scales (only axes with a thermal term need defaults)
    u_temp, u_exp = np.zeros(3), np.zeros(3)
    for k, axis in enumerate(AXES):
        has_term = float(expansion[k]) != 0.0
        temp = getattr(sec.scale_temperature_C, axis) if sec.scale_temperature_C else None
        if temp is not None:
            u_temp[k] = temp
        elif has_term:
            u_temp[k] = SCALE_TEMPERATURE_DEFAULT_C
            defaulted.append(f"uncertainty.scale_temperature_C.{axis}")
        alpha = getattr(sec.expansion, axis) if sec.expansion else None
        if alpha is not None:
            u_exp[k] = alpha
        elif has_term:
            u_exp[k] = EXPANSION_DEFAULT_FRACTION * abs(float(expansion[k]))
            defaulted.append(f"uncertainty.expansion.{axis}")
    exp_given = sec.expansion is not None and any(
        getattr(sec.expansion, a) is not None for a in AXES
    )
    if not np.any(np.asarray(expansion) != 0.0) and not exp_given:
        notes.append("the machine has no scale expansion terms: scale temperatures not used")

    # ---- thermal: workpiece
    wp_temp = wp_exp = 0.0
    has_wp = bool(workpiece_expansion)
    if sec.workpiece_temperature_C is not None:
        wp_temp = sec.workpiece_temperature_C
    elif has_wp:
        wp_temp = WORKPIECE_TEMPERATURE_DEFAULT_C
        defaulted.append("uncertainty.workpiece_temperature_C")
    if sec.workpiece_expansion is not None:
        wp_exp = sec.workpiece_expansion
    elif has_wp:
        wp_exp = EXPANSION_DEFAULT_FRACTION * abs(float(workpiece_expansion or 0.0))
        defaulted.append("uncertainty.workpiece_expansion")
    if not has_wp:
        notes.append(
            "the machine has no workpiece expansion term: the workpiece's expansion is not "
            "corrected and not part of the uncertainty"
        )

    # ---- probing
    if sec.probe_um is not None:
        probe = sec.probe_um
    elif probe_random_um > 0:
        probe = probe_random_um / 2.0
        notes.append("probe_um from [probe] random_um (a 2σ value): σ = random_um / 2")
    else:
        probe = PROBE_DEFAULT_UM
        defaulted.append("uncertainty.probe_um")
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
        defaulted=tuple(defaulted),
        notes=tuple(notes),
        given=dict(given or {}),
        zero=tuple(missing),
    )


def _default_correlation_mm(table: Any, span: tuple[float, float]) -> float:
    """The mean spacing of a tabulated table's positions (the calibration targets), else a
    quarter of the span (a polynomial or curve: the paper's few-point curve input)."""
    pos = getattr(table, "position_mm", None) if table is not None else None
    if pos is not None and len(pos) >= 2 and getattr(table, "polynomial", None) is None:
        return float((pos[-1] - pos[0]) / (len(pos) - 1))
    return float(span[1] - span[0]) / 4.0
