"""``cmm-comp uncertainty`` for a measurement task (``--length``, ``--e0-test``, ``--sphere``,
``--plane``; docs/uncertainty.md): run the virtual CMM, write the JSON summary and the
histograms, print the outputs' U. The points and volume modes and the flags are in
:mod:`.uncertainty`.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from .common import write_json_atomic
from .uncertainty import _end_progress, _finite, _progress, _settings, _stability, _warn_if_unstable

if TYPE_CHECKING:
    from cmm_comp.compensation import Machine

__all__ = ["task_mode"]


def _run_task(
    args: argparse.Namespace,
    machine: Machine,
    temps: dict[str, float] | None,
    stylus: list[float] | None,
    mode: str,
    kw: dict[str, Any],
) -> tuple[Any, float | None]:
    """Run the measurement task ``mode`` names: ``(result, E0/MPE pass limit or None)``."""
    import numpy as np

    from cmm_comp.compensation import uncertainty as unc

    if mode == "--length":
        c = _finite(list(args.length), "--length")
        return unc.length_uncertainty(machine, c[:3], c[3:], stylus, temps, **kw), None
    if mode == "--e0-test":
        from cmm_comp.sim_controller.iso10360 import length_test

        tests = length_test(machine.volume.lower_mm, machine.volume.upper_mm)
        pairs = np.array([[t.a_mm, t.b_mm] for t in tests])
        mpe = None if args.mpe is None else (float(args.mpe[0]), float(args.mpe[1]))
        result = unc.e0_uncertainty(machine, pairs, stylus, temps, mpe=mpe, **kw)
        return result, (None if mpe is None else 1.0)
    if mode == "--sphere":
        x, y, z, r = _finite(list(args.sphere), "--sphere")
        pts = unc.sphere_probing_points([x, y, z], r, args.sphere_points)
        return unc.sphere_uncertainty(machine, pts, stylus, temps, **kw), None
    v = _finite(list(args.plane), "--plane")
    pts = unc.plane_grid_points(v[0:3], v[3:6], v[6:9], args.plane_points, args.plane_points)
    return unc.flatness_uncertainty(machine, pts, stylus, temps, **kw), None


def _plot_task(
    args: argparse.Namespace, machine: Machine, result: Any, mpe_ratio_limit: float | None
) -> None:
    """The ``--plot`` histograms of a task's outputs (the per-length E0 errors left out)."""
    from cmm_comp.compensation.uncertainty.plots import plot_histogram

    mc = result.mc
    gum_u = result.gum["u"] if result.gum is not None else [None] * len(result.outputs)
    shown = [i for i, name in enumerate(result.outputs) if not name.startswith("length_error_um[")]
    columns = {i: mc.column(i) for i in shown}
    if any(c is None for c in columns.values()):  # not reachable with the tasks' defaults
        raise ValueError(
            f"uncertainty: the {mc.trials} trials' values were not kept "
            "(more than keep_values_limit): no histogram; fewer --max-trials or --trials"
        )
    panels = [
        (
            result.outputs[i],
            columns[i],
            (float(mc.low[i]), float(mc.high[i])),
            gum_u[i],
            mpe_ratio_limit if result.outputs[i] == "E0_over_MPE" else None,
        )
        for i in shown
    ]
    title = f"{machine.name}: {_TASK_TITLES.get(result.task, result.task)}, {mc.trials} virtual machines"
    if "p_pass" in result.nominal:
        title += f", probability of passing {_p_pass_text(result.nominal)}"
    if not mc.stable and args.trials is None:
        title += " (NOT stable: --max-trials reached)"
    plot_histogram(
        panels,
        args.plot,
        title=title,
        limit_label="pass limit E0/MPE =",
        probability=mc.probability,
    )


def task_mode(
    args: argparse.Namespace,
    machine: Machine,
    rng: Any,
    temps: dict[str, float] | None,
    stylus: list[float] | None,
    mode: str,
) -> int:
    from cmm_comp.compensation import uncertainty as unc

    settings = _settings(args, default_ndig=unc.E0_NDIG if mode == "--e0-test" else 2)
    kw: dict[str, Any] = {"rng": rng, "settings": settings, "progress": _progress("uncertainty")}
    result, mpe_ratio_limit = _run_task(args, machine, temps, stylus, mode, kw)
    _end_progress()
    summary = result.summary()
    summary["machine"] = machine.name
    summary["seed"] = args.seed
    summary["temperatures_C"] = temps or {}
    if result.task == "e0":  # keep the JSON readable: the per-length outputs in one table
        outputs = summary["outputs"]
        lengths = result.nominal["lengths_mm"]
        summary["length_errors"] = [
            {"length_mm": lengths[i], **outputs.pop(f"length_error_um[{i}]")}
            for i in range(len(lengths))
        ]
    if args.json is not None:
        write_json_atomic(args.json, summary)
    mc = result.mc
    if args.plot is not None:
        _plot_task(args, machine, result, mpe_ratio_limit)
    for i, name in enumerate(result.outputs):
        if name.startswith("length_error_um["):
            continue
        print(
            f"{name}: mean {mc.mean[i]:.4g}, u {mc.u[i]:.3g}, U (k = 2) {2 * mc.u[i]:.3g}, "
            f"95 % interval [{mc.low[i]:.4g}, {mc.high[i]:.4g}]"
        )
    if "p_pass" in result.nominal:
        print(f"probability of passing the E0 test: {_p_pass_text(result.nominal)}")
    print(f"{mc.trials} trials{_stability(mc, args)}")
    _warn_if_unstable(mc, args)
    return 0


_TASK_TITLES = {
    "length": "length",
    "e0": "ISO 10360-2 E0 test",
    "sphere": "sphere",
    "flatness": "flatness",
}


def _p_pass_text(nominal: dict[str, Any]) -> str:
    two_s = nominal.get("p_pass_2s")
    spread = "" if two_s is None else f" ± {two_s:.3f} (2s between the runs)"
    return f"{nominal['p_pass']:.3f}{spread}"
