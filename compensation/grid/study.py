"""The interpolation study of ``docs/interpolation.md``: run ``python -m cmm_comp.compensation.grid.study``.

Compares, against the exact field, at random points and for several grid densities:

* **Squad** — the correction grid (tensor Squad rotations, C² cubic-spline translations);
* **Slerp** — tensor-trilinear Slerp of the node quaternions, trilinear translations;
* **matrix-linear** — componentwise trilinear interpolation of the 9 rotation-matrix entries
  (not a rotation: reports ‖RᵀR − I‖), trilinear translations;
* **Zhang** — trilinear lookup of the correction vector itself for one fixed stylus
  (Zhang et al. 1985), which cannot serve another stylus without a new table.

Metric: the position error (µm) at a stylus 150 mm long, worst direction
(150 mm · ‖R − R_exact‖₂ for the rotation part) and for the fixed stylus (0, 0, −150) mm in
total. Quaternions (w, x, y, z).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import RegularGridInterpolator

from . import quaternion as qt
from .correction_grid import CorrectionGrid
from .field import AnalyticErrorField

FloatArray = NDArray[np.float64]
STYLUS_LEN_MM = 150.0
FIXED_STYLUS = np.array([0.0, 0.0, -STYLUS_LEN_MM])
STEPS = (5, 8, 10, 15, 20, 30, 40)


def _trilinear_slerp(grid: CorrectionGrid, pts: FloatArray) -> FloatArray:
    q = grid.q_work_stylus
    idx, h = [], []
    for k in range(3):
        u = (
            (pts[:, k] - grid.lower_mm[k])
            / (grid.upper_mm[k] - grid.lower_mm[k])
            * (grid.steps[k] - 1)
        )
        i = np.clip(np.floor(u).astype(int), 0, grid.steps[k] - 2)
        idx.append(i)
        h.append(u - i)
    i, j, k = idx
    cx = {}
    for a in (0, 1):
        for b in (0, 1):
            cx[a, b] = qt.slerp(q[i, j + a, k + b], q[i + 1, j + a, k + b], h[0])
    cy = {b: qt.slerp(cx[0, b], cx[1, b], h[1]) for b in (0, 1)}
    return qt.slerp(cy[0], cy[1], h[2])


def _spectral(m: FloatArray) -> FloatArray:
    return np.linalg.norm(m, ord=2, axis=(1, 2))


def study_field(
    machine: Any, label: str, temps: dict[str, float], n_pts: int = 20000
) -> list[dict[str, Any]]:
    """Errors of the four methods for ``machine`` over :data:`STEPS` (one row per density)."""
    rng = np.random.default_rng(12345)
    lo = np.asarray(machine.volume.lower_mm, float)
    hi = np.asarray(machine.volume.upper_mm, float)
    pts = rng.uniform(lo, hi, size=(n_pts, 3))
    exact = machine.pose_error(pts, temps_C=temps)
    r_exact = np.asarray(exact.rotation)
    t_exact = np.asarray(exact.translation_um)
    e_fixed = machine.volumetric_error(pts, FIXED_STYLUS, temps)
    angle_urad = 1e6 * np.linalg.norm(
        qt.rotvec_from_quaternion(qt.quaternion_from_matrix(r_exact)), axis=1
    )
    rows = []
    for n in STEPS:
        steps = (n, n, n)
        grid = CorrectionGrid.build(machine, steps=steps)
        nodes = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, 3)
        node_pose = machine.pose_error(nodes, temps_C=temps)
        r_nodes = np.asarray(node_pose.rotation).reshape(*steps, 9)
        t_nodes = np.asarray(node_pose.translation_um).reshape(*steps, 3)
        e_nodes = machine.volumetric_error(nodes, FIXED_STYLUS, temps).reshape(*steps, 3)
        lin_t = RegularGridInterpolator(grid.axes, t_nodes)(pts)
        # Squad grid
        q_sq, t_sq, _ = grid.pose(pts, temps)
        r_sq = qt.matrix_from_quaternion(q_sq)
        e_sq, _ = grid.error_um(pts, FIXED_STYLUS, temps)
        # tensor Slerp
        r_sl = qt.matrix_from_quaternion(_trilinear_slerp(grid, pts))
        # componentwise trilinear matrices
        r_lin = RegularGridInterpolator(grid.axes, r_nodes)(pts).reshape(-1, 3, 3)
        ortho = np.linalg.norm(np.swapaxes(r_lin, 1, 2) @ r_lin - np.eye(3), axis=(1, 2))
        # Zhang: trilinear correction vector for the fixed stylus
        e_zh = RegularGridInterpolator(grid.axes, e_nodes)(pts)

        def total(r: FloatArray, t: FloatArray) -> float:
            e = t + 1000.0 * np.einsum("nij,j->ni", r - np.eye(3), FIXED_STYLUS)
            return float(np.abs(np.linalg.norm(e - e_fixed, axis=1)).max())

        # the part of matrix-linear's error due to lost orthonormality: distance to the
        # nearest rotation (polar factor), times the stylus length
        u_svd, _, vt = np.linalg.svd(r_lin)
        polar = u_svd @ vt
        ortho_pos = 1000.0 * STYLUS_LEN_MM * _spectral(r_lin - polar)
        rows.append(
            {
                "field": label,
                "steps": n,
                "max_angle_urad": float(angle_urad.max()),
                "rot_pos_um": {
                    "squad": float((1000.0 * STYLUS_LEN_MM * _spectral(r_sq - r_exact)).max()),
                    "slerp": float((1000.0 * STYLUS_LEN_MM * _spectral(r_sl - r_exact)).max()),
                    "matrix_linear": float(
                        (1000.0 * STYLUS_LEN_MM * _spectral(r_lin - r_exact)).max()
                    ),
                },
                "ortho_loss": float(ortho.max()),
                "ortho_pos_um": float(ortho_pos.max()),
                "total_fixed_stylus_um": {
                    "squad": float(np.linalg.norm(e_sq - e_fixed, axis=1).max()),
                    "slerp": total(r_sl, lin_t),
                    "matrix_linear": total(r_lin, lin_t),
                    "zhang": float(np.linalg.norm(e_zh - e_fixed, axis=1).max()),
                },
                "translation_um": {
                    "spline": float(np.linalg.norm(t_sq - t_exact, axis=1).max()),
                    "trilinear": float(np.linalg.norm(lin_t - t_exact, axis=1).max()),
                },
                "error_size_um": float(np.linalg.norm(e_fixed, axis=1).max()),
            }
        )
        print(f"{label:>28} n={n:3d} done", file=sys.stderr)
    return rows


def _plot(results: dict[str, list[dict[str, Any]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5.2 * len(results), 4.4), sharex=True)
    styles = {
        "squad": ("Squad + cubic spline (this grid)", "C0", "o-"),
        "slerp": ("tensor Slerp + trilinear", "C1", "s-"),
        "matrix_linear": ("trilinear matrices + trilinear", "C2", "^-"),
        "zhang": ("Zhang: trilinear correction vector", "C3", "v--"),
    }
    for ax, (label, rows) in zip(np.atleast_1d(axes), results.items(), strict=True):
        steps = [r["steps"] for r in rows]
        for key, (name, color, fmt) in styles.items():
            ax.loglog(
                steps, [r["total_fixed_stylus_um"][key] for r in rows], fmt, color=color, label=name
            )
        ax.loglog(
            steps,
            [r["ortho_pos_um"] for r in rows],
            ":",
            color="C2",
            label="… of which: lost orthonormality",
        )
        ax.set_title(f"{label}\n(max rotation {rows[0]['max_angle_urad']:.0f} µrad)", fontsize=10)
        ax.set_xlabel("grid nodes per axis")
        ax.grid(True, which="both", alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("max position error at 150 mm stylus (µm)")
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the study, write ``docs/img/interpolation.png`` and print a markdown table."""
    root = Path(__file__).resolve().parents[1]
    t0 = time.perf_counter()
    results: dict[str, list[dict[str, Any]]] = {}
    ref = {"T_x": 20.0, "T_top": 20.0}
    results["analytic, realistic (30 µrad)"] = study_field(
        AnalyticErrorField(rotation_urad=30.0), "analytic 30 µrad", ref
    )
    results["analytic, exaggerated (3 mrad)"] = study_field(
        AnalyticErrorField(rotation_urad=3000.0), "analytic 3 mrad", ref
    )
    example = root / "examples" / "machines" / "npl-bridge.toml"
    if example.is_file():
        from ..machine import Machine

        machine = Machine.from_toml(example)
        temps = dict(machine.runtime_signals())
        results["npl-bridge (real model)"] = study_field(machine, "npl-bridge", temps)
    _plot(results, root / "docs" / "img" / "interpolation.png")
    out = root / "benchmarks" / "results" / "interpolation.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))
    print(
        "| field | nodes/axis | Squad | Slerp | matrix-linear | (orthonormality part) | ‖RᵀR−I‖ max | Zhang vector | error size |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for label, rows in results.items():
        for r in rows:
            tf = r["total_fixed_stylus_um"]
            print(
                f"| {label} | {r['steps']} | {tf['squad']:.3g} | {tf['slerp']:.3g} | {tf['matrix_linear']:.3g} "
                f"| {r['ortho_pos_um']:.2g} | {r['ortho_loss']:.2g} | {tf['zhang']:.3g} | {r['error_size_um']:.3g} |"
            )
    print(
        "\n| field | nodes/axis | rotation part at 150 mm: Squad | Slerp | matrix-linear | translation: spline | trilinear |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, rows in results.items():
        for r in rows:
            rp, tr = r["rot_pos_um"], r["translation_um"]
            print(
                f"| {label} | {r['steps']} | {rp['squad']:.3g} | {rp['slerp']:.3g} | {rp['matrix_linear']:.3g} "
                f"| {tr['spline']:.3g} | {tr['trilinear']:.3g} |"
            )
    print(f"\n(study took {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
