"""A random true machine: 18 smooth parametric error functions, squareness, a small reversal.

Each error function is a Legendre series in the axis' normalised travel s ∈ [−1, 1] (the
machine's [volume]), order 3 to 5, its shape coefficients falling as 1/k and scaled to a drawn
amplitude (sizes as a machine of moderate quality has them, docs of the package: README.md):

* positional ``dI_I``: a scale error of ±25 µm/m plus a curve of 1–6 µm, zero at the reference;
* straightness: a slope of ±5 µrad, an offset of ±2 µm and a curve of 0.5–6 µm;
* angular: an offset of ±4 µrad plus a curve of 1–8 µrad (rolls half that);
* squareness α, β1, β2: ±30 µrad;
* reversal (backlash) of each axis: a half step of 0.05–0.5 µm, +h after travelling towards larger
  positions, −h the other way; the truth compared with the identification is the mean (no h).

The reference point is the volume's lower corner (the contract). The same machine is written as
``machine.toml`` (docs/formats.md §1: polynomial tables in the axis position, the reversal as a
``reversal`` effect) for reference; this module imports nothing of cmm-comp.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.polynomial import legendre as leg
from numpy.typing import NDArray

from .kinematics import AXES, MODEL_AXES, Pose, chain_poses, tip_error_um

FloatArray = NDArray[np.float64]

#: the 18 tables: (δx, δy, δz, εx, εy, εz) of x, then of y, then of z
COMPONENTS: tuple[str, ...] = tuple(
    f"{kind}{direction}_{axis}" for axis in AXES for kind in ("d", "e") for direction in AXES
)
SQUARENESS = ("alpha", "beta1", "beta2")


@dataclass
class TrueMachine:
    """A machine with known errors. Positions mm, linear errors µm, angles µrad."""

    model: str
    lower_mm: FloatArray
    upper_mm: FloatArray
    probe_mm: FloatArray
    legendre: dict[str, FloatArray]  # component → Legendre coefficients on the travel
    squareness_urad: dict[str, float]
    reversal_um: dict[str, float] = field(default_factory=dict)  # half step per axis
    name: str = "calgen"

    @property
    def reference_mm(self) -> FloatArray:
        return self.lower_mm

    def _s(self, axis: str, q_mm: FloatArray) -> FloatArray:
        k = AXES.index(axis)
        lo, hi = self.lower_mm[k], self.upper_mm[k]
        return (2.0 * np.asarray(q_mm, dtype=float) - lo - hi) / (hi - lo)

    def component(self, name: str, q_axis_mm: FloatArray) -> FloatArray:
        """Values (µm or µrad) of one table at positions of its axis (mm)."""
        return leg.legval(self._s(name[3], q_axis_mm), self.legendre[name])

    def parametric(
        self, q_mm: FloatArray, dirs: Mapping[str, FloatArray] | None = None
    ) -> tuple[dict[str, FloatArray], dict[str, FloatArray]]:
        """Linear (µm) and angular (µrad) errors of each axis at points q (N, 3), each (N, 3).

        ``dirs`` maps an axis to its last direction of travel (+1/−1/0, scalar or (N,)); the
        reversal adds ``dir·h`` to that axis' positional error.
        """
        q = np.atleast_2d(np.asarray(q_mm, dtype=float))
        linear: dict[str, FloatArray] = {}
        angular: dict[str, FloatArray] = {}
        for j, axis in enumerate(AXES):
            lin = np.stack([self.component(f"d{i}_{axis}", q[:, j]) for i in AXES], axis=1)
            ang = np.stack([self.component(f"e{i}_{axis}", q[:, j]) for i in AXES], axis=1)
            if dirs is not None and axis in dirs:
                lin[:, j] += np.asarray(dirs[axis], dtype=float) * self.reversal_um.get(axis, 0.0)
            linear[axis] = lin
            angular[axis] = ang
        return linear, angular

    def poses(
        self, q_mm: FloatArray, dirs: Mapping[str, FloatArray] | None = None
    ) -> tuple[Pose, Pose]:
        """``(pose_base_tool, pose_base_work)`` of the exact chain at indicated points."""
        q = np.atleast_2d(np.asarray(q_mm, dtype=float))
        linear, angular = self.parametric(q, dirs)
        u = q - self.reference_mm
        return chain_poses(self.model, u, linear, angular, self.squareness_urad)

    def error_um(
        self,
        q_mm: FloatArray,
        stylus_mm: FloatArray | None = None,
        dirs: Mapping[str, FloatArray] | None = None,
    ) -> FloatArray:
        """Volumetric error (N, 3) µm, true − indicated, at indicated points for a stylus (mm)."""
        q = np.atleast_2d(np.asarray(q_mm, dtype=float))
        stylus = self.probe_mm if stylus_mm is None else np.asarray(stylus_mm, dtype=float)
        tool, work = self.poses(q, dirs)
        return tip_error_um(tool, work, q - self.reference_mm, stylus)

    def true_position_mm(
        self,
        q_mm: FloatArray,
        stylus_mm: FloatArray,
        dirs: Mapping[str, FloatArray] | None = None,
    ) -> FloatArray:
        """True tip position (workpiece frame, mm) at indicated points: q + error."""
        q = np.atleast_2d(np.asarray(q_mm, dtype=float))
        return q + self.error_um(q, stylus_mm, dirs) / 1000.0

    def body_rotation(
        self, q_mm: FloatArray, axis: str, dirs: Mapping[str, FloatArray] | None = None
    ) -> FloatArray:
        """(N, 3, 3) rotation of the body an angle optic sits on while ``axis`` moves.

        A tool axis: the ram (the optic at the stylus), relative to the base; a table axis: the
        table top, relative to the base. Either way the reading of the carriage's own angular
        error (plus constant parts of the carriages it rides on).
        """
        tool, work = self.poses(q_mm, dirs)
        return (tool if axis in MODEL_AXES[self.model][0] else work)[0]

    def power_series(self, name: str) -> list[float]:
        """Coefficients c0, c1, … of the table in the indicated position q (mm)."""
        k = AXES.index(name[3])
        series = np.polynomial.Legendre(
            self.legendre[name], domain=[self.lower_mm[k], self.upper_mm[k]]
        ).convert(kind=np.polynomial.Polynomial)
        return [float(c) for c in series.coef]


def _f(v: float) -> str:
    return repr(float(v))


def _vec(v: FloatArray) -> str:
    return "[" + ", ".join(_f(x) for x in v) + "]"


def machine_toml(machine: TrueMachine, note: str = "") -> str:
    """The machine as docs/formats.md §1 ``machine.toml`` text (polynomial tables)."""
    lines = [
        f"# the hidden truth of a generated calibration case {note}".rstrip(),
        'format = "cmm-machine/1"',
        f'name = "{machine.name}"',
        f'model = "{machine.model}"',
        "",
        "[volume]",
    ]
    for k, a in enumerate(AXES):
        lines.append(f"{a} = [{_f(machine.lower_mm[k])}, {_f(machine.upper_mm[k])}]")
    lines += [f"reference = {_vec(machine.reference_mm)}", "", "[probe]"]
    lines += [f"offset = {_vec(machine.probe_mm)}", "", "[thermal]", "reference_C = 20.0", ""]
    lines.append("[squareness]")
    lines += [f"{s} = {_f(machine.squareness_urad[s])}" for s in SQUARENESS]
    for name in COMPONENTS:
        lines += [
            "",
            f"[errors.{name}]",
            f"polynomial = {_vec(np.array(machine.power_series(name)))}",
        ]
    for k, a in enumerate(AXES):
        h = machine.reversal_um.get(a, 0.0)
        if h:
            lines += [
                "",
                "[[effects]]",
                'cause = "reversal"',
                f'axis = "{a}"',
                f"half_step_um = [{_f(h)}, 0.0]",
                f"span_mm = [{_f(machine.lower_mm[k])}, {_f(machine.upper_mm[k])}]",
            ]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- random machines
#: travel ranges (mm) per family: (x, y, z)
_SPANS = {
    "bridge": ((500.0, 1600.0), (500.0, 2000.0), (400.0, 1000.0)),
    "MH1": ((500.0, 1200.0), (1000.0, 3000.0), (600.0, 1600.0)),
    "MH2": ((1000.0, 3000.0), (500.0, 1200.0), (600.0, 1600.0)),
    "fixed_arm": ((500.0, 1500.0), (500.0, 1200.0), (500.0, 1200.0)),
    "column": ((400.0, 900.0), (300.0, 700.0), (250.0, 600.0)),
}


def _family(model: str) -> str:
    if model in ("MH1", "MH2"):
        return model
    return {"MB": "bridge", "FB": "bridge", "FH": "fixed_arm", "CX": "column", "CY": "column"}[
        model[:2]
    ]


def _shape(rng: np.random.Generator, first: int, order: int, amplitude: float) -> FloatArray:
    """Legendre coefficients of orders first…order (1/k spectrum) scaled to peak ``amplitude``."""
    coef = np.zeros(order + 1)
    k = np.arange(first, order + 1)
    coef[first:] = rng.normal(0.0, 1.0, k.size) / np.maximum(k, 1)
    peak = np.abs(leg.legval(np.linspace(-1.0, 1.0, 201), coef)).max()
    return coef * amplitude / max(peak, 1e-12)


def _table(rng: np.random.Generator, name: str, half_span_mm: float) -> FloatArray:
    order = int(rng.integers(3, 6))
    if name[0] == "e":
        amp = rng.uniform(1.0, 8.0) * (0.5 if name[1] == name[3] else 1.0)
        coef = _shape(rng, 1, order, amp)
        coef[0] += rng.uniform(-4.0, 4.0)
        return coef
    if name[1] == name[3]:  # positional: scale + curve, zero at the lower corner (s = −1)
        coef = _shape(rng, 2, order, rng.uniform(1.0, 6.0))
        coef[1] += rng.uniform(-25.0, 25.0) * half_span_mm / 1000.0
        coef[0] -= leg.legval(-1.0, coef)
        return coef
    coef = _shape(rng, 2, order, rng.uniform(0.5, 6.0))
    coef[1] += rng.uniform(-5.0, 5.0) * half_span_mm / 1000.0
    coef[0] += rng.uniform(-2.0, 2.0)
    return coef


def _probe(rng: np.random.Generator, model: str) -> FloatArray:
    lateral = rng.uniform(-20.0, 20.0, 3)
    if model == "MH1":
        p = np.array([rng.uniform(50.0, 200.0), lateral[1], -rng.uniform(0.0, 100.0)])
    elif model == "MH2":
        p = np.array([lateral[0], rng.uniform(50.0, 200.0), -rng.uniform(0.0, 100.0)])
    else:
        p = np.array([lateral[0], lateral[1], -rng.uniform(80.0, 250.0)])
    return p.round(1)


def random_machine(rng: np.random.Generator, model: str, name: str = "calgen") -> TrueMachine:
    """A random machine of ``model`` (one of MODEL_AXES)."""
    if model not in MODEL_AXES:
        raise ValueError(f"unknown model {model!r}; allowed: {sorted(MODEL_AXES)}")
    spans = _SPANS[_family(model)]
    span = np.array([rng.uniform(lo, hi) for lo, hi in spans]).round(0)
    lower = np.zeros(3) if rng.random() < 0.6 else rng.uniform(-300.0, 100.0, 3).round(0)
    upper = lower + span
    legendre = {c: _table(rng, c, span[AXES.index(c[3])] / 2.0) for c in COMPONENTS}
    squareness = {s: round(float(rng.uniform(-30.0, 30.0)), 2) for s in SQUARENESS}
    reversal = {a: round(float(rng.uniform(0.05, 0.5)), 3) for a in AXES}
    return TrueMachine(
        model=model,
        lower_mm=lower,
        upper_mm=upper,
        probe_mm=_probe(rng, model),
        legendre=legendre,
        squareness_urad=squareness,
        reversal_um=reversal,
        name=name,
    )


def grid_nodes(
    lower_mm: FloatArray, upper_mm: FloatArray, steps: tuple[int, int, int] = (6, 6, 6)
) -> FloatArray:
    """(n, 3) nodes of the contract's grid (corners included), x slowest, z fastest."""
    axes = [np.linspace(lower_mm[k], upper_mm[k], steps[k]) for k in range(3)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)
