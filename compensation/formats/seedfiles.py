"""The paper's own data-file layout (Park, Burdekin & Peggs, section 3), read and written.

A machine's data is a cluster of ASCII files named ``<spec><S|R>.<EXT>``: ``<spec>`` the machine
specification name (1–7 letters or digits, e.g. ``UMIST1``), ``S`` for systematic and ``R`` for
random data, and the extension naming the parametric error (case-insensitive on reading):

========================  ==========================================================
extension                 content
========================  ==========================================================
``CTL``                   master control file (machine info, model, volume, steps)
``DPX DPY DPZ``           positional errors of X, Y, Z (``dx_x dy_y dz_z``), µm
``DYX DZX DXY DZY         straightness: ``D<I><J>`` is the I error along axis J
DXZ DYZ``                 (``DYX`` = ``dy_x``), µm
``EXX EYX EZX EXY EYY     angular: ``E<I><J>`` is the rotation about I along axis J
EZY EXZ EYZ EZZ``         (``EXX`` = ``ex_x``, the roll of X — not ISO 230-1's EXX), µrad
``ALP BT1 BT2``           squareness α (XY), β1 (ΔX = −β1·z), β2 (ΔY = −β2·z), µrad
``THX THY THZ``           effective expansion coefficient of each axis, µm/(m·°C)
========================  ==========================================================

The paper gives no byte layout, so this is ours, kept to what section 3 lists. Every file is
plain text, one item per line. ``#``, ``!`` or ``;`` start a comment (whole line or trailing);
blank lines are ignored; fields are separated by whitespace and/or commas; keywords are
case-insensitive and may be followed by ``=`` or ``:``. A file has header lines (a keyword and
its values) followed by data rows (lines whose first field is a number)::

    # UMIST1S.DYX — Y straightness of X, systematic
    MACHINE   UMIST1          # optional; must match the file name
    TYPE      MB1             # optional; must match the master control file
    OFFSET    0, 200, 100     # measurement location (x, y, z) mm; absent = the reference point
    CRITERION least_squares   # straightness only: least_squares | end_points | min_zone
    0      0.00               # position (mm)  value (µm or µrad)
    100    1.20
    200    2.10

* Positional, straightness and angular files (``S``): ``position value`` rows, positions strictly
  increasing; or, instead of rows, ``POLYNOMIAL c0 c1 …`` (the paper's curve input, c0 first,
  position in mm). ``OFFSET`` and ``CRITERION`` as above (the paper's section 4 / A.2
  transformation is applied on loading, exactly as for ``offset`` in ``machine.toml``).
* The same extensions with ``R`` carry the random part (2σ) ``position value`` at the same
  positions as the ``S`` file, or ``BAND b``: a uniform band over the whole span (the paper's
  "uniform bandwidth input"). An ``R`` file without an ``S`` file means zero systematic error.
* Squareness and thermal files hold one value: a data row with a single number or ``VALUE v``.
  Squareness files may carry ``OFFSET`` (where the two lines were measured); an ``R`` squareness
  file holds its random part.
* Master control file ``<spec>S.CTL`` (``<spec>R.CTL`` accepted on reading)::

      MACHINE    UMIST1
      TITLE      npl-bridge       # the machine's full name (default: the spec name)
      EXAMINER   …                # free text, kept as metadata: also ENVIRONMENT, DATE, NOTE
      TYPE       MB1              # MB1 MB2 FB1 FB2 MH1 MH2 FH1 FH2 CX1 CY1
      INITIAL    0 0 0            # initial nominal coordinates X Y Z, mm (volume lower corner)
      STEPS      19 23 16         # nodes per axis
      STEPSIZE   50 50 26.667     # mm; the volume ends at INITIAL + (STEPS − 1)·STEPSIZE …
      FINAL      900 1150 400     # … unless FINAL (upper corner, mm) is given
      REFERENCE  0 0 0            # reference point (x0, y0, z0), mm; default INITIAL
      PROBE      0 0 -120         # stylus offset Xp Yp Zp, mm
      PROBE_RANDOM 0.5            # random probing error (2σ), µm
      TREF       20               # thermal reference temperature, °C
      WORKPIECE_EXPANSION 11.5    # µm/(m·°C)
      WORKPIECE_FIXTURE 450 575 0 # mm
      PHI1 0 / PHI2 0             # horizontal-arm deflection terms (MH1, MH2), µrad/m

:func:`load_seed_fileset` turns a file set into the same structure as ``machine.toml`` and builds
the machine with :meth:`Machine.from_dict`, so validation and offsets behave identically; a bad
file raises one :class:`MachineFileError` naming the file, the line and the problem.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MachineFileError
from ..kinematics import MODEL_CHAINS
from ..machine import Machine
from ..parametric_errors import AXES, SQUARENESS
from .seedfile_lines import (
    CRITERIA,
    CTL_KEYS,
    DATA_KEYS,
    EXTENSIONS,
    SPEC_NAME_RE,
    SQUARENESS_EXT,
    TABLE_EXT,
    THERMAL_EXT,
    SeedFile,
    index_seed_files,
    parse_seed_file,
)

__all__ = [
    "EXTENSIONS",
    "SPEC_NAME_RE",
    "find_seed_machines",
    "load_seed_fileset",
    "write_seed_fileset",
]


def find_seed_machines(directory: str | Path) -> list[str]:
    """Specification names (upper case, sorted) of the machines with a master control file."""
    index = index_seed_files(Path(directory))
    return sorted(spec for spec, files in index.items() if any(ext == "CTL" for _, ext in files))


# --------------------------------------------------------------------------- loading
def load_seed_fileset(directory: str | Path, name: str) -> Machine:
    """Load machine ``name`` (spec name, case-insensitive) from a seed-style file set.

    Builds the ``machine.toml`` structure (docs/formats.md §1) and goes through
    :meth:`Machine.from_dict`. Raises :class:`MachineFileError` naming the file, line and problem.
    """
    directory = Path(directory)
    if not SPEC_NAME_RE.match(name):
        raise MachineFileError(
            str(directory), "", f"machine specification name {name!r} must be 1–7 letters/digits"
        )
    spec = name.upper()
    files = index_seed_files(directory).get(spec, {})
    ctl_path = files.get(("S", "CTL")) or files.get(("R", "CTL"))
    if ctl_path is None:
        known = find_seed_machines(directory)
        raise MachineFileError(
            str(directory / f"{spec}S.CTL"),
            "",
            f"no master control file for {spec}; machines here: {', '.join(known) or 'none'}",
        )
    data, model = _from_ctl(parse_seed_file(ctl_path, CTL_KEYS), spec)
    errors: dict[str, Any] = {}
    sq: dict[str, Any] = {}
    sq_random: dict[str, float] = {}
    sq_offsets: dict[str, tuple[list[float] | None, Path]] = {}
    expansion: dict[str, float] = {}
    for ext, comp in TABLE_EXT.items():
        s_path, r_path = files.get(("S", ext)), files.get(("R", ext))
        if s_path is None and r_path is None:
            continue
        errors[comp] = _table(comp, s_path, r_path, spec, model)
    for ext, comp in SQUARENESS_EXT.items():
        if (s_path := files.get(("S", ext))) is not None:
            f = parse_seed_file(s_path, DATA_KEYS - {"CRITERION", "POLYNOMIAL", "BAND"})
            _check_identity(f, spec, model)
            sq[comp] = _single_value(f)
            sq_offsets[comp] = (f.numbers("OFFSET", 3), s_path)
        if (r_path := files.get(("R", ext))) is not None:
            f = parse_seed_file(r_path, DATA_KEYS - {"CRITERION", "POLYNOMIAL", "BAND"})
            _check_identity(f, spec, model)
            sq_random[comp] = _single_value(f, nonnegative=True)
    for ext, axis in THERMAL_EXT.items():
        if (path := files.get(("S", ext))) is not None:
            f = parse_seed_file(path, {"MACHINE", "TYPE", "VALUE", "UNIT", "NOTE"})
            _check_identity(f, spec, model)
            expansion[axis] = _single_value(f)
        if (path := files.get(("R", ext))) is not None:
            raise MachineFileError(str(path), "", "thermal coefficients have no random part")
    if expansion:
        data.setdefault("thermal", {})["expansion"] = expansion
    data["errors"] = errors
    offsets = {tuple(o) for o, _ in sq_offsets.values() if o is not None}
    differing = len(offsets) > 1 or (
        len(offsets) == 1 and any(o is None for o, _ in sq_offsets.values())
    )
    if sq:
        data["squareness"] = dict(sq)
        if offsets and not differing:
            data["squareness"]["offset"] = list(next(iter(offsets)))
    if sq_random:
        data.setdefault("squareness", {})["random"] = sq_random
    source = str(ctl_path)
    machine = Machine.from_dict(data, source=source, base_dir=directory)
    if differing:
        # each squareness measured at its own location: refer each one to the reference point
        # with the chain's rule (compensation.offsets), then rebuild without offsets
        from ..offsets import squareness_angular_part

        for j, comp in enumerate(SQUARENESS):
            offset, _ = sq_offsets.get(comp, (None, ctl_path))
            if offset is not None:
                part = squareness_angular_part(machine, np.asarray(offset, dtype=float))
                data["squareness"][comp] = sq[comp] - float(part[j])
        machine = Machine.from_dict(data, source=source, base_dir=directory)
    return machine


def _from_ctl(f: SeedFile, spec: str) -> tuple[dict[str, Any], str]:
    """The machine.toml skeleton (everything but errors and squareness) from the control file."""
    _check_identity(f, spec, None)
    model_line = f.header.get("TYPE", (None, []))[0]
    model = (f.text("TYPE") or "").upper()
    if model not in MODEL_CHAINS:
        raise f.fail(
            model_line,
            f"machine type {model or 'missing'!r}; allowed: {', '.join(MODEL_CHAINS)}",
        )
    initial = f.numbers("INITIAL", 3)
    if initial is None:
        raise f.fail(None, "INITIAL (initial nominal coordinates X Y Z, mm) is missing")
    steps_f = f.numbers("STEPS", 3)
    steps: list[int] | None = None
    if steps_f is not None:
        line = f.header["STEPS"][0]
        if any(s != int(s) or s < 2 for s in steps_f):
            raise f.fail(line, f"STEPS must be three integers ≥ 2, got {steps_f}")
        steps = [int(s) for s in steps_f]
    final = f.numbers("FINAL", 3)
    stepsize = f.numbers("STEPSIZE", 3)
    if final is None:
        if steps is None or stepsize is None:
            raise f.fail(None, "give FINAL (upper corner, mm) or both STEPS and STEPSIZE")
        final = [initial[k] + (steps[k] - 1) * stepsize[k] for k in range(3)]
    elif steps is not None and stepsize is not None:
        implied = [initial[k] + (steps[k] - 1) * stepsize[k] for k in range(3)]
        if not np.allclose(implied, final, rtol=1e-6, atol=1e-3):
            raise f.fail(
                f.header["STEPSIZE"][0],
                f"INITIAL + (STEPS − 1)·STEPSIZE = {implied} disagrees with FINAL {final}",
            )
    volume: dict[str, Any] = {a: [initial[k], final[k]] for k, a in enumerate(AXES)}
    volume["reference"] = f.numbers("REFERENCE", 3) or list(initial)
    if steps is not None:
        volume["steps"] = steps
    data: dict[str, Any] = {
        "format": "cmm-machine/1",
        "name": f.text("TITLE") or spec,
        "model": model,
        "volume": volume,
    }
    probe: dict[str, Any] = {}
    if (p := f.numbers("PROBE", 3)) is not None:
        probe["offset"] = p
    if (r := f.numbers("PROBE_RANDOM", 1)) is not None:
        probe["random_um"] = r[0]
    if probe:
        data["probe"] = probe
    thermal: dict[str, Any] = {}
    if (t := f.numbers("TREF", 1)) is not None:
        thermal["reference_C"] = t[0]
    if (w := f.numbers("WORKPIECE_EXPANSION", 1)) is not None:
        thermal["workpiece_expansion"] = w[0]
    if (fx := f.numbers("WORKPIECE_FIXTURE", 3)) is not None:
        thermal["workpiece_fixture"] = fx
    if thermal:
        data["thermal"] = thermal
    arm = {k.lower(): v[0] for k in ("PHI1", "PHI2") if (v := f.numbers(k, 1)) is not None}
    if arm:
        data["arm_deflection"] = arm
    meta = {k.lower(): f.text(k) for k in ("EXAMINER", "ENVIRONMENT", "DATE", "NOTE") if f.text(k)}
    meta["source"] = f"seed file set {spec} ({f.path.parent})"
    data["meta"] = meta
    return data, model


def _check_identity(f: SeedFile, spec: str, model: str | None) -> None:
    machine = f.text("MACHINE")
    if machine is not None and machine.upper() != spec:
        raise f.fail(
            f.header["MACHINE"][0], f"machine specification {machine!r} differs from {spec!r}"
        )
    kind = f.text("TYPE")
    if model is not None and kind is not None and kind.upper() != model:
        raise f.fail(
            f.header["TYPE"][0],
            f"machine type {kind!r} differs from the master control file's {model!r}",
        )


def _single_value(f: SeedFile, *, nonnegative: bool = False) -> float:
    values = f.numbers("VALUE", 1)
    if values is not None:
        if f.rows:
            raise f.fail(f.rows[0][0], "give either VALUE or one data row, not both")
        line, value = f.header["VALUE"][0], values[0]
    else:
        if len(f.rows) != 1 or len(f.rows[0][1]) != 1:
            bad = f.rows[1][0] if len(f.rows) > 1 else (f.rows[0][0] if f.rows else None)
            raise f.fail(bad, "expected exactly one value (a single number or VALUE v)")
        line, value = f.rows[0][0], f.rows[0][1][0]
    if nonnegative and value < 0:
        raise f.fail(line, f"a random part must be ≥ 0, got {value}")
    return value


def _rows(f: SeedFile) -> tuple[list[float], list[float]]:
    position: list[float] = []
    value: list[float] = []
    for line, numbers in f.rows:
        if len(numbers) != 2:
            raise f.fail(line, f"expected 'position value', got {len(numbers)} numbers")
        if position and numbers[0] <= position[-1]:
            raise f.fail(
                line, f"positions must increase strictly ({numbers[0]} after {position[-1]})"
            )
        position.append(numbers[0])
        value.append(numbers[1])
    return position, value


def _table(
    comp: str, s_path: Path | None, r_path: Path | None, spec: str, model: str
) -> dict[str, Any]:
    """One ``[errors.<comp>]`` table from its S and/or R file."""
    table: dict[str, Any] = {}
    straightness = comp[0] == "d" and comp[1] != comp[3]
    unit = "um" if comp[0] == "d" else "urad"
    if s_path is not None:
        f = parse_seed_file(s_path, DATA_KEYS - {"BAND", "VALUE"})
        _check_identity(f, spec, model)
        _check_unit(f, unit)
        if "POLYNOMIAL" in f.header:
            if f.rows:
                raise f.fail(f.rows[0][0], "give either POLYNOMIAL or data rows, not both")
            table["polynomial"] = f.numbers("POLYNOMIAL")
        else:
            if not f.rows:
                raise f.fail(None, "no data rows ('position value') and no POLYNOMIAL")
            table["position"], table["value"] = _rows(f)
        if (offset := f.numbers("OFFSET", 3)) is not None:
            table["offset"] = offset
        if "CRITERION" in f.header:
            line = f.header["CRITERION"][0]
            crit = (f.text("CRITERION") or "").lower()
            if not straightness:
                raise f.fail(line, "a straightness criterion applies to straightness files only")
            if crit not in CRITERIA:
                raise f.fail(line, f"unknown criterion {crit!r}; allowed: {', '.join(CRITERIA)}")
            table["criterion"] = crit
    if r_path is not None:
        f = parse_seed_file(r_path, {"MACHINE", "TYPE", "BAND", "UNIT", "NOTE", "OFFSET"})
        _check_identity(f, spec, model)
        _check_unit(f, unit)
        if "BAND" in f.header:
            line = f.header["BAND"][0]
            if f.rows:
                raise f.fail(f.rows[0][0], "give either BAND or data rows, not both")
            band = (f.numbers("BAND", 1) or [0.0])[0]
            if band < 0:
                raise f.fail(line, f"a random band must be ≥ 0, got {band}")
            table["random_band"] = band
        else:
            if not f.rows:
                raise f.fail(None, "no data rows ('position value') and no BAND")
            position, random = _rows(f)
            bad = next((r for r in f.rows if r[1][1] < 0), None)
            if bad is not None:
                raise f.fail(bad[0], f"a random part must be ≥ 0, got {bad[1][1]}")
            if "position" not in table:
                if "polynomial" in table:
                    raise f.fail(
                        None, "tabulated random values need a tabulated S file (not POLYNOMIAL)"
                    )
                table["position"], table["value"] = position, [0.0] * len(position)
            elif not np.array_equal(position, table["position"]):
                raise f.fail(
                    f.rows[0][0],
                    f"positions differ from the S file's ({len(position)} vs "
                    f"{len(table['position'])} rows); R values must be at the same positions",
                )
            table["random"] = random
    return table


def _check_unit(f: SeedFile, unit: str) -> None:
    if "UNIT" not in f.header:
        return
    given = (f.text("UNIT") or "").lower().replace("µ", "u").replace("μ", "u")
    aliases = {"um": {"um", "micron", "microns"}, "urad": {"urad", "um/m"}}
    if given not in aliases[unit]:
        raise f.fail(f.header["UNIT"][0], f"unit {given!r}: this file holds {unit}")


# --------------------------------------------------------------------------- writing
def _fmt(value: float) -> str:
    return repr(float(value))


def _vec(values: Any) -> str:
    return " ".join(_fmt(v) for v in values)


def write_seed_fileset(machine: Machine, directory: str | Path, name: str) -> list[Path]:
    """Write ``machine`` as the file set ``<name>S.*`` / ``<name>R.*`` in ``directory``.

    Tables are written as given in the machine's description (before any offset transformation,
    with their offsets), so loading the set gives back the same model. Everything is checked
    before the first file is written; ValueError if the machine needs something section 3 cannot
    hold (a custom chain, extra effects). Returns the paths written.
    """
    if not SPEC_NAME_RE.match(name):
        raise ValueError(f"machine specification name {name!r} must be 1–7 letters or digits")
    if machine.model not in MODEL_CHAINS:
        raise ValueError(f"model {machine.model!r} is not one of the paper's ten models")
    desc: Mapping[str, Any] = machine.description
    if desc.get("effects"):
        raise ValueError("effects cannot be written as seed files (use machine.toml)")
    spec = name.upper()
    head = f"MACHINE {spec}\nTYPE {machine.model}\n"
    texts = {f"{spec}S.CTL": _ctl_text(machine, spec, head)}
    texts.update(_error_texts(desc.get("errors", {}), spec, head))
    texts.update(_squareness_texts(desc.get("squareness", {}), spec, head))
    for ext, axis in THERMAL_EXT.items():
        coef = float(machine.thermal.expansion[AXES.index(axis)])
        texts[f"{spec}S.{ext}"] = (
            f"# {spec}S.{ext}: expansion coefficient of {axis.upper()}, µm/(m·°C)\n"
            f"{head}VALUE {_fmt(coef)}\n"
        )

    out_dir = Path(directory)
    out_dir.mkdir(parents=True, exist_ok=True)
    stale = index_seed_files(out_dir).get(spec, {})
    for (kind, ext), path in stale.items():  # a previous set of this machine: no leftovers
        if f"{spec}{kind}.{ext}" not in texts:
            path.unlink()
    written = []
    for fname, text in texts.items():
        path = out_dir / fname
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


def _ctl_text(machine: Machine, spec: str, head: str) -> str:
    """The master control file ``<spec>S.CTL`` (section 3.2): volume, probe, thermal, arm."""
    desc: Mapping[str, Any] = machine.description
    vol = machine.volume
    ctl = [
        f"# {spec}S.CTL: master control file (Park, Burdekin & Peggs, section 3.2)",
        head.rstrip(),
    ]
    ctl.append(f"TITLE {machine.name}")
    for key in ("examiner", "environment", "date", "note"):
        if isinstance(value := desc.get("meta", {}).get(key), str) and value.strip():
            ctl.append(f"{key.upper()} {' '.join(value.split())}")
    ctl.append(f"INITIAL {_vec(vol.lower_mm)}")
    ctl.append(f"FINAL {_vec(vol.upper_mm)}")
    if vol.steps is not None:
        ctl.append(f"STEPS {' '.join(str(s) for s in vol.steps)}")
        size = (vol.upper_mm - vol.lower_mm) / (np.asarray(vol.steps) - 1)
        ctl.append(f"STEPSIZE {_vec(size)}")
    ctl.append(f"REFERENCE {_vec(vol.reference_mm)}")
    ctl.append(f"PROBE {_vec(machine.probe.offset_mm)}")
    if machine.probe.random_um:
        ctl.append(f"PROBE_RANDOM {_fmt(machine.probe.random_um)}")
    th = machine.thermal
    ctl.append(f"TREF {_fmt(th.reference_C)}")
    if th.workpiece_expansion is not None:
        ctl.append(f"WORKPIECE_EXPANSION {_fmt(th.workpiece_expansion)}")
    if th.workpiece_fixture_mm is not None:
        ctl.append(f"WORKPIECE_FIXTURE {_vec(th.workpiece_fixture_mm)}")
    if machine.arm.phi1:
        ctl.append(f"PHI1 {_fmt(machine.arm.phi1)}")
    if machine.arm.phi2:
        ctl.append(f"PHI2 {_fmt(machine.arm.phi2)}")
    return "\n".join(ctl) + "\n"


def _error_texts(errors: Mapping[str, Any], spec: str, head: str) -> dict[str, str]:
    """The error table files ``<spec>S.<ext>`` and their random parts ``<spec>R.<ext>`` of the
    description's ``[errors]`` (ValueError when a table has both random forms)."""
    texts: dict[str, str] = {}
    ext_of = {c: e for e, c in TABLE_EXT.items()}
    for comp, tbl in errors.items():
        ext = ext_of[comp]
        unit = "um" if comp[0] == "d" else "urad"
        lines = [f"# {spec}S.{ext}: {comp}, systematic", head + f"UNIT {unit}"]
        if "offset" in tbl:
            lines.append(f"OFFSET {_vec(tbl['offset'])}")
        if "criterion" in tbl:
            lines.append(f"CRITERION {tbl['criterion']}")
        if "polynomial" in tbl:
            lines.append(f"POLYNOMIAL {_vec(tbl['polynomial'])}")
        else:
            lines += [
                f"{_fmt(p)} {_fmt(v)}" for p, v in zip(tbl["position"], tbl["value"], strict=True)
            ]
        texts[f"{spec}S.{ext}"] = "\n".join(lines) + "\n"
        if "random" in tbl or "random_band" in tbl:
            rl = [f"# {spec}R.{ext}: {comp}, random part (2σ)", head + f"UNIT {unit}"]
            if "random_band" in tbl:
                rl.append(f"BAND {_fmt(tbl['random_band'])}")
            else:
                rl += [
                    f"{_fmt(p)} {_fmt(v)}"
                    for p, v in zip(tbl["position"], tbl["random"], strict=True)
                ]
            texts[f"{spec}R.{ext}"] = "\n".join(rl) + "\n"
        if "random" in tbl and "random_band" in tbl:
            raise ValueError(
                f"{comp}: both a tabulated random part and a band; seed files hold one"
            )
    return texts


def _squareness_texts(sq_desc: Mapping[str, Any], spec: str, head: str) -> dict[str, str]:
    """The squareness files (µrad) and their random parts."""
    texts: dict[str, str] = {}
    for ext, comp in SQUARENESS_EXT.items():
        lines = [f"# {spec}S.{ext}: squareness {comp}, µrad", head.rstrip("\n")]
        if "offset" in sq_desc:
            lines.append(f"OFFSET {_vec(sq_desc['offset'])}")
        lines.append(f"VALUE {_fmt(sq_desc.get(comp, 0.0))}")
        texts[f"{spec}S.{ext}"] = "\n".join(lines) + "\n"
        rnd = sq_desc.get("random", {}).get(comp)
        if rnd is not None:
            texts[f"{spec}R.{ext}"] = f"{head}VALUE {_fmt(rnd)}\n"
    return texts
