"""``cmm-comp calibrate``: from calibration measurements to the machine description
(docs/calibration.md, formats in docs/formats.md §10).

Three forms, one subcommand::

    cmm-comp calibrate PLAN.toml -o MACHINE.toml [--report DIR]
    cmm-comp calibrate plan PLAN.toml [PLAN2.toml …] --machine GUESS.toml [--json OUT] [--trials N]
    cmm-comp calibrate apply MACHINE.toml RUN.dat --axis x [--line X Y Z] [--cycles 3 4 5] -o OUT.dat

Bad input is one error line naming the file, line and field, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import Subparsers, load_machine, write_json_atomic

__all__ = ["add_parsers", "cmd_calibrate"]

USAGE = """\
cmm-comp calibrate PLAN.toml -o MACHINE.toml [--report DIR [--no-figures]] [--quiet]
       cmm-comp calibrate plan PLAN.toml [PLAN.toml ...] --machine GUESS.toml [--json OUT] [--trials N] [--seed S]
       cmm-comp calibrate apply MACHINE.toml RUN.dat --axis {x,y,z} [--line X Y Z] [--optic X Y Z] [--cycles C ...] [--uncorrected] -o OUT.dat"""


def _say(args: argparse.Namespace) -> Any:
    def say(line: str) -> None:
        if not args.quiet:
            print(f"cmm-comp calibrate: {line}", file=sys.stderr, flush=True)

    return say


def _reach_text(reach: dict[str, Any]) -> str:
    """``x 97 %, y 95 %, z —``: per axis the % of the travel a data set's positions span."""
    return ", ".join(
        f"{axis} {span['percent_of_travel']:.0f} %" if span else f"{axis} —"
        for axis, span in reach.items()
    )


def _calibrate(args: argparse.Namespace, words: list[str]) -> int:
    from cmm_comp.compensation.calibration.calibrate import calibrate
    from cmm_comp.compensation.calibration.plan import read_plan
    from cmm_comp.compensation.calibration.report import write_outputs

    if len(words) != 1:
        raise ValueError(f"calibrate takes one plan, got {len(words)}: {' '.join(words)}")
    if args.output is None:
        raise ValueError("calibrate PLAN.toml needs -o MACHINE.toml (the identified machine)")
    if args.no_figures and args.report is None:
        raise ValueError("--no-figures leaves the figures out of a report: give --report DIR")
    plan = read_plan(words[0])
    result = calibrate(plan, progress=_say(args))
    written = write_outputs(result, args.output, args.report, figures=not args.no_figures)
    for w in result.warnings:
        print(f"cmm-comp: warning: {w}", file=sys.stderr)
    vol = result.volumetric.summary()
    print(
        f"{plan.name} ({plan.model}): {sum(b.n_rows for b in result.problem.blocks)} readings, "
        f"{len(result.bands)} functions identified; U (k = 2) of the volumetric error at the "
        f"calibration stylus: max {max(vol['max_um']):.3g} µm, RMS "
        f"{max(vol['rms_um']):.3g} µm; null directions "
        f"{result.gauge['all_data']['null_dimension']}; {result.elapsed_s:.1f} s"
    )
    for d in result.datasets_summary:
        print(
            f"  {d['where']:<20} {Path(d['file']).name:<24} RMS {d['rms_before_um']:.4g} → "
            f"{d['rms_after_um']:.4g} {d['unit']}; reach {_reach_text(d['reach'])} of the travel"
        )
    print("wrote " + ", ".join(str(p) for p in written))
    return 0


def _plan(args: argparse.Namespace, words: list[str]) -> int:
    from cmm_comp.compensation.calibration.gaps import reach_warning
    from cmm_comp.compensation.calibration.plan import read_plan
    from cmm_comp.compensation.calibration.planner import predict_plan

    if not words:
        raise ValueError("calibrate plan needs at least one PLAN.toml")
    if args.machine is None:
        raise ValueError("calibrate plan needs --machine GUESS.toml (the machine you expect)")
    if args.trials < 0:
        raise ValueError(f"--trials {args.trials}: must be ≥ 0")
    guess = load_machine(args.machine)
    plans = [read_plan(w) for w in words]
    results = [
        predict_plan(p, guess, trials=args.trials, seed=args.seed, progress=_say(args))
        for p in plans
    ]
    width = max(28, *(len(w) for w in words))
    header = f"{'plan':<{width}} {'readings':>8} {'U max µm':>9} {'U rms µm':>9} {'null':>5}"
    if args.trials:
        header += f" {'MC spread/u':>11} {'coverage':>8}"
    print(header)
    for word, r in zip(words, results, strict=True):
        v = r["volumetric_U_um"]
        line = (
            f"{word:<{width}} {r['readings']:>8} {max(v['max_um']):>9.3g} "
            f"{max(v['rms_um']):>9.3g} {r['null_dimension']:>5}"
        )
        if args.trials:
            mc = r["monte_carlo"]
            line += f" {mc['spread_over_predicted_u']['overall']:>11.2f} {mc['coverage_of_predicted_U']:>8.3f}"
        print(line)
    for word, r in zip(words, results, strict=True):
        axes = r["reach"]["per_axis"]
        print(
            f"  {word}: the data reach "
            + ", ".join(f"{a} {v['percent_of_travel']:.0f} %" for a, v in axes.items())
            + " of the travel"
        )
        warning = reach_warning(r["reach"]["unreached"])
        if warning:
            print(f"cmm-comp: warning: {word}: {warning}", file=sys.stderr)
    if args.json:
        write_json_atomic(args.json, results if len(results) > 1 else results[0])
        print(f"wrote {args.json}")
    return 0


