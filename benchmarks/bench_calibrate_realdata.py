"""Real data: each ISO 230-2 run of ../shared/realdata calibrates its axis' positional table
(``cmm-comp calibrate``, cycles 1–3), and ``cmm-comp iso230`` evaluates the *other* cycles (4–5)
uncorrected and corrected (``cmm-comp calibrate apply``): a cross-validated gain, not in-sample.

    python benchmarks/bench_calibrate_realdata.py

Prints E, M, R, A (µm, ISO 230-2) before/after per run and writes
benchmarks/results/calibrate_realdata.json. Exits 0 with a message when the data are absent.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REALDATA = ROOT.parent / "shared" / "realdata"
CLI = [sys.executable, "-m", "cmm_comp.cli"]
Runner = Callable[[list[str], Path], None]  # runs one ``cmm-comp`` command in a folder
CALIBRATE_CYCLES = (1, 2, 3)
CHECK_CYCLES = (4, 5)
#: (file, axis, a-priori σ of one reading µm: the runs' repeatability order of magnitude)
RUNS = (
    ("ess-target-b02/target_x.md_ISO230.dat", "x", 2.0),
    ("ess-target-b02/report_target_y.md_ISO230.dat", "y", 2.0),
    ("ess-target-b02/report_z.md_ISO230.dat", "z", 0.5),
    ("psi-ecmccfg/report.md_ISO230.dat", "x", 0.01),
)
PARAMETERS = ("E_um", "M_um", "R_um", "A_um")


def plan_text(dat: Path, axis: str, u_um: float) -> str:
    """A one-axis plan: the axis' travel over the targets, only its positional table."""
    from cmm_comp.compensation.formats.realdata import read_iso230_dat

    run = read_iso230_dat(dat)
    lo, hi = float(run.target_mm.min()), float(run.target_mm.max())
    volume = {a: (lo, hi) if a == axis else (0.0, 1.0) for a in "xyz"}
    nodes = {a: len(run.target_mm) if a == axis else 2 for a in "xyz"}
    lines = ['model = "MB1"', f'name = "{dat.parent.name}-{axis}"', "", "[volume]"]
    lines += [f"{a} = [{volume[a][0]}, {volume[a][1]}]" for a in "xyz"]
    lines += [
        "",
        "[fit]",
        f'components = ["d{axis}_{axis}"]',
        "nodes = {" + ", ".join(f"{a} = {nodes[a]}" for a in "xyz") + "}",
        "",
        "[[laser]]",
        f'file = "{dat}"',
        f'axis = "{axis}"',
        f"cycles = {list(CALIBRATE_CYCLES)}",
        f"u_linear_um = {u_um}",
        "",
    ]
    return "\n".join(lines)


def run_subprocess(args: list[str], cwd: Path) -> None:
    """``cmm-comp ARGS`` in ``cwd`` as a user runs it (a subprocess); fails on a non-zero exit."""
    subprocess.run([*CLI, *args], cwd=cwd, check=True, capture_output=True)


def iso(dat: Path, cwd: Path, run: Runner = run_subprocess) -> dict[str, float]:
    out = cwd / "iso.json"
    run(["iso230", str(dat), "--json", str(out)], cwd)
    data = json.loads(out.read_text())
    return {k: float(data[k]) for k in PARAMETERS}


def evaluate(
    rel: str, axis: str, u_um: float, tmp: Path, run: Runner = run_subprocess
) -> dict[str, object]:
    """Calibrate on the first cycles, evaluate the held-out ones; ``run`` runs one ``cmm-comp``
    command (a subprocess here; the test passes the CLI's ``main()`` in its own process)."""
    dat = REALDATA / rel
    folder = tmp / rel.replace("/", "_")
    folder.mkdir()
    (folder / "plan.toml").write_text(plan_text(dat, axis, u_um))
    run(["calibrate", "plan.toml", "-o", "machine.toml", "--report", "report", "--quiet"], folder)
    cycles = [str(c) for c in CHECK_CYCLES]
    for name, extra in (("before.dat", ["--uncorrected"]), ("after.dat", [])):
        apply = ["calibrate", "apply", "machine.toml", str(dat), "--axis", axis, "--cycles"]
        run([*apply, *cycles, *extra, "-o", name], folder)
    report = json.loads((folder / "report" / "calibration.json").read_text())
    return {
        "file": rel,
        "axis": axis,
        "calibrated_on_cycles": list(CALIBRATE_CYCLES),
        "evaluated_on_cycles": list(CHECK_CYCLES),
        "before": iso(folder / "before.dat", folder, run),
        "after": iso(folder / "after.dat", folder, run),
        "fit_rms_um": report["datasets"][0]["rms_after_um"],
        "reversal_written": bool(report["reversal_half_um"]),
    }


def main() -> int:
    if not REALDATA.is_dir():
        print(f"{REALDATA} is absent: nothing to evaluate")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        results = [evaluate(rel, axis, u, Path(tmp)) for rel, axis, u in RUNS]
    print(f"{'run':<46} {'':>6}" + "".join(f"{p[0]:>10}" for p in PARAMETERS))
    for r in results:
        for when in ("before", "after"):
            vals = r[when]  # type: ignore[index]
            print(f"{r['file']:<46} {when:>6}" + "".join(f"{vals[p]:>10.3f}" for p in PARAMETERS))
    out = {
        "method": f"calibrated on cycles {list(CALIBRATE_CYCLES)}, ISO 230-2 on cycles "
        f"{list(CHECK_CYCLES)} (held out), values µm",
        "runs": results,
    }
    path = ROOT / "benchmarks" / "results" / "calibrate_realdata.json"
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
