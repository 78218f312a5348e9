"""Values for a JSON report: numpy scalars and arrays as Python numbers and lists, and no number
that is not finite (``json`` would write NaN/Infinity, which is not JSON, or a caller would write
null: a figure silently missing)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np


def finite_json(obj: Any, where: str, refuse: Callable[[str, float], Exception]) -> Any:
    """``obj`` with numpy values as Python ones; ``raise refuse(path, value)`` at the first
    number that is not finite (``path`` like ``report.datasets[0].rms``)."""
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    if isinstance(obj, float) and not math.isfinite(obj):
        raise refuse(where, obj)
    if isinstance(obj, dict):
        return {k: finite_json(v, f"{where}.{k}", refuse) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [finite_json(v, f"{where}[{i}]", refuse) for i, v in enumerate(obj)]
    return obj
