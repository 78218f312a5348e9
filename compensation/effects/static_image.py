"""An effect driven by a signal, plus the static image it left in the tables when they were
calibrated (docs/formats.md §1.9 ``static_image``).

A machine calibrated on site, in a thermal state other than the reference (a vertical gradient
across the beam, an air temperature off 20 °C), has tables that already hold what a thermal effect
did at that moment. What the model then misses is the effect *minus* its value in that state: the
dynamic term, and a static table change of exactly the effect's own shape. The diagnosis fits the
two together as one cause (the static part alone is the signal frozen at its session mean, with
coefficients of its own), so a stale table that is the thermal cause's image is never named as a
second cause.

``StaticImageEffect(dynamic, static, frozen)`` evaluates ``dynamic`` as usual and ``static`` with
the signals named in ``frozen`` held at those values (°C). Its table is the dynamic effect's table
with ``static_image = {<static's parameters>, signals = {name = value}}``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .base import Effect, EvalContext, register_wrapper

__all__ = ["StaticImageEffect"]


class StaticImageEffect(Effect):
    """``dynamic`` plus ``static`` evaluated with the ``frozen`` signals held constant."""

    def __init__(self, dynamic: Effect, static: Effect, frozen: Mapping[str, float]) -> None:
        if type(static) is not type(dynamic):
            raise ValueError(
                f"static image must be the same kind of effect as the dynamic one, got "
                f"{type(static).__name__} for {type(dynamic).__name__}"
            )
        values = {str(k): float(v) for k, v in frozen.items()}
        if not values or not all(np.isfinite(v) for v in values.values()):
            raise ValueError(f"static_image signals must be finite numbers, got {dict(frozen)}")
        self.dynamic = dynamic
        self.static = static
        self.frozen = values
        self.cause = dynamic.cause  # type: ignore[misc]
        self.compensable = dynamic.compensable  # type: ignore[misc]

    def __getattr__(self, name: str) -> Any:
        # signal_filter, reference_C … of the dynamic effect (only for names not set here)
        if name in ("dynamic", "static", "frozen"):
            raise AttributeError(name)
        return getattr(self.dynamic, name)

    def signals(self) -> dict[str, float]:
        return self.dynamic.signals()

    def shortest_wavelength_mm(self) -> dict[str, float]:
        out = dict(self.dynamic.shortest_wavelength_mm())
        for k, v in self.static.shortest_wavelength_mm().items():
            out[k] = min(v, out.get(k, v))
        return out

    def transform_signals(self, ctx: EvalContext) -> None:
        self.dynamic.transform_signals(ctx)

    def _frozen(self, ctx: EvalContext, hook: Callable[[EvalContext], None]) -> None:
        saved = {k: ctx.signals.get(k) for k in self.frozen}
        try:
            for k, v in self.frozen.items():
                ctx.signals[k] = np.full(ctx.n, v)
            hook(ctx)
        finally:
            for k, old in saved.items():
                if old is None:
                    ctx.signals.pop(k, None)
                else:
                    ctx.signals[k] = old

    def modify_errors(self, ctx: EvalContext) -> None:
        self.dynamic.modify_errors(ctx)
        self._frozen(ctx, self.static.modify_errors)

    def add_direct(self, ctx: EvalContext) -> None:
        self.dynamic.add_direct(ctx)
        self._frozen(ctx, self.static.add_direct)

    def to_table(self) -> dict[str, Any]:
        static = {k: v for k, v in self.static.to_table().items() if k != "cause"}
        return {**self.dynamic.to_table(), "static_image": {**static, "signals": self.frozen}}

    def describe(self) -> dict[str, Any]:
        d = dict(self.dynamic.describe())
        params = dict(d.get("parameters", {}))
        params["static_image"] = {
            "parameters": self.static.describe().get("parameters", {}),
            "signals_C": dict(self.frozen),
            "meaning": "what the effect left in the tables at the thermal state of their "
            "calibration (the signals held at these values)",
        }
        d["parameters"] = params
        return d

    @classmethod
    def from_table(
        cls, table: Mapping[str, Any], build: Callable[[Mapping[str, Any]], Effect]
    ) -> StaticImageEffect:
        """From a table with a ``static_image`` sub-table; ``build`` makes a plain effect."""
        image = table.get("static_image")
        if not isinstance(image, Mapping):
            raise ValueError(f"static_image must be a table, got {image!r}")
        signals = image.get("signals")
        if not isinstance(signals, Mapping) or not signals:
            raise ValueError("static_image needs signals = {name = value, …} (°C)")
        try:
            frozen = {str(k): float(v) for k, v in signals.items()}
        except (TypeError, ValueError):
            raise ValueError(f"static_image signals must be numbers, got {dict(signals)}") from None
        dynamic = build({k: v for k, v in table.items() if k != "static_image"})
        # what the term acts on comes from the effect (a static image written by hand may give
        # only its coefficients); everything else is the image's own, defaults included
        static_table = {k: table[k] for k in _INHERITED if k in table}
        static_table.update({k: v for k, v in image.items() if k != "signals"})
        static_table["cause"] = table.get("cause")
        return cls(dynamic, build(static_table), frozen)


#: Keys a static image takes from its effect's table unless it gives them itself.
_INHERITED = (
    "axis",
    "component",
    "varies_with",
    "temperature",
    "reference_C",
    "span_mm",
    "fixture_mm",
    "fixed_at_mm",
    "time_constant_s",
)


register_wrapper("static_image", StaticImageEffect.from_table)
