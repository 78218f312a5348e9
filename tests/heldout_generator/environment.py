"""The thermal environment of a verification session: what the room and the machine do.

Everything is simulated on a fine time grid that starts long before the session (``history_s``),
so that every lagging body (scales, the structure above and below the main guideway, the granite
base, a workpiece brought in from another room) enters the session with its own past and not in
a convenient steady state.

* Air: a mean offset from 20 °C, a slow linear drift, the day's swing, the air-conditioning's
  on/off cycle (15–40 min) and a smooth random wander.
* Scales follow the air through their own lags (20–120 min) plus a local offset (drive heat).
* ``T_top`` (structure above the main guideway) follows the air quickly and warms further when
  the lights come on; ``T_bottom`` (granite base, below) follows the air slowly: their difference
  is the gradient that bends beams.
* The workpiece arrives from another room shortly before the session and soaks to the air.

The true temperatures drive the physics; the logged ones carry sensor noise (σ ≈ 3 mK) and are
written rounded to 1 mK. Temperatures in °C, times in s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter, lfiltic

FloatArray = NDArray[np.float64]

LOGGED = ("T_x", "T_y", "T_z", "T_air", "T_top", "T_bottom", "T_wp")
GRID_STEP_S = 30.0


def lag(
    time_s: FloatArray, signal: FloatArray, tau_s: float, start: float | None = None
) -> FloatArray:
    """First-order lag ``τ·dy/dt = u − y`` of a piecewise-linear input, solved exactly per step.

    ``start`` is the body's temperature at ``time_s[0]`` (default: the input's, a steady state).
    On a uniform grid the exact step is a linear recurrence, run by ``scipy.signal.lfilter``:
    ``y_k = a·y_(k−1) + (1 − c)·u_k + (c − a)·u_(k−1)``, a = e^(−dt/τ), c = τ(1 − a)/dt.
    """
    if not (np.isfinite(tau_s) and tau_s > 0):
        raise ValueError(f"lag time constant must be finite and > 0 s, got {tau_s!r}")
    y0 = float(signal[0] if start is None else start)
    if len(signal) < 2:
        return np.full_like(signal, y0)
    steps = np.diff(time_s)
    dt = float(steps[0])
    if not np.allclose(steps, dt, rtol=1e-9, atol=0.0):
        raise ValueError("lag needs a uniform time grid")
    a = float(np.exp(-dt / tau_s))
    c = tau_s * (1.0 - a) / dt
    b = [1.0 - c, c - a]
    den = [1.0, -a]
    zi = lfiltic(b, den, y=[y0], x=[float(signal[0])])
    out, _ = lfilter(b, den, signal[1:], zi=zi)
    return np.concatenate([[y0], out])


def _smooth_noise(
    rng: np.random.Generator, time_s: FloatArray, sigma: float, tau_s: float
) -> FloatArray:
    """A stationary smooth random wander (white noise through two lags), RMS ≈ ``sigma``."""
    white = rng.normal(0.0, 1.0, time_s.shape)
    once = lag(time_s, white, tau_s)
    twice = lag(time_s, once, tau_s)
    twice -= twice.mean()
    std = twice.std()
    return twice * (sigma / std) if std > 0 else twice


@dataclass
class Environment:
    """Temperatures on a fine grid, from ``-history_s`` to past the session's end."""

    time_s: FloatArray
    true_C: dict[str, FloatArray]
    params: dict[str, float] = field(default_factory=dict)

    def at(self, name: str, t_s: FloatArray) -> FloatArray:
        """True temperature ``name`` at times ``t_s`` (linear interpolation on the grid)."""
        return np.interp(t_s, self.time_s, self.true_C[name])

    def lagged(self, name: str, tau_s: float, t_s: FloatArray) -> FloatArray:
        """A body following the true ``name`` with lag ``tau_s``, from the start of the history."""
        return np.interp(t_s, self.time_s, lag(self.time_s, self.true_C[name], tau_s))


def make_environment(
    rng: np.random.Generator,
    duration_s: float,
    *,
    activity: float = 1.0,
    history_s: float = 24 * 3600.0,
) -> Environment:
    """Draw a room and a machine's temperatures; ``activity`` scales every variation."""
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"session duration must be finite and > 0 s, got {duration_s!r}")
    if not (np.isfinite(activity) and 0 < activity <= 10):
        raise ValueError(f"thermal activity must be in (0, 10], got {activity!r}")
    t = np.arange(-history_s, duration_s + 2 * GRID_STEP_S, GRID_STEP_S)
    p: dict[str, float] = {
        "air_offset_C": rng.uniform(-0.6, 1.0),
        "air_rate_C_per_h": rng.uniform(-0.15, 0.15) * activity,
        "day_amplitude_C": rng.uniform(0.3, 1.0) * activity,
        "day_phase_rad": rng.uniform(0, 2 * np.pi),
        "hvac_amplitude_C": rng.uniform(0.03, 0.15) * activity,
        "hvac_period_s": rng.uniform(900.0, 2400.0),
        "hvac_phase_rad": rng.uniform(0, 2 * np.pi),
        "wander_C": rng.uniform(0.05, 0.15) * activity,
        "lights_on_s": rng.uniform(-6 * 3600.0, 0.5 * duration_s),
        "lights_C": rng.uniform(0.15, 0.6) * activity,
        "tau_top_s": rng.uniform(900.0, 2700.0),
        "tau_bottom_s": rng.uniform(2 * 3600.0, 6 * 3600.0),
        "wp_arrival_s": rng.uniform(-2.5 * 3600.0, -0.1 * 3600.0),
        "wp_room_C": 20.0 + rng.uniform(-1.5, 2.5) * min(activity, 2.0),
        "tau_wp_s": rng.uniform(1800.0, 5400.0),
    }
    air = (
        20.0
        + p["air_offset_C"]
        + p["air_rate_C_per_h"] * t / 3600.0
        + p["day_amplitude_C"] * np.sin(2 * np.pi * t / 86400.0 + p["day_phase_rad"])
        + p["hvac_amplitude_C"] * np.sin(2 * np.pi * t / p["hvac_period_s"] + p["hvac_phase_rad"])
        + _smooth_noise(rng, t, p["wander_C"], 1200.0)
    )
    true: dict[str, FloatArray] = {"T_air": air}
    for axis in "xyz":
        tau = rng.uniform(1200.0, 7200.0)
        offset = rng.uniform(-0.1, 0.35)  # drives and electronics warm the scales a little
        p[f"tau_scale_{axis}_s"] = tau
        p[f"scale_offset_{axis}_C"] = offset
        true[f"T_{axis}"] = lag(t, air, tau) + offset
    lights = np.where(t >= p["lights_on_s"], p["lights_C"], 0.0)
    true["T_top"] = lag(t, air + lights, p["tau_top_s"])
    true["T_bottom"] = lag(t, air, p["tau_bottom_s"])
    wp = np.full_like(t, p["wp_room_C"])
    arrived = t >= p["wp_arrival_s"]
    wp[arrived] = lag(t[arrived], air[arrived], p["tau_wp_s"], start=p["wp_room_C"])
    true["T_wp"] = wp
    return Environment(time_s=t, true_C=true, params=p)


def logged_temperatures(
    rng: np.random.Generator, env: Environment, t_s: FloatArray, sensor_sigma_C: float = 0.003
) -> dict[str, FloatArray]:
    """What the session's sensors log at ``t_s``: truth + sensor noise, rounded to 1 mK."""
    return {
        name: np.round(env.at(name, t_s) + rng.normal(0.0, sensor_sigma_C, t_s.shape), 3)
        for name in LOGGED
    }
