"""A simulated CMM: turns true stylus-tip positions into the indicated positions its scales show.

The machine's error model says ``true = indicated + error(indicated)`` (error in µm, evaluated
at the indicated position, docs/formats.md), so the indicated position of a true point ``t`` is the
fixed point of ``q ← t − error(q)/1000``; the iteration contracts because ‖∂error/∂q‖ is
~10⁻⁵ µm/µm, and converges to < 1 nm in a few steps. Probing noise is Gaussian, along the
probing direction when one is given (σ = the machine's ``probe.random_um`` / 2, that value
being a 2σ band) else isotropic. Temperatures are those of :class:`Environment`.

Any :class:`compensation.Machine` works, including one with hidden effects (e.g. the true
machine of :mod:`sim_controller.true_machine`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cmm_comp.compensation.machine import Machine

FloatArray = NDArray[np.float64]


@dataclass
class Environment:
    """Temperatures of the machine's sensors: constant values plus a linear drift.

    ``temps_C`` role → °C at t = 0; ``drift_C_per_s`` role → °C/s; ``sensors`` sensor id → role
    (the ids the controller sends on the bus). The defaults are a shop at ~21 °C with a
    workpiece just brought in from a cooler store.
    """

    temps_C: dict[str, float] = field(
        default_factory=lambda: {"T_x": 21.0, "T_y": 21.2, "T_z": 21.4, "T_wp": 19.5}
    )
    drift_C_per_s: dict[str, float] = field(default_factory=dict)
    sensors: dict[int, str] = field(
        default_factory=lambda: {0: "T_x", 1: "T_y", 2: "T_z", 3: "T_wp"}
    )

    def at(self, t_s: float) -> dict[str, float]:
        """Temperatures by role at time ``t_s`` (s since the start), °C."""
        return {r: v + self.drift_C_per_s.get(r, 0.0) * t_s for r, v in self.temps_C.items()}

    def samples(self, t_s: float) -> dict[int, float]:
        """Temperature by sensor id at ``t_s``, rounded to the 0.001 °C the bus carries, °C."""
        temps = self.at(t_s)
        return {sid: round(temps[role], 3) for sid, role in self.sensors.items() if role in temps}


class SimulatedMachine:
    """Indicated positions of true points on ``machine`` at given temperatures, with noise.

    :param stylus_mm: stylus tip offset used for all points, mm.
    :param noise_um: 1σ probing noise, µm; None = half the machine's ``probe.random_um``.
    """

    def __init__(
        self,
        machine: Machine,
        stylus_mm: ArrayLike = (0.0, 0.0, 0.0),
        noise_um: float | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.machine = machine
        self.stylus_mm = np.asarray(stylus_mm, dtype=float)
        self.noise_um = machine.probe.random_um / 2 if noise_um is None else float(noise_um)
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def indicated_from_true(
        self,
        true_mm: ArrayLike,
        temps_C: Mapping[str, float] | None = None,
        probe_dirs: ArrayLike | None = None,
        tol_mm: float = 1e-7,
        max_iter: int = 20,
    ) -> FloatArray:
        """Indicated positions (N, 3) mm of true points (N, 3) mm, noise included.

        ``probe_dirs`` (N, 3) unit vectors put the noise along the probing direction (rows of
        zeros: isotropic noise).
        Raises RuntimeError if the fixed-point iteration does not converge.
        """
        t = np.atleast_2d(np.asarray(true_mm, dtype=float))
        q = t.copy()
        for _ in range(max_iter):
            err_um = self.machine.volumetric_error(q, self.stylus_mm, temps_C)
            new = t - err_um / 1000.0
            step = np.abs(new - q).max()
            q = new
            if step < tol_mm:
                break
        else:
            raise RuntimeError(f"indicated position did not converge (last step {step:.3g} mm)")
        return q + self.noise_mm(len(q), probe_dirs)

    def noise_mm(self, n: int, probe_dirs: ArrayLike | None = None) -> FloatArray:
        """Probing noise (n, 3) mm: along ``probe_dirs`` rows, isotropic where a row is zero."""
        if self.noise_um <= 0:
            return np.zeros((n, 3))
        if probe_dirs is None:
            return self.rng.normal(0.0, self.noise_um / np.sqrt(3) / 1000.0, (n, 3))
        dirs = np.asarray(probe_dirs, dtype=float).reshape(n, 3)
        along = dirs * self.rng.normal(0.0, self.noise_um / 1000.0, (n, 1))
        iso = self.rng.normal(0.0, self.noise_um / np.sqrt(3) / 1000.0, (n, 3))
        has_dir = np.linalg.norm(dirs, axis=1, keepdims=True) > 0.5
        return np.where(has_dir, along, iso)
