"""``cmm-comp grid build|info|keygen|sign`` and ``cmm-comp correct`` (docs/formats.md §3).

Register with ``add_parsers(subparsers)``; each handler takes the parsed arguments and returns
an exit code. User-file problems raise ``ValueError`` (``GridFileError`` is one) with a message
naming the file, line and column; nothing is written then.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .common import Subparsers, load_machine, write_text_atomic

if TYPE_CHECKING:
    import numpy as np

    from cmm_comp.compensation.grid import CorrectionGrid

__all__ = [
    "add_parsers",
    "cmd_correct",
    "cmd_grid_build",
    "cmd_grid_info",
    "cmd_grid_keygen",
    "cmd_grid_sign",
    "grid_info_lines",
    "read_points_csv",
]

DIRECTION_COLUMNS = ("dir_x", "dir_y", "dir_z")

#: ``cmm-comp correct --help``: the columns it reads and writes (docs/formats.md §3)
CORRECT_COLUMNS = """\
input columns (POINTS.csv, a header row, comma-separated; other columns are carried through):
  x, y, z               indicated position, mm (required)
  px, py, pz            stylus offset, mm (all three or none; default: the grid's probe offset,
                        shown by `cmm-comp grid info GRID`)
  T_x, T_y, T_z         scale temperatures as read, °C
  T_wp                  workpiece temperature, °C
  T_top, T_bottom       structure top and bottom, °C (thermal gradient)
  T_air                 ambient air, °C
  dir_x, dir_y, dir_z   direction each axis last travelled before the point: +1 or -1
                        (0: unknown; needed when the machine has reversal tables)
  Which signals a grid needs: `cmm-comp grid info GRID`. A needed signal that is missing or
  empty leaves the point uncorrected for its terms, with status no_temperature / missing_input.

output columns (OUT.csv): the input columns, then
  cx, cy, cz            corrected position, mm (empty for invalid_input and outside_volume;
                        use it as corrected only when status is ok)
  Ux_um, Uy_um, Uz_um   expanded uncertainty U (k = 2) per component, µm (only for status ok on a
                        grid built with --uncertainty)
  status                ok, or why the point is not fully corrected (docs/formats.md §7)
