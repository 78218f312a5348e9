"""The keys of ``machine.toml`` (docs/formats.md §1) and their rules, checked by pydantic
(:mod:`..toml_schema`): every problem of a file at once, each naming the file and the key path.
:mod:`.machine_parser` builds the parts of a machine from the checked definitions.

Units as in the file: positions mm, linear errors µm, angles µrad, temperatures °C, expansion
coefficients µm/(m·°C). Every number is finite; sizes are bounded where a value beyond them is a
unit mistake rather than a machine (a travel or stylus beyond ±1e6 mm = 1 km, a random part
beyond 1e9 µm, a temperature outside −273.15…1000 °C).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar

import numpy as np

from ..effects.base import effect_from_table
from ..kinematics import Chain
from ..models import known_models, model_code
from ..parametric_errors import SQUARENESS, bad_component_keys
from ..straightness import CRITERIA
from ..tables import MAX_POLYNOMIAL_ORDER, fit_polynomial
from ..toml_schema import Choice, Num, Problem, Rule, Table, Vec, usable
from ..uncertainty.model import UncertaintySection

FORMAT = "cmm-machine/1"
MAX_TABLE_POINTS = 100_000

_MM = Num(-1e6, 1e6, "mm", note="1 km: check the unit")
_POINT_MM = Vec(_MM, n=3)
_FINITE_3 = Vec(Num(), n=3)
_VALUES = Vec(Num(), max_n=MAX_TABLE_POINTS)
_BAND = Num(0.0, None)
_EXPANSION = Num(-1e6, 1e6, "µm/(m·°C)")
_COEFFICIENTS = Vec(
    Num(), min_n=1, max_n=MAX_POLYNOMIAL_ORDER + 1, note=f"order ≤ {MAX_POLYNOMIAL_ORDER}"
)


def _lower_upper(pair: list[float]) -> Iterable[Problem]:
    if not pair[1] > pair[0]:
        yield f"upper ({pair[1]}) must be greater than lower ({pair[0]})"


def _non_empty(name: str) -> Iterable[Problem]:
    if not name.strip():
        yield "a non-empty machine name is required"


def _supported(fmt: str) -> Iterable[Problem]:
    if fmt != FORMAT:
        yield f"unsupported format {fmt!r}; this version reads {FORMAT!r}"


def _effects(tables: list[dict[str, Any]]) -> Iterable[Problem]:
    for i, table in enumerate(tables):
        try:
            effect_from_table(table)
        except (ValueError, KeyError, TypeError) as exc:
            yield (i,), str(exc)


_SPAN = Vec(_MM, n=2)


@dataclass
class VolumeSection(Table):
    """``[volume]``: the working volume, mm."""

    x: Annotated[list[float], _SPAN, Rule(_lower_upper)]
    """``[lower, upper]`` travel of X, mm."""
    y: Annotated[list[float], _SPAN, Rule(_lower_upper)]
    """``[lower, upper]`` travel of Y, mm."""
    z: Annotated[list[float], _SPAN, Rule(_lower_upper)]
    """``[lower, upper]`` travel of Z, mm."""
    reference: Annotated[list[float], _FINITE_3] | None = None
    """``(x0, y0, z0)`` mm, the point all parametric errors are referred to (default: the lower
    corner)."""
    steps: Annotated[list[int], Vec(Num(2, 1000), n=3)] | None = None
    """Nodes per axis for maps and the starting point for grids."""


@dataclass
class ProbeSection(Table):
    """``[probe]``: the stylus."""

    offset: Annotated[list[float], _POINT_MM] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    """Stylus tip offset (Xp, Yp, Zp) from the ram reference point, mm."""
    random_um: Annotated[float, Num(0.0, 1e9, "µm")] = 0.0
    """Random probing error (2σ), µm."""


@dataclass
class ExpansionSection(Table):
    """Effective expansion coefficient of each axis' scale, µm/(m·°C)."""

    x: Annotated[float, _EXPANSION] = 0.0
    y: Annotated[float, _EXPANSION] = 0.0
    z: Annotated[float, _EXPANSION] = 0.0


