"""Public API of ``uncertainty`` (read by lazy_loader: names load on first use)."""

from .adaptive import McResult, MonteCarloSettings, numerical_tolerance, run_monte_carlo
from .fields import SquaredExponentialBasis, squared_exponential_basis
from .gum import BUDGET_GROUPS, residual_covariance, residual_std, uncertainty_budget
from .model import TableUncertainty, UncertaintyModel, UncertaintySection, resolve_uncertainty
from .tasks import (
    E0_NDIG,
    P_PASS_TOLERANCE,
    PointUncertainty,
    TaskUncertainty,
    e0_uncertainty,
    flatness_uncertainty,
    length_uncertainty,
    plane_grid_points,
    point_uncertainty,
    sphere_probing_points,
    sphere_uncertainty,
)
from .virtual_cmm import VirtualCMM

__all__ = [
    "BUDGET_GROUPS",
    "E0_NDIG",
    "P_PASS_TOLERANCE",
    "McResult",
    "MonteCarloSettings",
    "PointUncertainty",
    "SquaredExponentialBasis",
    "TableUncertainty",
    "TaskUncertainty",
    "UncertaintyModel",
    "UncertaintySection",
    "VirtualCMM",
    "e0_uncertainty",
    "flatness_uncertainty",
    "length_uncertainty",
    "numerical_tolerance",
    "plane_grid_points",
    "point_uncertainty",
    "residual_covariance",
    "residual_std",
    "resolve_uncertainty",
    "run_monte_carlo",
    "sphere_probing_points",
    "sphere_uncertainty",
    "squared_exponential_basis",
    "uncertainty_budget",
]
