"""The runtime signals a correction grid reads: their description in the grid
(:class:`GridSignal`), their deviations from the reference for a batch of points, and the
signals the grid derives itself (probe lobing from the probing direction).

Temperatures are °C (roles of :mod:`cmm_comp.compensation.thermal`), directions ``dir_<axis>``
±1, probing directions ``nx``, ``ny``, ``nz`` unit-vector components.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..thermal.roles import is_temperature

__all__ = ["GridSignal", "derive_lobing_inputs", "lobing_orders", "signal_deviations", "subset"]

FloatArray = NDArray[np.float64]
_LOBE_SIGNAL = re.compile(r"lobe(\d+)(?:r(\d+))?_[cs]_[xyz]")
_PROBE_DIRECTION = ("nx", "ny", "nz")


@dataclass(frozen=True)
class GridSignal:
    """A runtime signal: its name, reference value, and whether the grid depends on it."""

    name: str
    reference: float
    needed: bool

    @property
    def is_temperature(self) -> bool:
        return is_temperature(self.name)


def _lookup(name: str, *maps: Mapping[str, Any] | None) -> Any:
    for m in maps:
        if m is not None and name in m and m[name] is not None:
            return m[name]
    return None


def signal_deviations(
    signals: Sequence[GridSignal],
    n: int,
    temps_C: Mapping[str, Any] | None,
    inputs: Mapping[str, Any] | None,
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """Deviations from the reference (n, S) of the needed signals (0 where missing) and masks
    (n,) of the points missing a needed temperature / a needed other input (None or not finite).

    A temperature is looked up in ``temps_C`` first, any other signal in ``inputs`` first;
    values are scalars or (n,) arrays."""
    dev = np.zeros((n, len(signals)))
    no_temp = np.zeros(n, dtype=bool)
    no_input = np.zeros(n, dtype=bool)
    for s, sig in enumerate(signals):
        if not sig.needed:
            continue
        first, second = (temps_C, inputs) if sig.is_temperature else (inputs, temps_C)
        value = _lookup(sig.name, first, second)
        missing = no_temp if sig.is_temperature else no_input
        if value is None:
            missing[:] = True
            continue
        arr = np.asarray(value, dtype=np.float64)
        if arr.ndim == 0:
            arr = np.full(n, float(arr))
        if arr.shape != (n,):
            raise ValueError(
                f"signal {sig.name!r} must be a scalar or have shape ({n},), got {arr.shape}"
            )
        bad = ~np.isfinite(arr)
        missing |= bad
        dev[:, s] = np.where(bad, 0.0, arr - sig.reference)
    return dev, no_temp, no_input


def lobing_orders(signals: Sequence[GridSignal]) -> list[tuple[int, int]]:
    """(lobes, radial power) of the needed probe-lobing signals ``lobe<n>[r<p>]_{c,s}_<axis>``
    (sorted)."""
    return sorted(
        {
            (int(m.group(1)), int(m.group(2) or m.group(1)))
            for sig in signals
            if sig.needed and (m := _LOBE_SIGNAL.fullmatch(sig.name))
        }
    )


def derive_lobing_inputs(
    orders: Sequence[tuple[int, int]], inputs: Mapping[str, Any] | None
) -> Mapping[str, Any] | None:
    """``inputs`` with the probe-lobing signals of ``orders`` (lobes, radial power) derived from
    ``nx, ny, nz`` (:func:`cmm_comp.compensation.effects.lobing_signals`); anything given
    explicitly wins; without a probing direction ``inputs`` is returned as is."""
    if not orders or inputs is None:
        return inputs
    if not all(k in inputs and inputs[k] is not None for k in _PROBE_DIRECTION):
        return inputs
    from ..effects.probe import lobing_signals

    out = dict(inputs)
    for lobes, power in orders:
        derived = lobing_signals(inputs["nx"], inputs["ny"], inputs["nz"], lobes, power)
        for name, value in derived.items():
            out.setdefault(name, value)
    return out


def subset(
    mapping: Mapping[str, Any] | None, idx: NDArray[np.intp], n: int
) -> dict[str, Any] | None:
    """The signals of the points ``idx`` of ``n``: (n,) arrays indexed, scalars kept."""
    if mapping is None:
        return None
    out: dict[str, Any] = {}
    for k, v in mapping.items():
        if v is None:
            out[k] = None
            continue
        arr = np.asarray(v, dtype=np.float64)
        out[k] = arr[idx] if arr.ndim == 1 and arr.shape[0] == n else arr
    return out
