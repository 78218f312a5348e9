"""The harness: run ``cmm-comp calibrate`` on a case and score it against the hidden truth.

What it reads of the calibrate output (the contract, docs/formats.md's calibration section):

* ``OUT.toml`` through the public API only: ``Machine.from_toml(OUT).volumetric_error(nodes,
  stylus_mm=[probe] offset)`` at the grid's nodes: the identified volumetric error;
* ``DIR/volumetric_u.csv``: columns ``x,y,z,ex_um,ey_um,ez_um,Ux_um,Uy_um,Uz_um``, one row per
  node of the plan's [volume] grid (6 × 6 × 6, corners included): the expanded uncertainty U
  (k = 2) per component; its ``e*_um`` must equal the machine's error up to a rigid motion;
* ``DIR/calibration.json``: the contract's keys (``model``, ``errors``, ``squareness``,
  ``volumetric_U_um``, ``datasets`` with ``kind``/``file``/``rms_before_um``/``rms_after_um``,
  ``gauge``, ``condition``); ``gauge`` a non-empty list that names the rigid-body motion.

Score: d = identified − true on the nodes; the best rigid-body motion (3 translations, 3 small
rotations about the grid's centroid, linear least squares over all nodes) is removed from d;
coverage = fraction of (node, component) with |d| ≤ U; RMS ratio = RMS(d) / RMS(true error with
its own best rigid motion removed). Units: mm, µm.
"""

from __future__ import annotations

import csv
import json
import math
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .case import GRID_STEPS, Case
from .machine import grid_nodes

FloatArray = NDArray[np.float64]

COVERAGE_BAR = (0.90, 0.98)
RMS_RATIO_BAR = 0.20
U_COLUMNS = ("x", "y", "z", "ex_um", "ey_um", "ez_um", "Ux_um", "Uy_um", "Uz_um")
JSON_KEYS = ("model", "errors", "squareness", "volumetric_U_um", "datasets", "gauge", "condition")
#: a calibrate(plan, out_toml, report_dir) → (return code, stdout, stderr)
Calibrate = Callable[[Path, Path, Path], tuple[int, str, str]]


# ------------------------------------------------------------------------------ rigid motion
def rigid_basis(nodes_mm: FloatArray) -> FloatArray:
    """(3N, 6) columns: translations x, y, z (µm) and rotations about x, y, z (µrad) of the nodes.

    A rotation ω (µrad) about the centroid c moves node r by ω × (r − c) / 1000 µm.
    """
    r = (np.asarray(nodes_mm, dtype=float) - np.mean(nodes_mm, axis=0)) / 1000.0
    n = r.shape[0]
    basis = np.zeros((n, 3, 6))
    basis[:, :, :3] = np.eye(3)
    for k in range(3):
        omega = np.zeros(3)
        omega[k] = 1.0
        basis[:, :, 3 + k] = np.cross(omega, r)
    return basis.reshape(3 * n, 6)


