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
importer (:mod:`compensation.formats.seedfiles`) uses the paper's meaning; TOML tables use ISO's.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

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


#: our name → ISO 230-1 name (the inverse of :data:`ISO_ALIASES`).
ISO_NAMES: dict[str, str] = {ours: iso for iso, ours in ISO_ALIASES.items()}


def iso_name(name: str) -> str:
    """The ISO 230-1 name (``EXX``, ``EBX`` …) of a table component (ours or ISO); squareness
    names are returned unchanged (ISO 230-1 names them by the pair of axes, not one symbol)."""
    canon = canonical_name(name)
    return ISO_NAMES.get(canon or name, name)


def names_as_written(written: Mapping[str, str]) -> dict[str, str]:
    """How to name every table component for a user who wrote the components ``written``
    (our name → the key as written): each written one as written; the others in the same
    convention — ISO 230-1 names when most written names were ISO ones, else ours."""
    iso = sum(1 for ours, key in written.items() if key != ours and key.upper() in ISO_ALIASES)
    use_iso = iso > len(written) - iso
    return {c: written.get(c, ISO_NAMES[c] if use_iso else c) for c in TABLE_COMPONENTS}


def canonical_name(name: str) -> str | None:
    """Our name for ``name`` (ours or an ISO 230-1 alias), or None when unknown."""
    if name in ALL_COMPONENTS:
        return name
    upper = name.upper()
    if upper in ISO_ALIASES:
        return ISO_ALIASES[upper]
    lower = name.lower()
    return lower if lower in ALL_COMPONENTS else None


def bad_component_keys(tables: Mapping[str, object]) -> list[tuple[tuple[str], str]]:
    """The keys of ``tables`` (a mapping by component name, ours or ISO 230-1) that name no
    table component, or one already named (an alias counts): (key path, problem) each."""
    seen: set[str] = set()
    out: list[tuple[tuple[str], str]] = []
    if not isinstance(tables, Mapping):  # not a table: said by the table's own check
        return out
    for key in tables:
        canon = canonical_name(key)
        if canon is None or canon not in TABLE_COMPONENTS:
            allowed = ", ".join(TABLE_COMPONENTS)
            out.append(((key,), f"unknown error component; allowed: {allowed} or ISO 230-1 names"))
        elif canon in seen:
            out.append(((key,), f"component {canon} is given twice (aliases count)"))
        seen.add(str(canon))
    return out


def parse_component(name: str) -> Component:
    """The table component ``name`` (ours or ISO alias); ValueError naming the allowed ones."""
    canon = canonical_name(name)
    if canon is None or canon not in TABLE_COMPONENTS:
        raise ValueError(
            f"unknown error component {name!r}; allowed: {', '.join(TABLE_COMPONENTS)} "
            "or ISO 230-1 names (EXX, EYX, EAX, …)"
        )
    return Component(kind=canon[0], direction=canon[1], axis=canon[3])


