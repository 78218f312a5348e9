"""The plan's data sets, read, and the identification problem built from them: which functions
to identify (:class:`.basis.Layout`), the model (:class:`.model.MachineModel`) and one
observation block per data set (:mod:`.obs_laser`, :mod:`.obs_artefacts`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .basis import Layout
from .laser import LaserData, read_laser
from .model import MachineModel
from .multilateration import MultilaterationData, read_multilateration
from .obs_artefacts import MultilaterationBlock, PlateBlock
from .obs_laser import LaserBlock
from .observation import Block
from .plan import Plan
from .plate import PlateData, read_plate
from .solver import Problem

__all__ = ["Dataset", "build_problem", "load_datasets", "reversal_axes"]


@dataclass(frozen=True)
class Dataset:
    """One data set of the plan: ``kind`` laser | plate | multilateration, its plan key
    (``laser[0]`` …) and its data."""

    kind: str
    where: str
    data: LaserData | PlateData | MultilaterationData

    @property
    def source(self) -> str:
        return self.data.source


def load_datasets(plan: Plan, *, need_values: bool = True) -> list[Dataset]:
    """Read every data file of the plan (in the plan's order: lasers, plates, multilateration)."""
    vol = plan.base.volume
    lo, hi = vol.lower_mm, vol.upper_mm
    out = [
        Dataset("laser", s.where, read_laser(s, lo, hi, vol.reference_mm, need_values=need_values))
        for s in plan.lasers
    ]
    out += [
        Dataset("plate", s.where, read_plate(s, lo, hi, need_values=need_values))
        for s in plan.plates
    ]
    out += [
        Dataset(
            "multilateration", s.where, read_multilateration(s, lo, hi, need_values=need_values)
        )
        for s in plan.multilaterations
    ]
    return out


def reversal_axes(plan: Plan, datasets: list[Dataset]) -> tuple[int, ...]:
    """Axes with a positional error to identify and data that reach it from both directions:
    bidirectional linear laser runs on the axis, or a multilateration program that moves it
    both ways (its points' last directions of travel)."""
    if not plan.fit.reversal:
        return ()
    axes = set()
    for ds in datasets:
        if isinstance(ds.data, LaserData):
            for run in ds.data.runs:
                if run.kind == "linear" and np.any(run.direction > 0) and np.any(run.direction < 0):
                    axes.add(run.axis)
        elif isinstance(ds.data, MultilaterationData) and ds.data.direction.size:
            d = ds.data.direction
            axes.update(k for k in range(3) if np.any(d[:, k] > 0) and np.any(d[:, k] < 0))
    wanted = {k for k, a in enumerate("xyz") if f"d{a}_{a}" in plan.fit.components}
    return tuple(sorted(axes & wanted))


def build_problem(
    plan: Plan,
    datasets: list[Dataset],
    *,
    smoothness: Any = "plan",
    reversal: tuple[int, ...] | None = None,
) -> Problem:
    """The least-squares problem of ``datasets`` with the plan's fit settings (``smoothness``
    overrides the plan's: None = estimate, a number = fixed τ; ``reversal`` the axes whose
    reversal is estimated, default :func:`reversal_axes`)."""
    vol = plan.base.volume
    layout = Layout(
        vol.lower_mm,
        vol.upper_mm,
        basis=plan.fit.basis,
        nodes=plan.fit.nodes,
        order=plan.fit.order,
        components=plan.fit.components,
        reversal_axes=reversal_axes(plan, datasets) if reversal is None else reversal,
    )
    model = MachineModel(layout, plan.base.chain, vol.reference_mm, plan.base)
    blocks: list[Block] = []
    for i, ds in enumerate(datasets):
        if isinstance(ds.data, LaserData):
            blocks.append(LaserBlock(ds.data, i, model))
        elif isinstance(ds.data, PlateData):
            blocks.append(PlateBlock(ds.data, i, model))
        else:
            blocks.append(MultilaterationBlock(ds.data, i, model))
    smooth = plan.fit.smoothness if smoothness == "plan" else smoothness
    return Problem(model, blocks, prior_sd=plan.fit.prior, smoothness=smooth)
