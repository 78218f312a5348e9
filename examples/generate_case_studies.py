"""Write the two bundled example machines, shaped like the paper's case studies (section 6).

The paper's raw calibration data is not public: these are smooth synthetic tables with the
bandwidths the paper reports (fixed seed, so the files are reproducible). Run:
``python examples/generate_case_studies.py`` (rewrites ``examples/machines/*.toml``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tomli_w

HERE = Path(__file__).resolve().parent / "machines"


def smooth_profile(rng: np.random.Generator, q: np.ndarray, bandwidth: float) -> np.ndarray:
    """A smooth random curve over q with peak-to-valley ``bandwidth``, zero at q[0]."""
    span = q[-1] - q[0]
    s = (q - q[0]) / span
    curve = rng.normal() * s + sum(
        rng.normal() / k * np.sin(k * np.pi * s + rng.uniform(0, 2 * np.pi)) for k in range(1, 5)
    )
    curve = curve - curve[0]
    return curve / np.ptp(curve) * bandwidth


def table(q: np.ndarray, values: np.ndarray, random: float | None = None) -> dict:
    out = {
        "position": [round(float(v), 3) for v in q],
        "value": [round(float(v), 3) for v in values],
    }
    if random is not None:
        out["random_band"] = random
    return out


def gec_mh2() -> dict:
    """Moving horizontal arm, MH2, 1800 × 1200 × 1200 mm, 13 × 9 × 9 steps, 15 errors."""
    rng = np.random.default_rng(1990)
    qx, qy, qz = np.linspace(0, 1800, 19), np.linspace(0, 1200, 13), np.linspace(0, 1200, 13)
    errors = {
        # 3 positional
        "dx_x": table(qx, smooth_profile(rng, qx, 65.59)),  # paper fig. 2a: 65.59 µm bandwidth
        "dy_y": table(qy, smooth_profile(rng, qy, 18.0)),
        "dz_z": table(qz, smooth_profile(rng, qz, 22.0)),
        # 4 straightness
        "dy_x": table(qx, smooth_profile(rng, qx, 14.0)),
        "dz_x": table(qx, smooth_profile(rng, qx, 25.0)),
        "dx_z": table(qz, smooth_profile(rng, qz, 9.0)),
        "dy_z": table(qz, smooth_profile(rng, qz, 7.0)),
        # 5 angular
        "ey_x": table(qx, smooth_profile(rng, qx, 74.95)),  # paper fig. 2b: X pitch 74.95 µm/m
        "ez_x": table(qx, smooth_profile(rng, qx, 30.0)),
        "ex_x": table(qx, smooth_profile(rng, qx, 20.0)),
        "ex_z": table(qz, smooth_profile(rng, qz, 15.0)),
        "ez_z": table(qz, smooth_profile(rng, qz, 12.0)),
    }
    return {
        "format": "cmm-machine/1",
        "name": "gec-mh2",
        "model": "MH2",
        "meta": {
            "note": "synthetic, shaped like Park et al. section 6.1 (GEC Preston); not the paper's data"
        },
        "volume": {
            "x": [0.0, 1800.0],
            "y": [0.0, 1200.0],
            "z": [0.0, 1200.0],
            "reference": [0.0, 0.0, 0.0],
            "steps": [13, 9, 9],
        },
        "probe": {"offset": [0.0, 0.0, 0.0]},
        "thermal": {"reference_C": 20.0, "expansion": {"x": 11.5, "y": 11.5, "z": 11.5}},
        "squareness": {"alpha": 25.0, "beta1": -18.0, "beta2": 12.0},
        "errors": errors,
    }


def npl_bridge() -> dict:
    """Moving bridge, MB1, 900 × 1150 × 400 mm, 19 × 23 × 16 steps, 17 errors with random parts."""
    rng = np.random.default_rng(1984)
    qx, qy, qz = np.linspace(0, 900, 19), np.linspace(0, 1150, 24), np.linspace(0, 400, 9)
    errors = {
        "dx_x": table(qx, smooth_profile(rng, qx, 6.15), random=6.15),  # fig. 3a
        "dy_y": table(qy, smooth_profile(rng, qy, 5.0), random=2.0),
        "dz_z": table(qz, smooth_profile(rng, qz, 3.0), random=1.5),
        "dy_x": table(qx, smooth_profile(rng, qx, 3.40), random=15.6),  # fig. 3b
        "dz_x": table(qx, smooth_profile(rng, qx, 4.0), random=2.0),
        "dx_y": table(qy, smooth_profile(rng, qy, 4.5), random=2.0),
        "dz_y": table(qy, smooth_profile(rng, qy, 6.0), random=2.0),
        "ey_x": table(qx, smooth_profile(rng, qx, 11.18), random=12.3),  # fig. 3c
        "ez_x": table(qx, smooth_profile(rng, qx, 8.0), random=3.0),
        "ex_x": table(qx, smooth_profile(rng, qx, 6.0), random=3.0),
        "ex_y": table(qy, smooth_profile(rng, qy, 7.0), random=3.0),
        "ey_y": table(qy, smooth_profile(rng, qy, 9.0), random=3.0),
        "ez_y": table(qy, smooth_profile(rng, qy, 6.0), random=3.0),
        "ex_z": table(qz, smooth_profile(rng, qz, 5.0), random=2.0),
    }
    return {
        "format": "cmm-machine/1",
        "name": "npl-bridge",
        "model": "MB1",
        "meta": {
            "note": "synthetic, shaped like Park et al. section 6.2 (NPL); not the paper's data"
        },
        "volume": {
            "x": [0.0, 900.0],
            "y": [0.0, 1150.0],
            "z": [0.0, 400.0],
            "reference": [0.0, 0.0, 0.0],
            "steps": [19, 23, 16],
        },
        "probe": {"offset": [0.0, 0.0, -120.0], "random_um": 0.5},
        "thermal": {
            "reference_C": 20.0,
            "expansion": {"x": 10.5, "y": 10.5, "z": 10.5},
            "workpiece_expansion": 11.5,
            "workpiece_fixture": [450.0, 575.0, 0.0],
        },
        "squareness": {"alpha": 12.0, "beta1": -5.0, "beta2": 3.0},
        "errors": errors,
    }


def main(out_dir: Path = HERE) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for data in (gec_mh2(), npl_bridge()):
        path = out_dir / f"{data['name']}.toml"
        path.write_text(tomli_w.dumps(data), encoding="utf-8")
        written.append(path)
        print(f"wrote {path}")
    return written


if __name__ == "__main__":
    import sys

    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
