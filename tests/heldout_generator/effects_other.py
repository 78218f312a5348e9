"""Hidden effects without a logged driver (drift) and of the probe (probe_lobing)."""

from __future__ import annotations

import numpy as np

from .chain import AXES
from .design import Session
from .effect_base import Contribution, HiddenEffect, axis_index
from .identity import Identity
from .machine import RandomMachine


def draw_drift(rng: np.random.Generator, machine: RandomMachine, session: Session) -> HiddenEffect:
    """An axis' positional error drifts with time and nothing logged explains it.

    ``wander`` (its reading head creeps: a trend plus slow swings, periods ½–3× the session);
    ``warmup`` (an unlogged heat source settles: 1 − e^(−t/τ)); ``proportional`` (the scale warms
    locally from its drive: the drift grows with time and with the distance from the scale's fixed
    end).
    """
    axis = str(rng.choice(AXES))
    k = axis_index(axis)
    t = session.t_s
    duration = session.design.duration_h * 3600.0
    variant = str(rng.choice(["wander", "warmup", "proportional"]))
    params: dict[str, float] = {}
    if variant == "wander":
        curve = rng.uniform(-1, 1) * t / duration
        for _ in range(2):
            period = duration * rng.uniform(0.5, 3.0)
            curve = curve + rng.uniform(0.3, 1.0) * np.sin(
                2 * np.pi * t / period + rng.uniform(0, 2 * np.pi)
            )
        shape = curve
    else:
        tau = duration * rng.uniform(0.15, 0.5)
        params["tau_s"] = tau
        shape = 1.0 - np.exp(-t / tau)
        if variant == "proportional":
            end = int(rng.integers(2))
            s = machine.normalised(session.q_mm)[:, k]
            shape = shape * (s if end == 0 else 1 - s)
            params["fixed_end"] = end
    shape = shape / max(np.abs(shape).max(), 1e-12)
    n = session.n

    def forward(amplitude_um: float) -> Contribution:
        c = Contribution.zeros(n)
        c.errors[:, k, k] += amplitude_um * shape
        return c

    return HiddenEffect(
        identity=Identity("drift", axis=axis),
        variant=variant,
        params=params,
        forward=forward,
        knob_name="amplitude_um",
        knob_range=(0.02, 20.0),
    )


def draw_probe_lobing(
    rng: np.random.Generator, machine: RandomMachine, session: Session
) -> HiddenEffect:
    """A kinematic (three-seat) touch-trigger probe: the pre-travel varies with the azimuth φ of
    the probing direction about the probe body's axis (vertical), three lobes (``three``) or three
    with a sixth-order part (``three_six``); it fades towards vertical probing as ρ or ρ²
    (ρ = horizontal part of the normal) and grows with the stylus length. The qualification removes
    its mean, so the error along the normal is the pre-travel's variation: error = PT·n."""
    variant = str(rng.choice(["three", "three_six"]))
    power = int(rng.choice([1, 2]))
    nrm = session.normals
    phi = np.arctan2(nrm[:, 1], nrm[:, 0])
    rho = np.hypot(nrm[:, 0], nrm[:, 1])
    phase = rng.uniform(0, 2 * np.pi, 2)
    pattern = np.cos(3 * phi + phase[0])
    ratio = 0.0
    if variant == "three_six":
        ratio = rng.uniform(0.2, 0.5)
        pattern = pattern + ratio * np.cos(6 * phi + phase[1])
    length = np.linalg.norm(session.stylus_mm, axis=1)
    base = max(float(np.linalg.norm(machine.stylus_mm)), 1.0)
    pre_travel = pattern * rho**power * (length / base)
    n = session.n

    def forward(amplitude_um: float) -> Contribution:
        c = Contribution.zeros(n)
        c.direct_um += (amplitude_um * pre_travel)[:, None] * nrm
        return c

    return HiddenEffect(
        identity=Identity("probe_lobing"),
        variant=f"{variant}/rho^{power}",
        params={"sixth_ratio": ratio, "rho_power": power},
        forward=forward,
        knob_name="amplitude_um",
        knob_range=(0.02, 5.0),
    )
