"""Noise of the two instruments (µm).

* the machine: white (servo jitter, vibration between carriage and target), σ_m;
* the reference: white σ_r, plus a little correlated noise (air turbulence in the beam, a
  sensor's slow electronics: an Ornstein–Uhlenbeck process of σ_c = 10–40 % of σ_r and
  correlation time 0.3–3 s), and its resolution (the reading is rounded to it: the ESS
  triangulation sensor's step is 0.41 µm).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
RESOLUTIONS_UM = (0.01, 0.02, 0.05, 0.1, 0.2, 0.4)


@dataclass(frozen=True)
class Noise:
    machine_sigma_um: float
    ref_sigma_um: float
    corr_sigma_um: float
    corr_time_s: float
    resolution_um: float

    @property
    def total_sigma_um(self) -> float:
        """σ of the observed error from all parts (white + correlated + rounding)."""
        parts = (self.machine_sigma_um, self.ref_sigma_um, self.corr_sigma_um)
        return float(np.sqrt(sum(p * p for p in parts) + self.resolution_um**2 / 12))

    def machine_um(self, rng: np.random.Generator, n: int) -> FloatArray:
        return rng.normal(0.0, self.machine_sigma_um, n)

    def reference_um(self, rng: np.random.Generator, t_s: FloatArray) -> FloatArray:
        """White plus an exact OU process sampled at the (irregular) times t (s)."""
        t_s = np.asarray(t_s, dtype=float)
        white = rng.normal(0.0, self.ref_sigma_um, t_s.size)
        rho = np.exp(-np.diff(t_s, prepend=t_s[:1]) / self.corr_time_s)
        eps = rng.normal(0.0, 1.0, t_s.size)
        ou = np.empty(t_s.size)
        ou[0] = self.corr_sigma_um * eps[0]
        for k in range(1, t_s.size):
            ou[k] = rho[k] * ou[k - 1] + self.corr_sigma_um * np.sqrt(1 - rho[k] ** 2) * eps[k]
        return white + ou

    def describe(self) -> dict[str, float]:
        return {
            "machine_sigma_um": round(self.machine_sigma_um, 4),
            "ref_sigma_um": round(self.ref_sigma_um, 4),
            "corr_sigma_um": round(self.corr_sigma_um, 4),
            "corr_time_s": round(self.corr_time_s, 3),
            "resolution_um": self.resolution_um,
            "total_sigma_um": round(self.total_sigma_um, 4),
        }


def draw_noise(rng: np.random.Generator) -> Noise:
    sig_r = float(np.exp(rng.uniform(np.log(0.1), np.log(0.8))))
    res = [r for r in RESOLUTIONS_UM if r <= 2 * sig_r]
    return Noise(
        machine_sigma_um=float(np.exp(rng.uniform(np.log(0.05), np.log(0.4)))),
        ref_sigma_um=sig_r,
        corr_sigma_um=sig_r * float(rng.uniform(0.1, 0.4)),
        corr_time_s=float(np.exp(rng.uniform(np.log(0.3), np.log(3.0)))),
        resolution_um=float(rng.choice(res)),
    )