def _apply(args: argparse.Namespace, words: list[str]) -> int:
    from cmm_comp.compensation.calibration.iso230_apply import corrected_iso230, write_iso230_dat

    if len(words) != 2:
        raise ValueError("calibrate apply takes MACHINE.toml RUN.dat")
    if args.axis is None or args.output is None:
        raise ValueError("calibrate apply needs --axis {x,y,z} and -o OUT.dat")
    machine = load_machine(words[0])
    run = corrected_iso230(
        machine,
        Path(words[1]),
        args.axis,
        line_mm=args.line,
        optic_mm=args.optic,
        cycles=tuple(args.cycles) if args.cycles else None,
        correct=not args.uncorrected,
    )
    cycles = "all cycles" if not args.cycles else f"cycles {' '.join(map(str, args.cycles))}"
    what = "uncorrected (for comparison)" if args.uncorrected else f"corrected by {words[0]}"
    write_iso230_dat(run, args.output, f"{words[1]} ({cycles}) {what}")
    print(
        f"wrote {args.output}: {run.fwd_mm.shape[0]} targets × {run.fwd_mm.shape[1]} cycles; "
        f"evaluate with: cmm-comp iso230 {args.output}"
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Dispatch on the first word: ``plan``, ``apply`` or a plan file."""
    words = list(args.words)
    if words and words[0] == "plan" and not Path("plan").is_file():
        return _plan(args, words[1:])
    if words and words[0] == "apply" and not Path("apply").is_file():
        return _apply(args, words[1:])
    return _calibrate(args, words)


def add_parsers(sub: Subparsers) -> None:
    """Register ``calibrate`` (with its ``plan`` and ``apply`` forms)."""
    p = sub.add_parser(
        "calibrate",
        help="identify the 21 errors from laser runs, ball plates and multilateration",
        usage=USAGE,
        description="Identify the machine's parametric errors, with the uncertainty of each, "
        "from the data sets of a calibration plan (laser interferometer runs, ball or hole "
        "plates, sequential multilateration); 'plan' predicts the uncertainty a plan will give "
        "on a guessed machine; 'apply' corrects an ISO 230-2 run for a re-evaluation "
        "(docs/calibration.md, formats: docs/formats.md §10).",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("words", nargs="+", metavar="PLAN | plan PLAN… | apply MACHINE RUN.dat")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        help="the identified machine.toml (calibrate); the corrected .dat (apply)",
    )
    p.add_argument(
        "--report",
        type=Path,
        help="calibrate: write calibration.json, "
        "volumetric_u.csv, PNGs and index.html into this folder",
    )
    p.add_argument(
        "--no-figures",
        action="store_true",
        help="calibrate: the report without its PNGs (faster; index.html says they were not drawn)",
    )
    p.add_argument("--machine", type=Path, help="plan: the machine you expect (GUESS.toml)")
    p.add_argument("--json", type=Path, help="plan: the prediction as JSON")
    p.add_argument(
        "--trials",
        type=int,
        default=0,
        help="plan: check the prediction with this many simulated calibrations (default 0)",
    )
    p.add_argument("--seed", type=int, default=0, help="plan: random seed (default 0)")
    p.add_argument("--axis", choices=("x", "y", "z"), help="apply: the axis of the run")
    p.add_argument(
        "--line",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="apply: the other axes' positions during the run, mm (default the reference)",
    )
    p.add_argument(
        "--optic",
        nargs=3,
        type=float,
        metavar=("X", "Y", "Z"),
        help="apply: the optic's offset, mm (default 0 0 0)",
    )
    p.add_argument(
        "--cycles",
        nargs="+",
        type=int,
        metavar="C",
        help="apply: the cycles to correct (default all): use those not calibrated on",
    )
    p.add_argument(
        "--uncorrected",
        action="store_true",
        help="apply: write the chosen cycles without the correction (the 'before')",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(handler=cmd_calibrate)