"""


def _signal_columns() -> tuple[str, ...]:
    """Runtime-signal columns of a points CSV: the temperature roles, then the directions
    (imported on use: ``cmm-comp --help`` must not import the model)."""
    from cmm_comp.compensation.thermal.roles import TEMPERATURE_ROLES

    return (*TEMPERATURE_ROLES, *DIRECTION_COLUMNS)


def cmd_grid_build(args: argparse.Namespace) -> int:
    """``cmm-comp grid build MACHINE -o GRID [--steps NX NY NZ]``."""
    from cmm_comp.compensation.grid import CorrectionGrid

    machine = load_machine(args.machine)

    def progress(fraction: float, message: str) -> None:
        if sys.stderr.isatty():
            print(f"\rgrid build: {int(100 * fraction):3d} % {message}", end="", file=sys.stderr)

    grid = CorrectionGrid.build(machine, steps=args.steps, progress=progress)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    if args.uncertainty:
        grid = _add_uncertainty(grid, machine, args)
    sha = grid.save(args.output)
    print(
        f"wrote {args.output}: {machine.name} ({machine.model}), steps {list(grid.steps)}, "
        f"signals {[s.name for s in grid.signals]}, sha256 {sha[:16]}…"
    )
    for u in grid.metadata.get("unresolved_effects", []):
        print(
            f"warning: the {u['cause']} effect along {u['axis']} has a wavelength of "
            f"{u['wavelength_mm']:g} mm; these steps give it {u['nodes_per_wavelength']:.1f} "
            "nodes per wavelength (8 needed): the grid only partly corrects it — use more "
            "--steps along that axis or a smaller volume",
            file=sys.stderr,
        )
    return 0


def _add_uncertainty(grid: Any, machine: Any, args: argparse.Namespace) -> Any:
    """The grid carrying U per node from the virtual CMM (docs/uncertainty.md)."""
    import numpy as np

    from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

    if args.uncertainty_trials < 2:
        raise ValueError(f"--uncertainty-trials must be ≥ 2, got {args.uncertainty_trials}")

    def progress(fraction: float, message: str) -> None:
        if sys.stderr.isatty():
            print(
                f"\rgrid uncertainty: {int(100 * fraction):3d} % {message}", end="", file=sys.stderr
            )

    out = add_uncertainty(
        grid,
        machine,
        rng=np.random.default_rng(args.seed),
        seed=args.seed,
        trials=args.uncertainty_trials,
        rel_tolerance=args.uncertainty_tolerance,
        progress=progress,
    )
    if sys.stderr.isatty():
        print(file=sys.stderr)
    info = out.uncertainty.info if out.uncertainty is not None else {}
    print(f"uncertainty: {info.get('trials')} virtual machines per node")
    from .uncertainty import print_assumptions

    print_assumptions(
        info.get("defaulted", []),
        info.get("taken_as_zero", []),
        machine.error_label,
        where=f"the grid header: cmm-comp grid info {args.output}",
    )
    return out


def cmd_grid_info(args: argparse.Namespace) -> int:
    """``cmm-comp grid info GRID [--public-key PEM] [--json]``: what a grid file holds."""
    from cmm_comp.compensation.grid import CorrectionGrid
    from cmm_comp.compensation.grid.signing import (
        load_public_key,
        signature_info,
        verify_signature,
    )

    seen: list[Any] = []
    key = load_public_key(args.public_key) if args.public_key is not None else None

    def check(contents: Any) -> None:  # the bytes the grid is built from, read once
        seen.append(contents)
        if key is not None:
            verify_signature(contents, key)  # GridSignatureError: one line, exit 2

    grid = CorrectionGrid.load(args.grid, verify=check)
    contents = seen[0]
    sig = signature_info(contents)
    if args.json:
        print(json.dumps({"sha256": contents.sha256, "header": contents.header,
                          "signature": None if sig is None else {"algorithm": sig.algorithm,
                          "key_id": sig.key_id, "verified": key is not None}}, indent=1))  # fmt: skip
        return 0
    for line in grid_info_lines(grid, contents.header, contents.sha256):
        print(line)
    if sig is None:
        print("signature: none (the daemon refuses it unless grid.allow_unsigned = true; "
              "cmm-comp grid sign)")  # fmt: skip
    else:
        state = "verified with " + str(args.public_key) if key is not None else "not verified"
        print(f"signature: {sig.algorithm}, key id {sig.key_id} ({state}; --public-key PEM)")
    return 0


def grid_info_lines(grid: CorrectionGrid, header: dict[str, Any], sha256: str) -> list[str]:
    """The header of a grid file in words (steps, signals, probe, U, provenance)."""
    import numpy as np

    m = header.get("machine", {})
    lo, hi = grid.lower_mm, grid.upper_mm
    steps = list(grid.steps)
    lines = [
        f"grid: {header.get('format')} version {header.get('format_version')}, sha256 {sha256}",
        f"machine: {m.get('name')} ({m.get('model')}), description sha256 {m.get('sha256')}",
        "volume: "
        + ", ".join(f"{a} {lo[k]:g}…{hi[k]:g}" for k, a in enumerate("xyz"))
        + f" mm; steps {steps[0]} × {steps[1]} × {steps[2]} ({int(np.prod(steps))} nodes); "
        f"outside the volume: {header.get('outside_policy')}",
        f"probe offset (the stylus correct uses by default): {header.get('probe_offset_mm')} mm; "
        f"reference point {header.get('reference_mm')} mm, reference temperature "
        f"{header.get('reference_C')} °C",
    ]
    needed = [f"{s.name} (reference {s.reference:g})" for s in grid.signals if s.needed]
    other = [s.name for s in grid.signals if not s.needed]
    lines.append(
        "signals the correction needs: " + (", ".join(needed) or "none")
        + (f"; carried, not needed: {', '.join(other)}" if other else "")
    )  # fmt: skip
    for f in header.get("signal_filters", []):
        lines.append(f"signal filter: {json.dumps(f)}")
    lines += _uncertainty_lines(grid, header)
    lines.append(
        f"built {header.get('built_utc')} by cmm-comp {header.get('library_version')} "
        f"from {header.get('source', '?')}"
    )
    return lines


def _uncertainty_lines(grid: CorrectionGrid, header: dict[str, Any]) -> list[str]:
    """U of the grid: its range at the nodes (probe offset, reference temperatures) and how it
    was computed, with the inputs defaulted and taken as zero."""
    import numpy as np

    if not grid.has_uncertainty:
        return ["uncertainty: none (grid build --uncertainty adds U per node)"]
    u_info = header.get("uncertainty", {})
    nodes = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, 3)
    probe = np.asarray(header.get("probe_offset_mm", [0.0, 0.0, 0.0]), float)
    refs = {s.name: np.full(len(nodes), s.reference) for s in grid.signals}
    temps = {k: v for k, v in refs.items() if k.startswith("T_")}
    inputs = {k: v for k, v in refs.items() if not k.startswith("T_")}
    _, status, u_um = grid.correct_with_uncertainty(nodes, probe, temps or None, inputs or None)
    ok = status == "ok"
    if not ok.any():  # not reachable: every signal is at its reference
        return [f"uncertainty: no node corrected ({sorted(set(status.tolist()))})"]
    k = u_info.get("coverage_factor")
    ranges = ", ".join(
        f"{a} {np.nanmin(u_um[ok, i]):.3g}…{np.nanmax(u_um[ok, i]):.3g}"
        for i, a in enumerate("xyz")
    )
    stable = "" if u_info.get("stable") is None else f", stable: {u_info.get('stable')}"
    lines = [
        f"uncertainty: U (k = {k:g}) at the nodes, probe offset, reference temperatures: {ranges} µm",
        f"  {u_info.get('trials')} virtual machines per node in {u_info.get('runs')} run(s), "
        f"seed {u_info.get('seed')}{stable}; probing σ {u_info.get('probe_um')} µm",
    ]
    from .uncertainty import assumption_lines

    lines += [
        f"  {line}"
        for line in assumption_lines(u_info.get("defaulted", []), u_info.get("taken_as_zero", []))
    ]
    return lines


def cmd_grid_keygen(args: argparse.Namespace) -> int:
    """``cmm-comp grid keygen --out DIR``: a new Ed25519 grid-signing key pair."""
    from cmm_comp.compensation.grid.signing import generate_signing_key, key_id, load_public_key

    private, public = generate_signing_key(args.out)
    print(
        f"wrote {private} (private, keep it with whoever builds grids) and {public} "
        f"(public, for the daemon's grid.public_key); key id {key_id(load_public_key(public))}"
    )
    return 0


def cmd_grid_sign(args: argparse.Namespace) -> int:
    """``cmm-comp grid sign GRID --key PRIVATE.pem``: sign a grid file in place."""
    from cmm_comp.compensation.grid.signing import sign_grid

    kid = sign_grid(args.grid, args.key)
    print(f"signed {args.grid} with key {kid}")
    return 0


def read_points_csv(path: Path) -> tuple[list[str], list[list[str]], dict[str, np.ndarray]]:
    """Header, raw rows and float columns of a POINTS.csv; ValueError names file/line/column."""
    import numpy as np

    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            rows = [row for row in reader if any(cell.strip() for cell in row)]
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    for name in ("x", "y", "z"):
        if name not in header:
            raise ValueError(f"{path}: missing column {name!r} (required: x, y, z)")
    wanted = [c for c in ("x", "y", "z", "px", "py", "pz", *_signal_columns()) if c in header]
    cols = {c: np.empty(len(rows)) for c in wanted}
    for line, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise ValueError(f"{path}:{line}: {len(row)} cells, the header has {len(header)}")
        for c in wanted:
            cell = row[header.index(c)].strip()
            try:
                cols[c][line - 2] = float(cell) if cell else math.nan
            except ValueError:
                raise ValueError(f"{path}:{line}: column {c!r}: not a number: {cell!r}") from None
    return header, rows, cols


def cmd_correct(args: argparse.Namespace) -> int:
    """``cmm-comp correct GRID --in POINTS.csv --out OUT.csv``."""
    import numpy as np

    from cmm_comp.compensation.grid import CorrectionGrid

    grid = CorrectionGrid.load(args.grid)
    header, rows, cols = read_points_csv(Path(args.input))
    pts = np.c_[cols["x"], cols["y"], cols["z"]]
    if all(c in cols for c in ("px", "py", "pz")):
        stylus = np.c_[cols["px"], cols["py"], cols["pz"]]
    else:
        stylus = np.asarray(grid.metadata.get("probe_offset_mm", [0.0, 0.0, 0.0]), float)
    signals = {c: cols[c] for c in _signal_columns() if c in cols}
    temps = {k: v for k, v in signals.items() if k.startswith("T_")}
    inputs = {k: v for k, v in signals.items() if not k.startswith("T_")}
    corrected, status, u_um = grid.correct_with_uncertainty(
        pts, stylus, temps or None, inputs or None
    )
    out = Path(args.output)
    buf = io.StringIO(newline="")
    writer = csv.writer(buf)
    writer.writerow([*header, "cx", "cy", "cz", "Ux_um", "Uy_um", "Uz_um", "status"])
    for row, c, u, st in zip(rows, corrected, u_um, status, strict=True):
        cells = ["" if math.isnan(v) else f"{v:.6f}" for v in c]
        u_cells = ["" if math.isnan(v) else f"{v:.4f}" for v in u]
        writer.writerow([*row, *cells, *u_cells, st])
    write_text_atomic(out, buf.getvalue())
    n_ok = int(np.sum(status == "ok"))
    print(f"wrote {out}: {len(rows)} points, {n_ok} ok, {len(rows) - n_ok} flagged")
    if not grid.has_uncertainty:
        print(
            "cmm-comp: note: the grid carries no uncertainty: Ux_um, Uy_um, Uz_um are empty "
            "(build it with `cmm-comp grid build --uncertainty`)",
            file=sys.stderr,
        )
    return 0


def add_parsers(sub: Subparsers) -> None:
    """Add ``grid build`` and ``correct`` to the ``cmm-comp`` subcommands."""
    p = sub.add_parser("grid", help="correction grid files")
    grid_sub = p.add_subparsers(dest="grid_command", required=True)
    b = grid_sub.add_parser("build", help="evaluate the model at every node and write a grid file")
    b.add_argument("machine", type=Path, help="machine description (machine.toml)")
    b.add_argument("-o", "--output", type=Path, required=True, help="grid file to write")
    b.add_argument(
        "--steps",
        nargs=3,
        type=int,
        metavar=("NX", "NY", "NZ"),
        help="nodes per axis (default: the machine's [volume] steps)",
    )
    b.add_argument(
        "--uncertainty",
        action="store_true",
        help="also store U per node from the virtual CMM (docs/uncertainty.md)",
    )
    b.add_argument(
        "--uncertainty-trials",
        type=int,
        default=1000,
        metavar="N",
        help="virtual machines per node (default 1000; the adaptive runs' size with "
        "--uncertainty-tolerance)",
    )
    b.add_argument(
        "--uncertainty-tolerance",
        type=float,
        metavar="REL",
        help="adaptive: add runs until every node's u is stable to REL (2s ≤ REL·u), e.g. 0.05",
    )
    b.add_argument("--seed", type=int, default=0, help="random seed of the virtual CMM (default 0)")
    b.set_defaults(handler=cmd_grid_build)
    i = grid_sub.add_parser(
        "info",
        help="what a grid file holds: steps, signals, probe, U, signature",
        description="Print a grid file's header in words: machine, volume and steps, the "
        "signals the correction needs, the probe offset, U (k = 2) at the nodes with how it was "
        "computed and what it assumed (grid build --uncertainty), provenance and signature. "
        "The file is checked as the daemon checks it (format, SHA-256).",
    )
    i.add_argument("grid", type=Path, help="grid file")
    i.add_argument(
        "--public-key",
        type=Path,
        metavar="PEM",
        help="verify the signature with this public key (grid keygen's .pub.pem)",
    )
    i.add_argument("--json", action="store_true", help="the raw header as JSON instead")
    i.set_defaults(handler=cmd_grid_info)
    k = grid_sub.add_parser("keygen", help="make an Ed25519 key pair for signing grids")
    k.add_argument(
        "--out", type=Path, required=True, help="folder for the two PEM files (never overwritten)"
    )
    k.set_defaults(handler=cmd_grid_keygen)
    s = grid_sub.add_parser(
        "sign", help="sign a grid file (Ed25519 over its SHA-256 and header) in place"
    )
    s.add_argument("grid", type=Path, help="grid file")
    s.add_argument("--key", type=Path, required=True, help="private key PEM (grid keygen)")
    s.set_defaults(handler=cmd_grid_sign)
    c = sub.add_parser(
        "correct",
        help="correct indicated points with a grid (CSV in, CSV out)",
        description="Correct indicated points with a grid: corrected = indicated + error "
        "(error = true − indicated, docs/conventions.md).",
        epilog=CORRECT_COLUMNS,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument("grid", type=Path, help="grid file")
    c.add_argument(
        "--in", dest="input", type=Path, required=True, help="POINTS.csv (columns below)"
    )
    c.add_argument("--out", dest="output", type=Path, required=True, help="OUT.csv (columns below)")
    c.set_defaults(handler=cmd_correct)