def remove_rigid(nodes_mm: FloatArray, error_um: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(residual (N, 3) µm, motion (6,) µm/µrad) of the least-squares rigid fit to ``error_um``."""
    a = rigid_basis(nodes_mm)
    b = np.asarray(error_um, dtype=float).reshape(-1)
    motion = np.linalg.lstsq(a, b, rcond=None)[0]
    return (b - a @ motion).reshape(-1, 3), motion


def rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


# ------------------------------------------------------------------------------ reading outputs
def read_u_csv(path: Path) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(nodes mm, error µm, U µm) from ``volumetric_u.csv``; ValueError naming what is wrong."""
    with path.open(encoding="utf-8", newline="") as fh:
        lines = [line for line in fh if line.strip() and not line.lstrip().startswith("#")]
    reader = csv.DictReader(lines)
    missing = [c for c in U_COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise ValueError(f"{path.name}: missing column(s) {missing}; has {reader.fieldnames}")
    rows = [[float(row[c]) for c in U_COLUMNS] for row in reader]
    data = np.array(rows, dtype=float).reshape(-1, len(U_COLUMNS))
    return data[:, :3], data[:, 3:6], data[:, 6:9]


def match_nodes(expected_mm: FloatArray, got_mm: FloatArray, tol_mm: float = 1e-3) -> NDArray[Any]:
    """Index into ``got_mm`` for each expected node; ValueError when the grids differ."""
    if got_mm.shape[0] != expected_mm.shape[0]:
        raise ValueError(f"{got_mm.shape[0]} nodes, expected {expected_mm.shape[0]} (6×6×6)")
    d = np.linalg.norm(expected_mm[:, None, :] - got_mm[None, :, :], axis=2)
    idx = np.argmin(d, axis=1)
    far = d[np.arange(idx.size), idx] > tol_mm
    if far.any() or np.unique(idx).size != idx.size:
        k = int(np.argmax(far)) if far.any() else 0
        raise ValueError(f"the nodes are not the plan's grid (e.g. no node at {expected_mm[k]})")
    return idx


def check_report_json(path: Path, case: Case) -> list[str]:
    """Problems with ``calibration.json`` against the contract (empty when fine)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        return [f"calibration.json unreadable: {exc}"]
    problems = [f"calibration.json: no key {k!r}" for k in JSON_KEYS if k not in doc]
    if doc.get("model") not in (None, case.model):
        problems.append(f"calibration.json: model {doc.get('model')!r}, plan has {case.model!r}")
    gauge = doc.get("gauge")
    text = json.dumps(gauge).lower()
    if not isinstance(gauge, list) or not gauge:
        problems.append("calibration.json: gauge is not a non-empty list")
    elif "rigid" not in text and not ("translation" in text and "rotation" in text):
        problems.append(f"calibration.json: gauge does not name the rigid-body motion: {gauge}")
    datasets = doc.get("datasets") if isinstance(doc.get("datasets"), list) else []
    seen = {(d.get("kind"), Path(str(d.get("file"))).name) for d in datasets if isinstance(d, dict)}
    for ds in case.datasets:
        if (ds["kind"], ds["file"]) not in seen:
            problems.append(f"calibration.json: datasets lacks {ds['kind']} {ds['file']}")
    for d in datasets:
        for key in ("rms_before_um", "rms_after_um"):
            if not isinstance(d, dict) or not _finite(d.get(key)):
                problems.append(f"calibration.json: datasets entry without a finite {key}: {d}")
                break
    for name, entry in (doc.get("errors") or {}).items():
        if not isinstance(entry, dict) or not all(
            k in entry for k in ("position_mm", "value", "u")
        ):
            problems.append(f"calibration.json: errors.{name} lacks position_mm/value/u")
    for name, entry in (doc.get("squareness") or {}).items():
        if not isinstance(entry, dict) or not all(k in entry for k in ("value_urad", "u_urad")):
            problems.append(f"calibration.json: squareness.{name} lacks value_urad/u_urad")
    return problems


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


# ------------------------------------------------------------------------------ scoring
@dataclass
class CaseScore:
    """One case's outcome. Coverage and RMS are NaN when the run or its outputs failed."""

    seed: int
    kind: str
    model: str
    returncode: int
    seconds: float
    coverage: float = math.nan
    hits: int = 0
    values: int = 0
    rms_diff_um: float = math.nan
    rms_true_um: float = math.nan
    rms_ratio: float = math.nan
    median_U_um: float = math.nan
    csv_vs_machine_um: float = math.nan
    problems: list[str] = field(default_factory=list)
    stderr_tail: str = ""

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.problems

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def score_arrays(
    nodes_mm: FloatArray, identified_um: FloatArray, truth_um: FloatArray, u_um: FloatArray
) -> dict[str, float]:
    """Coverage and RMS of identified vs true error on nodes after the rigid-body motion."""
    diff, _ = remove_rigid(nodes_mm, identified_um - truth_um)
    true_free, _ = remove_rigid(nodes_mm, truth_um)
    hits = int(np.count_nonzero(np.abs(diff) <= u_um))
    return {
        "hits": hits,
        "values": int(diff.size),
        "coverage": hits / diff.size,
        "rms_diff_um": rms(diff),
        "rms_true_um": rms(true_free),
        "rms_ratio": rms(diff) / rms(true_free),
    }


def score_outputs(case: Case, out_toml: Path, report_dir: Path, score: CaseScore) -> CaseScore:
    """Fill ``score`` from the files a successful calibrate wrote."""
    from cmm_comp.compensation.machine import Machine  # the public API, the only coupling

    try:
        nodes_csv, err_csv, u_um = read_u_csv(report_dir / "volumetric_u.csv")
        expected = grid_nodes(case.machine.lower_mm, case.machine.upper_mm, GRID_STEPS)
        idx = match_nodes(expected, nodes_csv)
        identified = Machine.from_toml(out_toml).volumetric_error(
            case.nodes_mm, stylus_mm=case.stylus_mm
        )
    except (OSError, ValueError) as exc:
        score.problems.append(f"outputs unreadable: {exc}")
        return score
    u_um, err_csv = u_um[idx], err_csv[idx]
    if not np.all(np.isfinite(u_um)) or np.any(u_um <= 0):
        score.problems.append("volumetric_u.csv: U not finite and positive everywhere")
    score.csv_vs_machine_um = float(
        np.abs(remove_rigid(case.nodes_mm, err_csv - identified)[0]).max()
    )
    if score.csv_vs_machine_um > 0.01:
        score.problems.append(
            f"volumetric_u.csv's error differs from OUT.toml's by {score.csv_vs_machine_um:.3g} µm "
            "beyond a rigid motion"
        )
    for key, value in score_arrays(case.nodes_mm, identified, case.truth_um, u_um).items():
        setattr(score, key, value)
    score.median_U_um = float(np.median(u_um))
    score.problems += check_report_json(report_dir / "calibration.json", case)
    return score


def cmm_comp_command() -> list[str]:
    """The installed ``cmm-comp`` next to this Python (the venv's), else the one on PATH."""
    exe = Path(sys.executable).parent / "cmm-comp"
    return [str(exe)] if exe.exists() else ["cmm-comp"]


def run_cli(
    plan: Path, out_toml: Path, report_dir: Path, timeout_s: float = 900.0
) -> tuple[int, str, str]:
    """``cmm-comp calibrate PLAN -o OUT --report DIR`` as a user types it, in a subprocess."""
    cmd = [
        *cmm_comp_command(),
        "calibrate",
        str(plan),
        "-o",
        str(out_toml),
        "--report",
        str(report_dir),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    return proc.returncode, proc.stdout, proc.stderr


def calibrate_and_score(case: Case, work_dir: Path, calibrate: Calibrate = run_cli) -> CaseScore:
    """Run ``calibrate`` on the case's plan into ``work_dir`` and score the outputs."""
    work_dir.mkdir(parents=True, exist_ok=True)
    out_toml, report_dir = work_dir / "identified.toml", work_dir / "report"
    t0 = time.perf_counter()
    rc, _, stderr = calibrate(case.plan, out_toml, report_dir)
    score = CaseScore(case.seed, case.kind, case.model, rc, time.perf_counter() - t0)
    score.stderr_tail = "\n".join(stderr.strip().splitlines()[-3:])
    if rc != 0:
        score.problems.append(f"calibrate exited {rc}: {score.stderr_tail}")
        return score
    return score_outputs(case, out_toml, report_dir, score)


def pooled(scores: Iterable[CaseScore]) -> dict[str, Any]:
    """Coverage pooled over every (node, component) of every case; RMS ratios per machine."""
    s = list(scores)
    good = [c for c in s if c.values]
    ratios = np.array([c.rms_ratio for c in good])
    hits, values = sum(c.hits for c in good), sum(c.values for c in good)
    return {
        "cases": len(s),
        "scored": len(good),
        "failed": len(s) - len(good),
        "coverage": hits / values if values else math.nan,
        "rms_ratio_median": float(np.median(ratios)) if good else math.nan,
        "rms_ratio_max": float(ratios.max()) if good else math.nan,
        "rms_ratio_within_bar": int(np.count_nonzero(ratios <= RMS_RATIO_BAR)) if good else 0,
    }


def bar_failures(scores: list[CaseScore]) -> list[str]:
    """Why a set of cases misses the issue's bars (empty when every bar holds)."""
    out = [f"{c.kind} {c.model} seed {c.seed}: {'; '.join(c.problems)}" for c in scores if not c.ok]
    p = pooled(scores)
    lo, hi = COVERAGE_BAR
    if not lo <= p["coverage"] <= hi:
        out.append(f"pooled coverage {p['coverage']:.3f} outside [{lo}, {hi}]")
    out += [
        f"{c.kind} {c.model} seed {c.seed}: RMS difference {100 * c.rms_ratio:.1f} % > "
        f"{100 * RMS_RATIO_BAR:.0f} %"
        for c in scores
        if c.values and not c.rms_ratio <= RMS_RATIO_BAR
    ]
    return out


# ------------------------------------------------------------------------------ bad input
_LINE = re.compile(r"\blines?\s+(\d+)(?:\s*(?:-|–|…|\.\.|to)\s*(\d+))?", re.IGNORECASE)


def mentioned_lines(message: str) -> set[int]:
    """Line numbers a message names (``line 7``, ``lines 7-9`` → {7, 8, 9})."""
    out: set[int] = set()
    for m in _LINE.finditer(message):
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        out.update(range(a, b + 1) if 0 <= b - a < 100000 else (a, b))
    return out


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("cmm-comp: error:")]