@dataclass(frozen=True)
class ParametricErrors:
    """The parametric errors of a machine given in Python, for :meth:`Machine.from_parts`.

    ``tables`` maps each given error (our name, e.g. ``dx_x``) to its ``[errors]`` entry of
    ``machine.toml`` (docs/formats.md §1); ``squareness_urad`` is (α, β1, β2) in µrad. Errors not
    given are zero. Build it with :meth:`from_polynomials` or :meth:`from_tables` (and
    :meth:`combined` to mix both) rather than by hand; the machine checks it exactly as it
    checks a file. Linear errors µm, angular errors µrad, axis positions mm (absolute).
    """

    tables: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    squareness_urad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    written: Mapping[str, str] = field(default_factory=dict)
    """Our name → the name the caller used (ISO 230-1 or ours): the machine keeps using it."""

    @classmethod
    def from_polynomials(
        cls,
        polynomials: Mapping[str, Sequence[float]],
        *,
        random_band: Mapping[str, float] | None = None,
        squareness_urad: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> ParametricErrors:
        """Errors as polynomials ``c0 + c1·q + c2·q² …`` of the axis position q (mm), c0 first.

        ``polynomials`` maps error names (ours like ``ey_x`` or ISO 230-1 like ``EBX``) to the
        coefficients (µm or µrad per mm^k); ``random_band`` optional uniform 2σ bands per error.
        """
        tables = {name: {"polynomial": _floats(c, name)} for name, c in polynomials.items()}
        for name, band in (random_band or {}).items():
            _entry(tables, name)["random_band"] = float(band)
        canon, written = _canonical_tables(tables)
        return cls(canon, _squareness(squareness_urad), written)

    @classmethod
    def from_tables(
        cls,
        tables: Mapping[str, tuple[Sequence[float], Sequence[float]]],
        *,
        random: Mapping[str, Sequence[float]] | None = None,
        offsets_mm: Mapping[str, Sequence[float]] | None = None,
        criteria: Mapping[str, str] | None = None,
        squareness_urad: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> ParametricErrors:
        """Errors as tabulated ``(position_mm, value)`` pairs per error name (cubic spline between
        the positions, end values held outside), as measured.

        ``random``: 2σ values at the same positions; ``offsets_mm``: where a line was measured
        (x, y, z), referred to the reference point on loading (paper §4); ``criteria``: the
        straightness criterion of a straightness table (``least_squares`` …).
        """
        out: dict[str, dict[str, Any]] = {}
        for name, (position, value) in tables.items():
            out[name] = {"position": _floats(position, name), "value": _floats(value, name)}
        for name, rnd in (random or {}).items():
            _entry(out, name)["random"] = _floats(rnd, name)
        for name, offset in (offsets_mm or {}).items():
            _entry(out, name)["offset"] = _floats(offset, name)
        for name, criterion in (criteria or {}).items():
            _entry(out, name)["criterion"] = str(criterion)
        canon, written = _canonical_tables(out)
        return cls(canon, _squareness(squareness_urad), written)

    def combined(self, other: ParametricErrors) -> ParametricErrors:
        """Both sets together (squareness added); ValueError if an error is given in both."""
        both = sorted(set(self.tables) & set(other.tables))
        if both:
            raise ValueError(f"errors given twice: {', '.join(both)}")
        sq = tuple(a + b for a, b in zip(self.squareness_urad, other.squareness_urad, strict=True))
        return ParametricErrors(
            {**self.tables, **other.tables}, _squareness(sq), {**self.written, **other.written}
        )

    def toml_sections(self) -> dict[str, Any]:
        """The ``[errors]`` and ``[squareness]`` tables of ``machine.toml`` for these errors
        (each error under the name the caller used)."""
        return {
            "errors": {
                self.written.get(name, name): dict(entry) for name, entry in self.tables.items()
            },
            "squareness": dict(zip(SQUARENESS, self.squareness_urad, strict=True)),
        }


def _floats(values: Sequence[float], name: str) -> list[float]:
    try:
        return [float(v) for v in values]
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a sequence of numbers, got {values!r}") from None


def _entry(tables: dict[str, dict[str, Any]], name: str) -> dict[str, Any]:
    if name not in tables:
        raise ValueError(f"{name}: a random part or option is given for an error with no values")
    return tables[name]


def _canonical_tables(
    tables: Mapping[str, dict[str, Any]],
) -> tuple[dict[str, dict[str, Any]], dict[str, str]]:
    """The tables under our names, and our name → the name as given."""
    out: dict[str, dict[str, Any]] = {}
    written: dict[str, str] = {}
    for name, entry in tables.items():
        canon = canonical_name(name)
        if canon is None or canon not in TABLE_COMPONENTS:
            raise ValueError(
                f"unknown error component {name!r}; allowed: {', '.join(TABLE_COMPONENTS)} "
                "or ISO 230-1 names (EXX, EYX, EAX, …); squareness goes in squareness_urad"
            )
        if canon in out:
            raise ValueError(f"component {canon} is given twice (aliases count)")
        out[canon] = entry
        written[canon] = name
    return out, written


def _squareness(values: Sequence[float]) -> tuple[float, float, float]:
    sq = [float(v) for v in values]
    if len(sq) != 3:
        raise ValueError(f"squareness_urad must be (alpha, beta1, beta2), got {values!r}")
    return sq[0], sq[1], sq[2]
