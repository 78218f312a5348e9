"""Public API of ``calibration`` (read by lazy_loader: names load on first use)."""

from .datasets import Dataset, build_problem, load_datasets
from .plan import FitSettings, LaserSpec, MultilaterationSpec, Plan, PlateSpec, read_plan
from .simulate import simulate_laser, simulate_multilateration, simulate_plate
from .solver import Problem, Solution, solve

__all__ = [
    "Dataset",
    "FitSettings",
    "LaserSpec",
    "MultilaterationSpec",
    "Plan",
    "PlateSpec",
    "Problem",
    "Solution",
    "build_problem",
    "load_datasets",
    "read_plan",
    "simulate_laser",
    "simulate_multilateration",
    "simulate_plate",
    "solve",
]
