"""A simulated fleet: N machines measured on a series of dates, some changing slowly.

Each machine of the fleet is the user's description (``model``, one ``machine.toml`` per machine,
renamed) and a *truth*: the description plus the hidden effects of the slow changes that concern
it, evaluated on each date. A :class:`SlowChange` is one ``[[effects]]`` table
(docs/formats.md §1.9) present from its ``start`` date on, whose amplitude keys grow by
``per_day`` every day after it (a squareness creeping by 0.1 µrad a day) or stay put (a reversal
appearing on one date, after a crash). Every session is planned and measured afresh
(:func:`~.sessions.plan_session`, :func:`~.sessions.measure_session`) with a generator seeded by
(fleet seed, machine, date), so a fleet is reproducible and each session independent.

:func:`write_fleet` lays the fleet out as ``ROOT/<machine>/<YYYY-MM-DD>/machine.toml`` +
``measurements.csv`` (the layout ``cmm-comp fleet diagnose`` reads) and writes what was injected
to ``ROOT/fleet-truth.json`` (:meth:`FleetSpec.truth`), which nothing but a test or a person
reads. Units: mm, µm, µrad, °C, days.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import date, timedelta
from pathlib import Path
from typing import Any

import numpy as np

from cmm_comp.compensation.effects import Effect, effect_from_table
from cmm_comp.compensation.formats.atomic import write_text_atomic
from cmm_comp.compensation.formats.measurements import write_measurements
from cmm_comp.compensation.machine import Machine

from .sessions import measure_session, plan_session

__all__ = [
    "TRUTH_FILE",
    "FleetSpec",
    "SlowChange",
    "default_fleet",
    "write_fleet",
]

TRUTH_FILE = "fleet-truth.json"
"""Name of the file under ROOT that records what :func:`write_fleet` injected."""


@dataclass(frozen=True)
class SlowChange:
    """One hidden effect of one machine: ``effect`` (an ``[[effects]]`` table) from ``start`` on,
    each amplitude key in ``per_day`` growing by that much per day after ``start`` (a list key:
    element by element). ``per_day`` empty: the effect is constant once present."""

    machine: str
    effect: Mapping[str, Any]
    start: date
    per_day: Mapping[str, Any] = field(default_factory=dict)

    def table_on(self, day: date) -> dict[str, Any] | None:
        """The effect's table on ``day`` (None before ``start``)."""
        if day < self.start:
            return None
        days = (day - self.start).days
        table = json.loads(json.dumps(dict(self.effect)))
        for key, rate in self.per_day.items():
            value = table[key]
            if isinstance(value, list):
                table[key] = [v + r * days for v, r in zip(value, rate, strict=True)]
            else:
                table[key] = value + rate * days
        return table

    def effect_on(self, day: date) -> Effect | None:
        """The effect on ``day`` as a model effect (None before ``start``)."""
        table = self.table_on(day)
        return None if table is None else effect_from_table(table)

    @property
    def keys(self) -> dict[str, Any]:
        """What names the effect besides its cause (``component``, ``axis`` …: the string-valued
        keys of its table, as the diagnosis names them)."""
        return {k: v for k, v in self.effect.items() if k != "cause" and isinstance(v, str)}

    @property
    def kind(self) -> str:
        """``creep`` (grows day by day) or ``appears`` (constant from ``start`` on)."""
        return "creep" if self.per_day else "appears"

    def as_dict(self) -> dict[str, Any]:
        return {
            "machine": self.machine,
            "cause": self.effect["cause"],
            "keys": self.keys,
            "kind": self.kind,
            "start": self.start.isoformat(),
            "per_day": dict(self.per_day),
            "effect": dict(self.effect),
        }


@dataclass(frozen=True)
class FleetSpec:
    """Machines × dates, the description every machine starts from, and the hidden effects.

    ``model`` is the description each machine's ``machine.toml`` holds (renamed per machine);
    ``n_points`` and ``hours`` size each session (:func:`plan_session`); ``noise_um`` is the
    reference/probing noise (1σ per axis, µm)."""

    model: Machine
    machines: tuple[str, ...]
    dates: tuple[date, ...]
    changes: tuple[SlowChange, ...] = ()
    n_points: int = 400
    hours: float = 4.0
    noise_um: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        unknown = sorted({c.machine for c in self.changes} - set(self.machines))
        if unknown:
            raise ValueError(f"slow changes name machines not in the fleet: {', '.join(unknown)}")
        if len(set(self.dates)) != len(self.dates):
            raise ValueError("the fleet's dates must be distinct")

    def description(self, machine: str) -> Machine:
        """What ``machine``'s ``machine.toml`` says (the model, named ``machine``)."""
        data = json.loads(json.dumps(self.model.description))
        data["name"] = machine
        return Machine.from_dict(data, source=f"<fleet {machine}>")

    def hidden_on(self, machine: str, day: date) -> list[Effect]:
        """The hidden effects of ``machine`` on ``day``."""
        out = []
        for change in self.changes:
            if change.machine == machine and (eff := change.effect_on(day)) is not None:
                out.append(eff)
        return out

    def truth_on(self, machine: str, day: date) -> Machine:
        """The true ``machine`` on ``day``: its description plus the hidden effects."""
        described = self.description(machine)
        hidden = self.hidden_on(machine, day)
        return described.with_effects(hidden) if hidden else described

    def rng(self, machine: str, day: date, stream: int = 0) -> np.random.Generator:
        """The generator of one session (independent of every other session's)."""
        k = self.machines.index(machine)
        return np.random.default_rng([self.seed, k, day.toordinal(), stream])

    def truth(self) -> dict[str, Any]:
        """What was injected (the content of ``fleet-truth.json``)."""
        return {
            "machines": list(self.machines),
            "dates": [d.isoformat() for d in self.dates],
            "changes": [c.as_dict() for c in self.changes],
            "n_points": self.n_points,
            "noise_um": self.noise_um,
            "seed": self.seed,
        }


