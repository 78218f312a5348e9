"""Public API of ``calibration`` (read by lazy_loader: names load on first use)."""

from .calibrate import CalibrationResult, calibrate
from .datasets import Dataset, build_problem, load_datasets
from .iso230_apply import corrected_iso230, write_iso230_dat
from .plan import FitSettings, LaserSpec, MultilaterationSpec, Plan, PlateSpec, read_plan
from .planner import predict_plan, simulated_datasets
from .report import report_json, volumetric_csv, write_outputs
from .simulate import run_values, simulate_laser, simulate_multilateration, simulate_plate
from .solver import Problem, Solution, solve
from .virtual_truth import draw_machine

__all__ = [
    "CalibrationResult",
    "Dataset",
    "FitSettings",
    "LaserSpec",
    "MultilaterationSpec",
    "Plan",
    "PlateSpec",
    "Problem",
    "Solution",
    "build_problem",
    "calibrate",
    "corrected_iso230",
    "draw_machine",
    "load_datasets",
    "predict_plan",
    "read_plan",
    "report_json",
    "run_values",
    "simulate_laser",
    "simulate_multilateration",
    "simulate_plate",
    "simulated_datasets",
    "solve",
    "volumetric_csv",
    "write_iso230_dat",
    "write_outputs",
]