@dataclass
class ThermalSection(Table):
    """``[thermal]``: the thermal reference and expansion coefficients."""

    reference_C: Annotated[float, Num(-273.15, 1000.0, "°C")] = 20.0
    """Thermal reference temperature, °C."""
    expansion: ExpansionSection = field(default_factory=ExpansionSection)
    """Effective expansion coefficient of each axis' scale, µm/(m·°C)."""
    workpiece_expansion: Annotated[float, _EXPANSION] | None = None
    """Workpiece expansion coefficient, µm/(m·°C)."""
    workpiece_fixture: Annotated[list[float], _POINT_MM] | None = None
    """The point the workpiece grows from, mm (default: ``volume.reference``)."""


@dataclass
class SquarenessRandom(Table):
    """The three squareness angles, µrad: the paper's α (XY), β1 (XZ), β2 (YZ)."""

    alpha: Annotated[float, Num(unit="µrad")] = 0.0
    """Squareness XY, µrad."""
    beta1: Annotated[float, Num(unit="µrad")] = 0.0
    """Squareness XZ, µrad."""
    beta2: Annotated[float, Num(unit="µrad")] = 0.0
    """Squareness YZ, µrad."""

    def values(self) -> np.ndarray:
        """(α, β1, β2) µrad."""
        return np.array([getattr(self, k) for k in SQUARENESS], dtype=float)


@dataclass
class SquarenessSection(SquarenessRandom):
    """``[squareness]``, µrad, with their random part and where they were measured."""

    random: SquarenessRandom = field(default_factory=SquarenessRandom)
    """Random part (2σ) of each, µrad: ``{alpha = …, beta1 = …, beta2 = …}``."""
    offset: Annotated[list[float], _FINITE_3] | None = None
    """``[x, y, z]`` mm where the two lines that gave the squareness were measured."""


@dataclass
class CurveSection(Table):
    """``curve = {position, value, order}``: a least-squares polynomial through a few points."""

    position: Annotated[list[float], Vec(Num(), min_n=1, max_n=MAX_TABLE_POINTS)]
    """Axis positions, mm."""
    value: Annotated[list[float], _VALUES]
    """Values at them (µm or µrad)."""
    order: Annotated[int, Num(0, MAX_POLYNOMIAL_ORDER)] | None = None
    """Polynomial order (default min(3, points − 1))."""

    def polynomial(self) -> np.ndarray:
        order = self.order if self.order is not None else min(3, len(self.position) - 1)
        return fit_polynomial(np.array(self.position), np.array(self.value), order)

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        if not usable(context, "position", "value", "order"):
            return
        if len(self.value) != len(self.position):
            yield ("value",), f"expected {len(self.position)} numbers, got {len(self.value)}"
            return
        try:
            self.polynomial()
        except ValueError as exc:
            yield str(exc)


