"""Validating a machine description (the ``machine.toml`` structure, docs/formats.md §1) into the
parts of a machine (:class:`ParsedMachine`), with one clear :class:`MachineFileError` per problem
naming the source, the key and what is allowed. Reading and writing the file itself is
:mod:`.machine_toml`. Units as in the file: positions mm, linear errors µm, angles µrad, °C.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..effects.base import Effect, effect_from_table
from ..kinematics import MODEL_CHAINS, Chain
from ..machine_parts import ArmDeflection, Probe, Volume
from ..models import known_models, model_code
from ..parametric_errors import AXES, SQUARENESS, parse_component
from ..tables import MAX_POLYNOMIAL_ORDER, ErrorTable, fit_polynomial
from ..thermal import Thermal
from ..toml_checks import TomlChecks
from ..uncertainty.model import UncertaintyModel, parse_uncertainty

FORMAT = "cmm-machine/1"
CRITERIA = ("least_squares", "end_points", "min_zone")
_TOP_TABLES = {
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
}
_TABLE_KEYS = {
    "position",
    "value",
    "random",
    "offset",
    "criterion",
    "file",
    "reversal",
    "polynomial",
    "curve",
    "random_band",
    "unit",
    "note",
}
MAX_TABLE_POINTS = 100_000


@dataclass
class ParsedMachine:
    """A validated machine description: the keyword arguments of ``Machine`` plus the squareness
    measurement offset, which is applied once the machine exists (:mod:`..offsets`)."""

    name: str
    model: str
    chain: Chain
    volume: Volume
    probe: Probe
    thermal: Thermal
    squareness_urad: np.ndarray
    squareness_random_urad: np.ndarray
    squareness_offset_mm: np.ndarray | None
    tables: dict[str, ErrorTable]
    arm: ArmDeflection
    effects: list[Effect]
    description: dict[str, Any]
    warnings: list[str] = field(default_factory=list)
    uncertainty: UncertaintyModel | None = None


def parse_machine(data: Mapping[str, Any], *, source: str, base_dir: Path) -> ParsedMachine:
    """Validate the TOML structure ``data`` (tables named in ``file`` keys are read relative to
    ``base_dir``); :class:`MachineFileError` naming ``source``, the key and the problem."""
    return _Parser(source, base_dir).machine(data)


class _Parser(TomlChecks):
    def __init__(self, source: str, base_dir: Path) -> None:
        super().__init__(source)
        self.base_dir = base_dir
        self.warnings: list[str] = []

    # ---------------------------------------------------------------- scalars / vectors
    def vector(self, value: Any, where: str, length: int | None = None) -> np.ndarray:
        if not isinstance(value, list):
            raise self.fail(where, f"expected an array of numbers, got {value!r}")
        if length is not None and len(value) != length:
            raise self.fail(where, f"expected {length} numbers, got {len(value)}")
        if len(value) > MAX_TABLE_POINTS:
            raise self.fail(where, f"too many values ({len(value)} > {MAX_TABLE_POINTS})")
        return np.array([self.number(v, f"{where}[{i}]") for i, v in enumerate(value)], dtype=float)

    def table(self, data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
        value = data.get(key, {})
        if not isinstance(value, Mapping):
            raise self.fail(key, f"expected a table [{key}], got {type(value).__name__}")
        return value

    # ---------------------------------------------------------------- sections
    def machine(self, data: Mapping[str, Any]) -> ParsedMachine:
        fmt = data.get("format", FORMAT)
        if fmt != FORMAT:
            raise self.fail("format", f"unsupported format {fmt!r}; this version reads {FORMAT!r}")
        for key, value in data.items():
            is_table = isinstance(value, Mapping) or (
                isinstance(value, list) and any(isinstance(v, Mapping) for v in value)
            )
            if is_table and key not in _TOP_TABLES:
                raise self.fail(key, f"unknown table; known: {sorted(_TOP_TABLES)}")
        name = data.get("name")
        if not isinstance(name, str) or not name.strip():
            raise self.fail("name", "a non-empty machine name is required")
        model = data.get("model")
        chain_tbl = self.table(data, "chain")
        if chain_tbl:
            self.check_keys(chain_tbl, "chain", {"tool", "workpiece"})
            tool, work = chain_tbl.get("tool", []), chain_tbl.get("workpiece", [])
            if not (isinstance(tool, list) and isinstance(work, list)):
                raise self.fail("chain", "tool and workpiece must be arrays of axis names")
            try:
                chain = Chain(
                    tool=tuple(str(a) for a in tool), workpiece=tuple(str(a) for a in work)
                )
            except ValueError as exc:
                raise self.fail("chain", str(exc)) from None
            model = model if isinstance(model, str) else "custom"
        else:
            code = model_code(model) if isinstance(model, str) else None
            if code is None:
                raise self.fail(
                    "model",
                    f"unknown model {model!r}; allowed: {known_models()} (or give a [chain])",
                )
            model = code
            chain = MODEL_CHAINS[model]
        assert isinstance(model, str)

        volume = self.volume(self.table(data, "volume"))
        probe = self.probe(self.table(data, "probe"))
        thermal = self.thermal(self.table(data, "thermal"), volume)
        sq_tbl = self.table(data, "squareness")
        self.check_keys(sq_tbl, "squareness", {*SQUARENESS, "random", "offset"})
        squareness = np.array(
            [self.number(sq_tbl.get(k, 0.0), f"squareness.{k}") for k in SQUARENESS]
        )
        sq_random = np.zeros(3)
        if "random" in sq_tbl:
            rnd = sq_tbl["random"]
            if not isinstance(rnd, Mapping):
                raise self.fail("squareness.random", "expected an inline table {alpha = …, …}")
            self.check_keys(rnd, "squareness.random", set(SQUARENESS))
            sq_random = np.array(
                [self.number(rnd.get(k, 0.0), f"squareness.random.{k}") for k in SQUARENESS]
            )
        sq_offset = (
            self.vector(sq_tbl["offset"], "squareness.offset", 3) if "offset" in sq_tbl else None
        )

        tables, normalised_tables = self.error_tables(self.table(data, "errors"))
        arm_tbl = self.table(data, "arm_deflection")
        self.check_keys(arm_tbl, "arm_deflection", {"phi1", "phi2"})
        arm = ArmDeflection(
            phi1=self.number(arm_tbl.get("phi1", 0.0), "arm_deflection.phi1"),
            phi2=self.number(arm_tbl.get("phi2", 0.0), "arm_deflection.phi2"),
        )
        effects_raw = data.get("effects", [])
        if not isinstance(effects_raw, list):
            raise self.fail("effects", "expected an array of tables [[effects]]")
        effects = []
        for i, tbl in enumerate(effects_raw):
            if not isinstance(tbl, Mapping):
                raise self.fail(f"effects[{i}]", "expected a table")
            try:
                effects.append(effect_from_table(tbl))
            except (ValueError, KeyError, TypeError) as exc:
                raise self.fail(f"effects[{i}]", str(exc)) from None

        unc = data.get("uncertainty")
        uncertainty = parse_uncertainty(
            unc if unc is not None else None,
            source=self.source,
            tables=tables,
            lower_mm=volume.lower_mm,
            upper_mm=volume.upper_mm,
            reference_mm=volume.reference_mm,
            expansion=thermal.expansion,
            workpiece_expansion=thermal.workpiece_expansion,
            probe_random_um=probe.random_um,
        )

        description = plain_copy(data)
        description["format"] = FORMAT
        description["model"] = model
        description["errors"] = normalised_tables
        return ParsedMachine(
            name=name.strip(),
            model=model,
            chain=chain,
            volume=volume,
            probe=probe,
            thermal=thermal,
            squareness_urad=squareness,
            squareness_random_urad=sq_random,
            squareness_offset_mm=sq_offset,
            tables=tables,
            arm=arm,
            effects=effects,
            description=description,
            warnings=self.warnings,
            uncertainty=uncertainty,
        )

    def volume(self, tbl: Mapping[str, Any]) -> Volume:
        self.check_keys(tbl, "volume", {"x", "y", "z", "reference", "steps"})
        lower, upper = np.zeros(3), np.zeros(3)
        for k, axis in enumerate(AXES):
            if axis not in tbl:
                raise self.fail(f"volume.{axis}", "missing: give [lower, upper] in mm")
            lo, hi = self.vector(tbl[axis], f"volume.{axis}", 2)
            if not hi > lo:
                raise self.fail(f"volume.{axis}", f"upper ({hi}) must be greater than lower ({lo})")
            if max(abs(lo), abs(hi)) > 1e6:  # a travel of 1e300 mm overflowed every report
                raise self.fail(
                    f"volume.{axis}",
                    f"[{lo}, {hi}] mm is beyond ±1e6 mm (1 km): check the unit, mm",
                )
            lower[k], upper[k] = lo, hi
        reference = (
            self.vector(tbl["reference"], "volume.reference", 3)
            if "reference" in tbl
            else lower.copy()
        )
        steps = None
        if "steps" in tbl:
            s = tbl["steps"]
            if not (
                isinstance(s, list)
                and len(s) == 3
                and all(isinstance(v, int) and not isinstance(v, bool) for v in s)
            ):
                raise self.fail("volume.steps", f"expected three integers, got {s!r}")
            if any(v < 2 or v > 1000 for v in s):
                raise self.fail("volume.steps", f"each step count must be 2…1000, got {s}")
            steps = (int(s[0]), int(s[1]), int(s[2]))
        return Volume(lower_mm=lower, upper_mm=upper, reference_mm=reference, steps=steps)

    def probe(self, tbl: Mapping[str, Any]) -> Probe:
        self.check_keys(tbl, "probe", {"offset", "random_um"})
        offset = self.vector(tbl["offset"], "probe.offset", 3) if "offset" in tbl else np.zeros(3)
        rnd = self.number(tbl.get("random_um", 0.0), "probe.random_um")
        if rnd < 0:
            raise self.fail("probe.random_um", f"must be ≥ 0, got {rnd}")
        # beyond these no stylus (1e300 mm wrote a grid of 1e297 µm corrections; a random
        # part of 1e300 µm ended report and uncertainty in an OverflowError traceback)
        if not np.all(np.abs(offset) <= 1e6):
            raise self.fail("probe.offset", f"{offset.tolist()} mm is beyond ±1e6 mm (1 km)")
        if rnd > 1e9:
            raise self.fail("probe.random_um", f"{rnd:g} µm is beyond 1e9 µm (1 km)")
        return Probe(offset_mm=offset, random_um=rnd)

    def thermal(self, tbl: Mapping[str, Any], volume: Volume) -> Thermal:
        self.check_keys(
            tbl, "thermal", {"reference_C", "expansion", "workpiece_expansion", "workpiece_fixture"}
        )
        ref = self.number(tbl.get("reference_C", 20.0), "thermal.reference_C")
        exp_tbl = tbl.get("expansion", {})
        if not isinstance(exp_tbl, Mapping):
            raise self.fail("thermal.expansion", "expected an inline table {x = …, y = …, z = …}")
        self.check_keys(exp_tbl, "thermal.expansion", set(AXES))
        expansion = np.array(
            [self.number(exp_tbl.get(a, 0.0), f"thermal.expansion.{a}") for a in AXES]
        )
        wp = tbl.get("workpiece_expansion")
        wp_val = None if wp is None else self.number(wp, "thermal.workpiece_expansion")
        fixture = None
        if "workpiece_fixture" in tbl:
            fixture = self.vector(tbl["workpiece_fixture"], "thermal.workpiece_fixture", 3)
        # beyond these no machine: products with a temperature difference overflowed to inf
        if not -273.15 <= ref <= 1000.0:
            raise self.fail("thermal.reference_C", f"{ref:g} °C is not in -273.15…1000 °C")
        for k, alpha in enumerate([*expansion, 0.0 if wp_val is None else wp_val]):
            if abs(alpha) > 1e6:
                where = f"thermal.expansion.{AXES[k]}" if k < 3 else "thermal.workpiece_expansion"
                raise self.fail(where, f"{alpha:g} µm/(m·°C) is beyond ±1e6")
        if fixture is not None and not np.all(np.abs(fixture) <= 1e6):
            raise self.fail("thermal.workpiece_fixture", f"{fixture.tolist()} mm is beyond ±1e6 mm")
        return Thermal(
            reference_C=ref,
            expansion=expansion,
            workpiece_expansion=wp_val,
            workpiece_fixture_mm=fixture,
        )

    def error_tables(
        self, errors: Mapping[str, Any]
    ) -> tuple[dict[str, ErrorTable], dict[str, Any]]:
        tables: dict[str, ErrorTable] = {}
        normalised: dict[str, Any] = {}
        for key, tbl in errors.items():
            where = f"errors.{key}"
            canon = self.error_component(key, where, tables)
            if not isinstance(tbl, Mapping):
                raise self.fail(where, "expected a table")
            table, norm = self.error_table(canon, tbl, where)
            tables[canon] = table
            normalised[canon] = norm
        return tables, normalised

    def error_table(
        self, canon: str, tbl: Mapping[str, Any], where: str
    ) -> tuple[ErrorTable, dict[str, Any]]:
        self.check_keys(tbl, where, _TABLE_KEYS)
        comp = parse_component(canon)
        norm: dict[str, Any] = {}
        sources = [k for k in ("position", "file", "polynomial", "curve") if k in tbl]
        if len(sources) != 1:
            raise self.fail(where, "give exactly one of position/value, file, polynomial or curve")
        position = value = poly = random = reversal = None
        if "position" in tbl or "file" in tbl:
            if "file" in tbl:
                position, value, random = self.read_csv(tbl["file"], where)
                if "random" in tbl:
                    random = self.vector(tbl["random"], f"{where}.random")
            else:
                if "value" not in tbl:
                    raise self.fail(where, "position given without value")
                position = self.vector(tbl["position"], f"{where}.position")
                value = self.vector(tbl["value"], f"{where}.value")
                if "random" in tbl:
                    random = self.vector(tbl["random"], f"{where}.random")
            if len(position) == 0:
                raise self.fail(where, "empty table")
            if len(value) != len(position):
                raise self.fail(
                    where, f"position has {len(position)} values but value has {len(value)}"
                )
            if random is not None and len(random) != len(position):
                raise self.fail(where, f"random has {len(random)} values, position {len(position)}")
            if "reversal" in tbl:
                if not comp.is_positional:
                    raise self.fail(
                        f"{where}.reversal",
                        "a reversal applies to positional tables (dx_x, dy_y, dz_z) only",
                    )
                reversal = self.vector(tbl["reversal"], f"{where}.reversal")
                if len(reversal) != len(position):
                    raise self.fail(
                        where, f"reversal has {len(reversal)} values, position {len(position)}"
                    )
                norm["reversal"] = reversal.tolist()
            if np.any(np.diff(position) <= 0):
                i = int(np.argmax(np.diff(position) <= 0)) + 1
                raise self.fail(
                    f"{where}.position",
                    f"positions must increase strictly (index {i}: {position[i]})",
                )
            norm.update(position=position.tolist(), value=value.tolist())
            if random is not None:
                norm["random"] = random.tolist()
        elif "polynomial" in tbl:
            poly = self.vector(tbl["polynomial"], f"{where}.polynomial")
            if not 1 <= len(poly) <= MAX_POLYNOMIAL_ORDER + 1:
                raise self.fail(
                    f"{where}.polynomial",
                    f"1…{MAX_POLYNOMIAL_ORDER + 1} coefficients (order ≤ {MAX_POLYNOMIAL_ORDER}), got {len(poly)}",
                )
            norm["polynomial"] = poly.tolist()
        else:
            curve = tbl["curve"]
            if not isinstance(curve, Mapping):
                raise self.fail(
                    f"{where}.curve", "expected {position = […], value = […], order = n}"
                )
            self.check_keys(curve, f"{where}.curve", {"position", "value", "order"})
            cpos = self.vector(curve.get("position"), f"{where}.curve.position")
            cval = self.vector(curve.get("value"), f"{where}.curve.value", len(cpos))
            order = curve.get("order", min(3, len(cpos) - 1))
            if not isinstance(order, int) or isinstance(order, bool):
                raise self.fail(f"{where}.curve.order", f"expected an integer, got {order!r}")
            try:
                poly = fit_polynomial(cpos, cval, order)
            except ValueError as exc:
                raise self.fail(f"{where}.curve", str(exc)) from None
            norm["polynomial"] = poly.tolist()
        band = None
        if "random_band" in tbl:
            band = self.number(tbl["random_band"], f"{where}.random_band")
            if band < 0:
                raise self.fail(f"{where}.random_band", "must be ≥ 0")
            norm["random_band"] = band
        if random is not None and np.any(random < 0):
            raise self.fail(f"{where}.random", "random bands must be ≥ 0")
        offset = None
        if "offset" in tbl:
            offset = self.vector(tbl["offset"], f"{where}.offset", 3)
            norm["offset"] = offset.tolist()
        criterion = tbl.get("criterion")
        if criterion is not None and not comp.is_straightness:
            if criterion not in CRITERIA:
                raise self.fail(
                    f"{where}.criterion",
                    f"unknown criterion {criterion!r}; allowed: {', '.join(CRITERIA)}",
                )
            self.warnings.append(
                f"{self.source}: {where}.criterion: a straightness criterion applies to "
                f"straightness tables only; ignored for {canon}"
            )
            criterion = None
        if criterion is not None:
            if criterion not in CRITERIA:
                raise self.fail(
                    f"{where}.criterion",
                    f"unknown criterion {criterion!r}; allowed: {', '.join(CRITERIA)}",
                )
            if position is None:
                raise self.fail(
                    f"{where}.criterion",
                    "a criterion needs tabulated values (position/value or file)",
                )
            norm["criterion"] = criterion
        table = ErrorTable(
            component=comp,
            position_mm=position,
            value=value,
            polynomial=poly,
            random_2sigma=random,
            random_band=band,
            offset_mm=offset,
            criterion=criterion,
            reversal=reversal,
            source=dict(norm),
        )
        return table, norm

    def read_csv(self, name: Any, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        if not isinstance(name, str):
            raise self.fail(f"{where}.file", f"expected a file name, got {name!r}")
        path = (self.base_dir / name).resolve()
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise self.fail(f"{where}.file", f"cannot read {path} ({exc.strerror})") from None
        rows = [r for r in csv.reader(text.splitlines()) if r and not r[0].lstrip().startswith("#")]
        if not rows:
            raise self.fail(f"{where}.file", f"{path} is empty")
        header = [h.strip().lower() for h in rows[0]]
        if "position" in header:
            body = rows[1:]
            try:
                ip, iv = header.index("position"), header.index("value")
            except ValueError:
                raise self.fail(
                    f"{where}.file", f"{path}: header must name position,value[,random]"
                ) from None
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
                raise self.fail(
                    f"{where}.file", f"{path} line {n}: expected numbers, got {row}"
                ) from None
        arrs = [np.array(c, dtype=float) for c in cols]
        if not all(np.all(np.isfinite(a)) for a in arrs):
            raise self.fail(f"{where}.file", f"{path}: non-finite value")
        return arrs[0], arrs[1], (arrs[2] if ir is not None else None)


def plain_copy(data: Mapping[str, Any]) -> dict[str, Any]:
    """A JSON-able deep copy of the parsed TOML (for hashing and writing back)."""
    return json.loads(json.dumps(data, default=str))
