"""Issue 24: a twin is judged at the term's own shape, so only the coordinate is compared.

Without a reversal (and without a latency) the carriage stands where the axis says: the
distance the sensor looks at *is* the indicated position, so a cyclic error of the sensor's
reading and one of the axis' position predict the same readings, point for point — whatever
its shape (harmonics, an amplitude that changes along the range). The session cannot tell the
two instruments apart: the source is ``either`` and the twin's Δχ² is noise. The oracle is
numpy on the simulated session (the same columns at both coordinates, least squares), not the
diagnosis' code path; the diagnosis once refuted the machine's twin by Δχ² ≈ 5 000–60 000 on
such sessions because it offered the twin only its own (constant-amplitude) shapes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.polynomial import legendre
from scipy import stats
from two_instrument_sessions import Truth, simulate

from cmm_comp.compensation import Machine
from cmm_comp.compensation.diagnosis import diagnose
from cmm_comp.compensation.formats.measurements import read_measurements

PERIOD_MM = 0.37
AMPLITUDE_UM = 6.0
NOISE_UM = 0.5


def _ripple_um(x_mm: np.ndarray) -> np.ndarray:
    """A sensor ripple of constant period whose amplitude grows by ±60 % along ±20 mm, with a
    5 % second harmonic."""
    phase = 2.0 * np.pi * x_mm / PERIOD_MM
    amp = AMPLITUDE_UM * (1.0 + 0.6 * x_mm / 20.0)
    return amp * (np.cos(phase + 0.3) + 0.05 * np.cos(2.0 * phase + 1.0))


def _columns(coord_mm: np.ndarray) -> np.ndarray:
    """cos/sin of two harmonics × an envelope of order 1, and an offset (numpy, apart)."""
    phase = 2.0 * np.pi * coord_mm / PERIOD_MM
    env = legendre.legvander(coord_mm / 20.0, 1)
    cols = [np.ones_like(coord_mm)]
    for n in (1, 2):
        for j in range(env.shape[1]):
            cols += [env[:, j] * np.cos(n * phase), env[:, j] * np.sin(n * phase)]
    return np.column_stack(cols)


def test_constant_ripple_without_reversal_is_either(tmp_path: Path) -> None:
    truth = Truth(
        smooth_um=0.0, screw_um=0.0, reversal_um=0.0, expansion_um=0.0, ripple_um=0.0, noise_um=0.0
    )
    session = simulate(truth, seed=11, passes=4, rate_hz=5.0)
    q = session.columns["x"]
    rng = np.random.default_rng(7)
    looked_at = q.copy()  # no reversal, no latency: the carriage is where the axis says
    noise = rng.normal(0.0, NOISE_UM, len(q))
    session.columns["ref_x"] = q + (_ripple_um(looked_at) + noise) / 1000.0
    # the oracle: both twins' predicted readings, fitted with numpy at each coordinate
    err = (session.columns["ref_x"] - q) * 1000.0
    reading = session.columns["ref_x"]
    fits = {}
    for name, coord in (("position", q), ("reading", reading)):
        x = _columns(coord)
        beta, *_ = np.linalg.lstsq(x, err, rcond=None)
        fits[name] = (x @ beta, float(np.sum((err - x @ beta) ** 2)))
    # the noise-free predictions coincide (the reading differs from the position by the error
    # itself, ≤ 10 µm: a phase of 2π·0.01/0.37 at most, mostly noise's) …
    assert np.max(np.abs(fits["position"][0] - fits["reading"][0])) < 3.0 * NOISE_UM
    assert np.sqrt(np.mean((fits["position"][0] - _ripple_um(q)) ** 2)) < 0.2 * NOISE_UM
    # … and so do their residuals: at the position the fit leaves the noise (χ² ≈ n); at the
    # raw reading a little more (its noise moves the phase: here ~40 σ², which the diagnosis'
    # denoised reading removes), never thousands
    n = len(q)
    assert abs(fits["position"][1] / NOISE_UM**2 - n) < 5.0 * np.sqrt(2.0 * n)
    assert abs(fits["position"][1] - fits["reading"][1]) / NOISE_UM**2 < 200.0
    machine, csv = session.write(tmp_path)
    d = diagnose(Machine.from_toml(machine), read_measurements(csv))
    cyclic = [e for e in d.entries if e["cause"] in ("periodic", "reference_ripple")]
    assert len(cyclic) == 1, [(e["cause"], e.get("source")) for e in d.entries]
    e = cyclic[0]
    band = float(stats.chi2.ppf(0.999, 1))
    twin = next(t for t in e["evidence"]["twins"] if t["cause"] != e["cause"])
    assert abs(twin["delta_chi2"]) < 3.0 * band, twin  # was +16 632 with the twin's own shapes
    assert e["source"] == "either" and e["locked_to"] == "undetermined"
    assert abs(e["parameters"]["period_mm"] - PERIOD_MM) < 0.01 * PERIOD_MM