@dataclass
class ErrorTableSection(Table):
    """``[errors.<name>]``: one parametric error table (one source of values: ``position`` and
    ``value``, ``file``, ``polynomial`` or ``curve``)."""

    position: Annotated[list[float], _VALUES] | None = None
    """Axis positions, mm, strictly increasing."""
    value: Annotated[list[float], _VALUES] | None = None
    """Values at the positions, µm or µrad."""
    random: Annotated[list[float], Vec(_BAND, max_n=MAX_TABLE_POINTS)] | None = None
    """Random part (2σ band) at each position, ≥ 0."""
    offset: Annotated[list[float], _FINITE_3] | None = None
    """``[x, y, z]`` mm where the line was measured."""
    criterion: Annotated[str, Choice(CRITERIA)] | None = None
    """Straightness reference line removed from the values."""
    file: str | None = None
    """A CSV next to the TOML file: columns position,value[,random]."""
    reversal: Annotated[list[float], _VALUES] | None = None
    """Half reversal at each position, µm (positional tables)."""
    polynomial: Annotated[list[float], _COEFFICIENTS] | None = None
    """Coefficients c0, c1, … in the axis position (mm)."""
    curve: CurveSection | None = None
    """A least-squares polynomial through a few measured points."""
    random_band: Annotated[float, _BAND] | None = None
    """A uniform random part (2σ) over the whole span, ≥ 0."""
    unit: str | None = None
    """Free text for people (not written back)."""
    note: str | None = None
    """Free text for people (not written back)."""
    columns: Any = field(default=None, init=False, repr=False)
    """The ``file``'s position, value and random columns, once read."""

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        keys = ("position", "file", "polynomial", "curve")
        if not usable(context, *keys) or context.get("unknown"):  # a source key misspelt?
            return
        if sum(getattr(self, k) is not None for k in keys) != 1:
            yield "give exactly one of position/value, file, polynomial or curve"
            return
        if self.file is not None and usable(context, "file"):
            try:
                self.columns = read_table_csv(Path(context.get("base_dir", ".")) / self.file)
            except ValueError as exc:
                yield ("file",), str(exc)
                return
        if self.position is not None and self.value is None and usable(context, "value"):
            yield "position given without value"
            return
        yield from self._lengths(context)
        if self.criterion is not None and self.position is None and self.columns is None:
            yield ("criterion",), "a criterion needs tabulated values (position/value or file)"

    def tabulated(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """Positions, values and random part of a tabulated or file table (else None)."""
        if self.columns is not None:
            position, value, random = self.columns
            if self.random is not None:
                random = np.array(self.random, dtype=float)
            return position, value, random
        if self.position is None or self.value is None:
            return None
        random = None if self.random is None else np.array(self.random, dtype=float)
        return np.array(self.position, float), np.array(self.value, float), random

    def _lengths(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        if not usable(context, "position", "value", "random", "reversal"):
            return
        table = self.tabulated()
        if table is None:
            return
        position, value, random = table
        n = len(position)
        if n == 0:
            yield "empty table"
            return
        if len(value) != n:
            yield f"position has {n} values but value has {len(value)}"
        if random is not None and len(random) != n:
            yield f"random has {len(random)} values, position {n}"
        if random is not None and np.any(random < 0):
            yield ("random",), "random bands must be ≥ 0"
        if self.reversal is not None and len(self.reversal) != n:
            yield f"reversal has {len(self.reversal)} values, position {n}"
        step = np.diff(position) <= 0
        if np.any(step):
            i = int(np.argmax(step)) + 1
            where = "position" if self.columns is None else "file"
            yield (where,), f"positions must increase strictly (index {i}: {position[i]})"


def _reversal_positional(tables: Mapping[str, ErrorTableSection]) -> Iterable[Problem]:
    from ..parametric_errors import canonical_name, parse_component

    for key, table in tables.items():
        known = canonical_name(key) is not None and not bad_component_keys({key: table})
        if known and table.reversal is not None and not parse_component(key).is_positional:
            yield (
                (key, "reversal"),
                "a reversal applies to positional tables (dx_x, dy_y, dz_z) only",
            )


@dataclass
class ChainSection(Table):
    """``[chain]``: the kinematic chain of a machine none of the ten models describes."""

    tool: list[str] = field(default_factory=list)
    """Axes carrying the stylus, base → stylus."""
    workpiece: list[str] = field(default_factory=list)
    """Axes carrying the table, base → table."""

    def chain(self) -> Chain:
        return Chain(tool=tuple(self.tool), workpiece=tuple(self.workpiece))

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        if usable(context, "tool", "workpiece"):
            try:
                self.chain()
            except ValueError as exc:
                yield str(exc)


@dataclass
class ArmDeflectionSection(Table):
    """``[arm_deflection]``: the φ terms of the horizontal-arm models, µrad/m."""

    phi1: Annotated[float, Num(unit="µrad/m")] = 0.0
    """Load-dependent tilt per m of arm travel, µrad/m."""
    phi2: Annotated[float, Num(unit="µrad/m")] = 0.0
    """Droop curvature of the arm, µrad/m."""


_TABLES = (
    "volume",
    "probe",
    "thermal",
    "squareness",
    "errors",
    "chain",
    "arm_deflection",
    "effects",
    "meta",
    "uncertainty",
)


@dataclass
class MachineFile(Table):
    """``machine.toml``: one machine. Top-level keys besides these are kept as given (and
    written back); an unknown table is refused."""

    __pydantic_config__: ClassVar[dict[str, Any]] = {
        **Table.__pydantic_config__,
        "extra": "ignore",  # other scalars are kept in the description, unchecked
    }

    name: Annotated[str, Rule(_non_empty)]
    """Non-empty free text; also the prefix of seed-style file sets."""
    volume: VolumeSection
    """The working volume."""
    format: Annotated[str, Rule(_supported)] = FORMAT
    """File format."""
    model: str | None = None
    """One of the ten kinematic models (code or alias); free text with ``[chain]``."""
    probe: ProbeSection = field(default_factory=ProbeSection)
    thermal: ThermalSection = field(default_factory=ThermalSection)
    squareness: SquarenessSection = field(default_factory=SquarenessSection)
    errors: Annotated[
        dict[str, ErrorTableSection],
        Rule(bad_component_keys, raw=True),
        Rule(_reversal_positional),
    ] = field(default_factory=dict)
    """One table per measured component (absent = zero)."""
    chain: ChainSection | None = None
    arm_deflection: ArmDeflectionSection = field(default_factory=ArmDeflectionSection)
    effects: Annotated[list[dict[str, Any]], Rule(_effects)] = field(default_factory=list)
    """``[[effects]]``: terms beyond the rigid-body model, each with its ``cause``."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Free text for people, kept and written back."""
    uncertainty: UncertaintySection | None = None
    """The uncertainty model (§1.11)."""

    @classmethod
    def unknown_key(cls, key: str, value: Any) -> str | None:
        is_table = isinstance(value, Mapping) or (
            isinstance(value, list) and any(isinstance(v, Mapping) for v in value)
        )
        return f"unknown table; known: {', '.join(sorted(_TABLES))}" if is_table else None

    def model_code(self) -> str:
        """The model's code (``custom`` or the free text given with a ``[chain]``)."""
        if self.chain is not None:
            return self.model if self.model is not None else "custom"
        return str(model_code(self.model or ""))

    def rules(self, context: Mapping[str, Any]) -> Iterable[Problem]:
        known = isinstance(self.model, str) and model_code(self.model) is not None
        if self.chain is None and usable(context, "model", "chain") and not known:
            yield (
                ("model",),
                f"unknown model {self.model!r}; allowed: {known_models()} (or give a [chain])",
            )


def read_table_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The position, value and random columns of an error table's CSV (``#`` comments; a
    header naming ``position,value[,random]`` or none); ValueError naming the problem."""
    path = path.resolve()
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read {path} ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path} is not UTF-8 text") from None
    rows = [r for r in csv.reader(text.splitlines()) if r and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"{path} is empty")
    header = [h.strip().lower() for h in rows[0]]
    if "position" in header:
        body = rows[1:]
        if "value" not in header:
            raise ValueError(f"{path}: header must name position,value[,random]")
        ip, iv = header.index("position"), header.index("value")
        ir = header.index("random") if "random" in header else None
    else:
        body, ip, iv = rows, 0, 1
        ir = 2 if len(rows[0]) > 2 else None
    cols: list[list[float]] = [[], [], []]
    for n, row in enumerate(body, start=2 if body is not rows else 1):
        try:
            cols[0].append(float(row[ip]))
            cols[1].append(float(row[iv]))
            if ir is not None:
                cols[2].append(float(row[ir]))
        except (ValueError, IndexError):
            raise ValueError(f"{path} line {n}: expected numbers, got {row}") from None
    arrs = [np.array(c, dtype=float) for c in cols]
    if not all(np.all(np.isfinite(a)) for a in arrs):
        raise ValueError(f"{path}: non-finite value")
    if len(arrs[0]) > MAX_TABLE_POINTS:
        raise ValueError(f"{path}: too many values ({len(arrs[0])} > {MAX_TABLE_POINTS})")
    return arrs[0], arrs[1], (arrs[2] if ir is not None else None)


__all__ = ["CRITERIA", "FORMAT", "MAX_TABLE_POINTS", "MachineFile", "read_table_csv"]