def default_fleet(
    model: Machine,
    n_machines: int = 4,
    n_dates: int = 12,
    *,
    start: date = date(2026, 1, 5),
    every_days: int = 7,
    n_points: int = 400,
    seed: int = 0,
) -> FleetSpec:
    """``n_machines`` machines (``cmm-01`` …) measured every ``every_days`` days, with:

    * ``cmm-02``: squareness ``alpha`` creeping from 0 to 6 µrad over the whole series;
    * the last machine: an X reversal (half step 1.2 µm, a 2.4 µm reversal) appearing on the
      middle date, as after a crash;
    * ``cmm-03`` (with ≥ 4 machines): a cyclic Y error (period 60 mm, 1.5 µm) the description
      lacks, constant over the series (present, but nothing changes);

    every other machine as described. Needs ≥ 3 machines and ≥ 4 dates.
    """
    if n_machines < 3 or n_dates < 4:
        raise ValueError(
            f"a default fleet needs ≥ 3 machines and ≥ 4 dates, got {n_machines}, {n_dates}"
        )
    machines = tuple(f"cmm-{i + 1:02d}" for i in range(n_machines))
    dates = tuple(start + timedelta(days=every_days * i) for i in range(n_dates))
    span_days = max((dates[-1] - dates[0]).days, 1)
    x_span = [float(model.volume.lower_mm[0]), float(model.volume.upper_mm[0])]
    changes = [
        SlowChange(
            machines[1],
            {
                "cause": "parametric",
                "component": "alpha",
                "orders": [0],
                "coefficients": [0.0],
                "span_mm": [0.0, 1.0],
            },
            dates[0],
            {"coefficients": [6.0 / span_days]},
        ),
        SlowChange(
            machines[-1],
            {"cause": "reversal", "axis": "x", "half_step_um": [1.2, 0.0], "span_mm": x_span},
            dates[n_dates // 2],
        ),
    ]
    if n_machines >= 4:
        changes.append(
            SlowChange(
                machines[2],
                {
                    "cause": "periodic",
                    "axis": "y",
                    "period_mm": 60.0,
                    "a_cos_um": 1.2,
                    "b_sin_um": 0.9,
                },
                dates[0],
            )
        )
    return FleetSpec(model, machines, dates, tuple(changes), n_points=n_points, seed=seed)


def session_dir(root: str | Path, machine: str, day: date) -> Path:
    """``ROOT/<machine>/<YYYY-MM-DD>``."""
    return Path(root) / machine / day.isoformat()


def write_fleet(
    root: str | Path,
    spec: FleetSpec,
    progress: Callable[[int, int], None] | None = None,
    only: Sequence[tuple[str, date]] | None = None,
) -> list[Path]:
    """Write every session of ``spec`` under ``root`` (module docstring) and ``fleet-truth.json``;
    returns the session directories. ``only`` restricts to some (machine, date) pairs."""
    root = Path(root)
    pairs = list(only) if only is not None else [(m, d) for m in spec.machines for d in spec.dates]
    out: list[Path] = []
    described: dict[str, Machine] = {}
    for i, (machine, day) in enumerate(pairs):
        if machine not in described:
            described[machine] = spec.description(machine)
        rng = spec.rng(machine, day)
        plan = plan_session(described[machine], rng, n_points=spec.n_points, hours=spec.hours)
        data = measure_session(spec.truth_on(machine, day), plan, spec.noise_um, rng)
        folder = session_dir(root, machine, day)
        folder.mkdir(parents=True, exist_ok=True)
        described[machine].to_toml(folder / "machine.toml")
        write_measurements(folder / "measurements.csv", data)
        out.append(folder)
        if progress is not None:
            progress(i + 1, len(pairs))
    write_text_atomic(root / TRUTH_FILE, json.dumps(spec.truth(), indent=2) + "\n")
    return out


def truth_changes(root: str | Path) -> list[dict[str, Any]]:
    """The slow changes recorded in ``ROOT/fleet-truth.json`` (as :meth:`SlowChange.as_dict`)."""
    data = json.loads((Path(root) / TRUTH_FILE).read_text(encoding="utf-8"))
    return list(data["changes"])


def change_from_dict(data: Mapping[str, Any]) -> SlowChange:
    """Inverse of :meth:`SlowChange.as_dict`."""
    return SlowChange(
        str(data["machine"]),
        dict(data["effect"]),
        date.fromisoformat(str(data["start"])),
        dict(data.get("per_day", {})),
    )
