"""The hand analysis of the ESS X ripple behind docs/discovery.md ("Real data"), apart from the
diagnosis code: numpy least squares only.

    .venv/bin/cmm-comp import camonitor ../shared/realdata/ess-target-b02/x_230_2.log --axis x \\
        --position TARGET_DU:X-PosAct --reference IOC_TEST:ILD_DownSample --out-dir ess-x
    .venv/bin/python docs/img/ess_ripple_analysis.py ess-x/measurements.csv

prints, per 3 mm window of the travel: the local period of the strongest sine (after a smooth
curve per direction of order 14 and a reversal are removed), its amplitude, and how far it
moves between the + and − passes in axis coordinates and in the sensor's reading; then the
triangulation law fitted to the local periods, the drift's change along the axis; and writes
``docs/img/camonitor_ess_x_ripple.png``.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
from numpy.polynomial import legendre

OUT = Path(__file__).resolve().parent / "camonitor_ess_x_ripple.png"
PERIODS = np.linspace(0.12, 0.9, 800)


def load(path: str) -> dict[str, np.ndarray]:
    with open(path, encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    out = {k: np.array([float(r[k]) for r in rows]) for k in ("x", "ref_x", "t", "dir_x", "v_x")}
    out["e"] = (out["ref_x"] - out["x"]) * 1000.0
    return out


def sine(coord: np.ndarray, y: np.ndarray, p: float) -> np.ndarray:
    w = 2 * np.pi / p
    a = np.column_stack([np.cos(w * coord), np.sin(w * coord), np.ones_like(coord), coord])
    return np.linalg.lstsq(a, y, rcond=None)[0]


def main(path: str) -> None:
    d = load(path)
    x, e, dr, ref = d["x"], d["e"], d["dir_x"], d["ref_x"]
    s = x / np.max(np.abs(x))
    res = np.empty_like(e)
    for sign in (1, -1):
        m = dr == sign
        v = legendre.legvander(s[m], 14)
        res[m] = e[m] - v @ np.linalg.lstsq(v, e[m], rcond=None)[0]
    moving = d["v_x"] != 0
    rows = []
    print(" centre  period  amp   shift(pos)  shift(ref)  e(−)−e(+)   [mm, µm]")
    for c in np.arange(-18.5, 19, 2.0):
        m = moving & (np.abs(x - c) < 1.5)
        amps = [np.hypot(*sine(x[m], res[m], p)[:2]) for p in PERIODS]
        p = float(PERIODS[int(np.argmax(amps))])
        shifts = []
        for coord in (x, ref):
            ph = [
                np.arctan2(*sine(coord[m & (dr == g)], res[m & (dr == g)], p)[1::-1])
                for g in (1, -1)
            ]
            shifts.append(((ph[1] - ph[0] + np.pi) % (2 * np.pi) - np.pi) / (2 * np.pi) * p * 1000)
        rev = float(np.mean(e[m & (dr < 0)]) - np.mean(e[m & (dr > 0)]))
        rows.append((c, float(np.mean(ref[m])), p, float(max(amps)), *shifts, rev))
        print(f"{c:7.1f} {p:7.3f} {max(amps):5.1f} {shifts[0]:10.1f} {shifts[1]:10.1f} {rev:10.1f}")
    arr = np.array(rows)
    # triangulation: √p linear in the reading, r0 where it crosses zero
    coef = np.polyfit(arr[:, 1], np.sqrt(arr[:, 2]), 1, w=arr[:, 3])
    r0 = -coef[1] / coef[0]
    print(
        f"triangulation law: r0 = {r0:.1f} mm (axis frame), p(0) = {np.polyval(coef, 0) ** 2:.3f} mm"
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    rr = np.linspace(arr[:, 1].min(), arr[:, 1].max(), 100)
    ax[0].plot(arr[:, 1], arr[:, 2], "o", label="local period (3 mm windows)")
    ax[0].plot(rr, np.polyval(coef, rr) ** 2, "-", label=f"p ∝ (r − {r0:.0f} mm)²")
    ax[0].set_xlabel("reference reading r, axis frame (mm)")
    ax[0].set_ylabel("period (mm)")
    ax[0].legend(fontsize=8)
    ax[0].grid(alpha=0.3)
    ax[1].plot(arr[:, 0], arr[:, 4], "o-", label="shift in axis coordinates")
    ax[1].plot(arr[:, 0], arr[:, 5], "s-", label="shift in the sensor's reading")
    ax[1].plot(arr[:, 0], -arr[:, 6], "k--", label="−(e(−) − e(+)), the reversal")
    ax[1].set_xlabel("position x (mm)")
    ax[1].set_ylabel("ripple moved from + to − passes (µm)")
    ax[1].legend(fontsize=8)
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT, dpi=90)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "ess-x/measurements.csv")
