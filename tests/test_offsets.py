"""Measurement offsets (paper section 4, appendix A.2) against three independent oracles.

1. The paper's printed rules (tests/paper_a2.py): coefficient by coefficient against the chain's
   first-order Jacobian, and against what ``Machine.from_dict`` does with a table's ``offset``.
2. The exact model: measure a line through an offset point with ``volumetric_error``, load it with
   ``offset = o`` and compare with the same line measured at the reference point.
3. Squareness measured with two lines through an offset point, likewise.

Disagreements between the paper and the chain are explained in docs/seed-equations-a2.md.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from paper_a2 import LINEAR_TARGETS, PRINTED, SLIPS, SQUARENESS_AGREE, SQUARENESS_TARGETS

from cmm_comp.compensation.kinematics import MODEL_CHAINS, first_order_jacobian
from cmm_comp.compensation.machine import Machine
from cmm_comp.compensation.parametric_errors import AXES, AXIS_INDEX, TABLE_COMPONENTS
from cmm_comp.compensation.straightness import apply_criterion

MODELS = tuple(MODEL_CHAINS)
ANGULAR = tuple(f"e{i}_{a}" for a in AXES for i in AXES)
LINEAR = tuple(f"d{i}_{a}" for a in AXES for i in AXES)
#: squareness → its two lines: (axis the line runs along, error component the line shows)
SQUARENESS_LINES = {
    "alpha": (("x", 1), ("y", 0)),
    "beta1": (("x", 2), ("z", 0)),
    "beta2": (("y", 2), ("z", 1)),
}
UPPER_MM = np.array([800.0, 1000.0, 600.0])
NODES = 17


# --------------------------------------------------------------------------- helpers
def evaluate(expr: str, env: dict[str, Any]) -> Any:
    """A printed rule with every symbol zero except those in ``env`` (arms in metres)."""
    names = dict.fromkeys((*ANGULAR, *LINEAR, "alpha", "beta1", "beta2"), 0.0)
    names.update(x=0.0, y=0.0, z=0.0, xo=0.0, yo=0.0, zo=0.0)
    names.update(env)
    return eval(expr, {"__builtins__": {}}, names)


def jacobian_per_m(model: str, u_mm: list[float]) -> np.ndarray:
    """First-order coefficients (3 out, 3 axes, 6) at ``u`` with arms in metres (µm per µrad·m)."""
    jac, _ = first_order_jacobian(MODEL_CHAINS[model], np.array([u_mm], float), np.zeros(3))
    return jac[0] * 1000.0


def chain_linear_rule(model: str, comp: str) -> dict[tuple[str, str], float]:
    """Chain's δ* = δ − Σ_k [J_i,ak(o) − J_i,ak(ref)]·ε_k(a): coefficient of (m − mo)·e_k(a)."""
    i, a = AXIS_INDEX[comp[1]], AXIS_INDEX[comp[3]]
    j0 = jacobian_per_m(model, [0.0, 0.0, 0.0])
    out = {}
    for m in range(3):
        if m == a:  # a line along a has no offset along a
            continue
        jm = jacobian_per_m(model, [1.0 if n == m else 0.0 for n in range(3)])
        for k in range(3):
            c = -(jm[i, a, 3 + k] - j0[i, a, 3 + k])
            if abs(c) > 1e-12:
                out[(f"e{AXES[k]}_{comp[3]}", AXES[m])] = round(c, 9)
    return out


def paper_linear_rule(expr: str) -> dict[tuple[str, str], float]:
    """Coefficient of (m − mo)·e in a printed linear rule (any angular error, any offset)."""
    out = {}
    for e, m in itertools.product(ANGULAR, AXES):
        c = evaluate(expr, {e: 1.0, m: 1.0}) - evaluate(expr, {})
        if abs(c) > 1e-12:
            out[(e, m)] = round(c, 9)
    return out


def chain_squareness_rule(model: str, sq: str) -> dict[tuple[str, str], float]:
    """Chain's squareness rule ``s* = s_m + Σ slopes of all Abbe terms along the two lines``.

    Keys: ``(e, "const")`` — the angular error at the measurement location (another axis'
    error whose arm grows along the line); ``(e, "arm n")`` — (n − no)·slope of e along its own
    axis (the paper's chord ``(n − no)·E(a)/(a − ao)``); ``(e, "own arm")`` — slope of
    (a − ao)·e(a) (a workpiece-side axis whose arm is its own travel; no paper counterpart).
    """
    d = [
        jacobian_per_m(model, [1.0 if n == m else 0.0 for n in range(3)])
        - jacobian_per_m(model, [0.0, 0.0, 0.0])
        for m in range(3)
    ]
    out: dict[tuple[str, str], float] = {}
    for axis, comp in SQUARENESS_LINES[sq]:
        line = AXIS_INDEX[axis]
        for a, k in itertools.product(range(3), range(3)):
            e = f"e{AXES[k]}_{AXES[a]}"
            if a != line:
                keys = [((e, "const"), d[line][comp, a, 3 + k])]
            else:
                keys = [
                    ((e, "own arm" if n == a else f"arm {AXES[n]}"), d[n][comp, a, 3 + k])
                    for n in range(3)
                ]
            for key, c in keys:
                if abs(c) > 1e-12:
                    out[key] = out.get(key, 0.0) + c
    return {k: round(v, 9) for k, v in out.items() if abs(v) > 1e-12}


def paper_squareness_rule(expr: str) -> dict[tuple[str, str], float]:
    """Printed squareness rule in the same basis, by probing it at random offsets.

    A chord ``(n − no)·E(a)/(m − mo)`` with m ≠ a (a chord along the wrong axis) is kept as
    ``(e, "arm n / m")`` so that it can never match the chain.
    """
    rng = np.random.default_rng(7)
    d = rng.uniform(0.3, 2.0, (30, 3)) * rng.choice([-1.0, 1.0], (30, 3))
    pairs = [(n, m) for n in range(3) for m in range(3) if n != m]
    basis = np.column_stack([np.ones(len(d))] + [d[:, n] / d[:, m] for n, m in pairs])
    out = {}
    for e in ANGULAR:
        g = np.array(
            [
                evaluate(expr, {e: 1.0, "x": p[0], "y": p[1], "z": p[2]})
                - evaluate(expr, {"x": p[0], "y": p[1], "z": p[2]})
                for p in d
            ]
        )
        coef, *_ = np.linalg.lstsq(basis, g, rcond=None)
        assert np.allclose(basis @ coef, g), f"{expr}: not of the chord form in {e}"
        if abs(coef[0]) > 1e-9:
            out[(e, "const")] = round(float(coef[0]), 9)
        for (n, m), c in zip(pairs, coef[1:], strict=True):
            if abs(c) > 1e-9:
                kind = f"arm {AXES[n]}" if AXES[m] == e[-1] else f"arm {AXES[n]} / {AXES[m]}"
                out[(e, kind)] = round(float(c), 9)
    return out


def synthetic_tables(seed: int = 0, amp_urad: float = 20.0) -> dict[str, dict[str, Any]]:
    """18 smooth tables on 17 nodes, zero at the reference (the lower corner)."""
    rng = np.random.default_rng(seed)
    tables = {}
    for comp in TABLE_COMPONENTS:
        k = AXIS_INDEX[comp[3]]
        pos = np.linspace(0.0, UPPER_MM[k], NODES)
        s = pos / UPPER_MM[k]
        a1, a2, a3 = rng.normal(0.0, amp_urad if comp[0] == "e" else 5.0, 3)
        tables[comp] = {
            "position": pos.tolist(),
            "value": (a1 * s + a2 * np.sin(2.5 * s) + a3 * s**3).tolist(),
        }
    return tables


def machine_dict(model: str, errors: dict[str, Any], **squareness: Any) -> dict[str, Any]:
    return {
        "name": f"oracle-{model}",
        "model": model,
        "volume": {"x": [0.0, UPPER_MM[0]], "y": [0.0, UPPER_MM[1]], "z": [0.0, UPPER_MM[2]]},
        "squareness": {"alpha": 12.0, "beta1": -5.0, "beta2": 3.0, **squareness},
        "errors": errors,
    }


def is_straightness(comp: str) -> bool:
    return comp[0] == "d" and comp[1] != comp[3]


# --------------------------------------------------------------------------- 1. printed rules
@pytest.mark.parametrize("model", MODELS)
def test_printed_linear_rules_vs_chain(model: str) -> None:
    """Every printed positional/straightness rule equals the chain's, coefficient by coefficient,
    except the slips listed in paper_a2.SLIPS, which differ and whose correction is the chain."""
    for comp in LINEAR_TARGETS:
        expr, _ = PRINTED[model][comp]
        assert expr is not None
        chain = chain_linear_rule(model, comp)
        assert paper_linear_rule(f"({expr}) - {comp}") == chain or (model, comp) in SLIPS, (
            f"{model} {comp}: printed {expr!r} disagrees with the chain {chain}"
        )
        if (model, comp) in SLIPS:
            assert paper_linear_rule(f"({expr}) - {comp}") != chain, f"{model} {comp} agrees"
            assert paper_linear_rule(f"({SLIPS[model, comp]}) - {comp}") == chain


def test_printed_criterion_marks_are_straightness_only() -> None:
    for model, comp in itertools.product(MODELS, LINEAR_TARGETS):
        _, criterion = PRINTED[model][comp]
        assert not criterion or is_straightness(comp), (model, comp)


def table_own_travel(
    model: str, comp: str, u_own_mm: np.ndarray, env: dict[str, Any]
) -> np.ndarray:
    """The A.1 Abbe term of a moving table's own angular errors with its own travel as arm (e.g.
    FB1 ΔX ∋ y·Ez(y)): a line measured anywhere reads it, and the loader removes it from tables
    given with an ``offset`` (docs/seed-equations.md). Zero for tool-side axes. Oracle: the
    printed appendix A.1 (tests/paper_a1.py), evaluated term by term."""
    from paper_a1 import CORRECTIONS as A1_CORRECTIONS
    from paper_a1 import PRINTED as A1

    i, axis = "xyz".index(comp[1]), comp[3]
    expr = A1[model][i]
    if (model, i) in A1_CORRECTIONS:
        expr = f"({expr}) + {A1_CORRECTIONS[(model, i)]}"
    base: dict[str, Any] = dict.fromkeys(
        [*LINEAR, *ANGULAR, "alpha", "beta1", "beta2", "phi1", "phi2"], 0.0
    )
    base.update(x=0.0, y=0.0, z=0.0, Xp=0.0, Yp=0.0, Zp=0.0)
    base[axis] = u_own_mm / 1000.0
    total = np.zeros_like(u_own_mm)
    for e in ANGULAR:
        if e[3] == axis:
            one = dict(base)
            one[e] = 1.0
            total = total + evaluate(expr, one) * env[e]
    return total


@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("direction", AXES)
def test_loader_applies_the_printed_rules(model: str, direction: str) -> None:
    """``Machine.from_dict`` with ``offset`` = o − ref along one direction (one coefficient at a
    time) gives the printed rule (its chain correction for the slips) evaluated on the tables."""
    ref = np.array([100.0, 200.0, 50.0])
    offset = ref.copy()
    offset[AXIS_INDEX[direction]] += 250.0
    errors = synthetic_tables(seed=3)
    measured = {}
    for comp in LINEAR_TARGETS:
        if comp[3] == direction:
            continue  # a line along this axis has no offset along it
        measured[comp] = errors[comp]
        errors[comp] = {**errors[comp], "offset": offset.tolist()}
        if is_straightness(comp):
            errors[comp]["criterion"] = "least_squares"
    data = machine_dict(model, errors)
    data["volume"]["reference"] = ref.tolist()
    machine = Machine.from_dict(data)
    arms_m = dict(zip(("x", "y", "z"), (offset - ref) / 1000.0, strict=True))
    for comp, tbl in measured.items():
        pos = np.asarray(tbl["position"])
        env: dict[str, Any] = {comp: np.asarray(tbl["value"]), **arms_m}
        for e in ANGULAR:
            if e[3] == comp[3]:
                env[e] = np.asarray(errors[e]["value"])
        rule = SLIPS.get((model, comp), PRINTED[model][comp][0])
        assert rule is not None
        expected = evaluate(rule, env) * np.ones_like(pos) - table_own_travel(
            model, comp, pos - ref[AXIS_INDEX[comp[3]]], env
        )
        if is_straightness(comp):
            expected = apply_criterion(pos, expected, "least_squares")
        got = machine.tables[comp].value
        np.testing.assert_allclose(got, expected, atol=1e-9, err_msg=f"{model} {comp}")


@pytest.mark.parametrize("model", MODELS)
def test_printed_squareness_rules_vs_chain(model: str) -> None:
    """The printed squareness rules that agree with the derivation are exactly those listed in
    paper_a2.SQUARENESS_AGREE (the rest are tabulated in docs/seed-equations-a2.md)."""
    for sq in SQUARENESS_TARGETS:
        expr, _ = PRINTED[model][sq]
        chain = chain_squareness_rule(model, sq)
        agree = expr is not None and paper_squareness_rule(f"({expr}) - {sq}") == chain
        assert agree == ((model, sq) in SQUARENESS_AGREE), f"{model} {sq}: {expr} vs {chain}"


# --------------------------------------------------------------------------- 2. exact model
def measure_line(machine: Machine, comp: str, at_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Simulated measurement of ``comp`` along its axis through ``at_mm`` (exact model).

    Positional errors are zeroed at the first position, like an interferometer.
    """
    k = AXIS_INDEX[comp[3]]
    pos = np.linspace(0.0, UPPER_MM[k], NODES)
    pts = np.repeat(at_mm[None, :], NODES, axis=0)
    pts[:, k] = pos
    value = machine.volumetric_error(pts)[:, AXIS_INDEX[comp[1]]]
    if not is_straightness(comp):
        value = value - value[0]
    return pos, value


def loaded_from_measurements(
    truth: Machine, model: str, angular: dict[str, Any], at_mm: np.ndarray
) -> Machine:
    errors = dict(angular)
    for comp in LINEAR:
        pos, value = measure_line(truth, comp, at_mm)
        errors[comp] = {"position": pos.tolist(), "value": value.tolist(), "offset": list(at_mm)}
        if is_straightness(comp):
            errors[comp]["criterion"] = "least_squares"
    return Machine.from_dict(machine_dict(model, errors))


@pytest.mark.parametrize("model", MODELS)
def test_lines_measured_at_an_offset_reproduce_the_reference_tables(model: str) -> None:
    """Measure every linear error along a line through o with the exact model, load it with
    ``offset = o``: the tables equal those measured through the reference point (to second order:
    angles ~50 µrad, arms ≤ 1.4 m → second-order terms ≲ 0.01 µm)."""
    tables = synthetic_tables(seed=11)
    truth = Machine.from_dict(machine_dict(model, tables))
    angular = {c: t for c, t in tables.items() if c[0] == "e"}
    at_ref = loaded_from_measurements(truth, model, angular, np.zeros(3))
    for o in (np.array([400.0, 700.0, 450.0]), np.array([800.0, 0.0, 600.0])):
        at_o = loaded_from_measurements(truth, model, angular, o)
        for comp in LINEAR:
            np.testing.assert_allclose(
                at_o.tables[comp].value,
                at_ref.tables[comp].value,
                atol=0.01,
                err_msg=f"{model} {comp} measured at {o}",
            )
        pts = np.random.default_rng(1).uniform(0.0, UPPER_MM, (40, 3))
        np.testing.assert_allclose(
            at_o.volumetric_error(pts), at_ref.volumetric_error(pts), atol=0.02
        )


@pytest.mark.parametrize("model", ["MB1", "MB2", "MH1", "MH2"])
def test_tool_side_tables_measured_at_the_reference_are_the_model(model: str) -> None:
    """With every axis on the tool side the reference-point table is the parametric table itself
    (after zeroing and the straightness criterion), so the loaded model is the true one."""
    tables = synthetic_tables(seed=12)
    for comp in LINEAR:
        if is_straightness(comp):
            tables[comp]["criterion"] = "least_squares"
    truth = Machine.from_dict(machine_dict(model, tables))
    angular = {c: t for c, t in tables.items() if c[0] == "e"}
    loaded = loaded_from_measurements(truth, model, angular, np.array([500.0, 300.0, 200.0]))
    for comp in LINEAR:
        np.testing.assert_allclose(
            loaded.tables[comp].value, truth.tables[comp].value, atol=0.01, err_msg=comp
        )


@pytest.mark.parametrize("model", ["FB1"])
def test_workpiece_side_tables_measured_at_the_reference_are_the_model(model: str) -> None:
    tables = synthetic_tables(seed=12)
    for comp in LINEAR:
        if is_straightness(comp):
            tables[comp]["criterion"] = "least_squares"
    truth = Machine.from_dict(machine_dict(model, tables))
    angular = {c: t for c, t in tables.items() if c[0] == "e"}
    loaded = loaded_from_measurements(truth, model, angular, np.zeros(3))
    for comp in LINEAR:
        np.testing.assert_allclose(
            loaded.tables[comp].value, truth.tables[comp].value, atol=0.01, err_msg=comp
        )


# --------------------------------------------------------------------------- 3. squareness
def _squareness_slopes(
    at_mm: np.ndarray, nodes: int, along: Callable[[np.ndarray, int], np.ndarray]
) -> np.ndarray:
    """Σ over the two lines of each squareness of the least-squares slope (µrad) of
    ``along(points, component)`` along the line through ``at_mm`` (sampled at ``nodes`` points)."""
    out = []
    for sq in SQUARENESS_TARGETS:
        total = 0.0
        for axis, comp in SQUARENESS_LINES[sq]:
            k = AXIS_INDEX[axis]
            q = np.linspace(0.0, UPPER_MM[k], nodes)
            pts = np.repeat(at_mm[None, :], nodes, axis=0)
            pts[:, k] = q
            total += np.polyfit(q, along(pts, comp), 1)[0] * 1000.0
        out.append(total)
    return np.array(out)


def measure_squareness(machine: Machine, at_mm: np.ndarray, nodes: int = NODES) -> np.ndarray:
    """(α, β1, β2) µrad from the least-squares slopes of two lines through ``at_mm``, sampled at
    the straightness tables' positions (the loader takes the lines' slopes there)."""
    return -_squareness_slopes(at_mm, nodes, lambda pts, c: machine.volumetric_error(pts)[:, c])


def chain_squareness_correction(
    machine: Machine, at_mm: np.ndarray, nodes: int = NODES
) -> np.ndarray:
    """The derivation: slopes of the Abbe terms of *all* axes' angular errors along both lines."""

    def abbe(pts: np.ndarray, comp: int) -> np.ndarray:
        jac, _ = first_order_jacobian(machine.chain, pts - machine.volume.reference_mm, np.zeros(3))
        err = machine.parametric_errors(pts)
        return np.einsum("nas,nas->n", jac[:, comp, :, 3:], err[:, :, 3:])

    return _squareness_slopes(at_mm, nodes, abbe)


def truth_machine(model: str) -> Machine:
    tables = synthetic_tables(seed=5)
    for comp in LINEAR:
        if is_straightness(comp):
            tables[comp]["criterion"] = "least_squares"
    return Machine.from_dict(machine_dict(model, tables))


@pytest.mark.parametrize("model", MODELS)
def test_chain_squareness_rule_recovers_the_true_squareness(model: str) -> None:
    """The derivation (docs/seed-equations-a2.md) applied to squareness measured with the exact
    model through three locations gives the model's (α, β1, β2) to second order."""
    truth = truth_machine(model)
    for at in ([400.0, 700.0, 450.0], [0.0, 0.0, 0.0], [800.0, 100.0, 50.0]):
        o = np.array(at)
        recovered = measure_squareness(truth, o) + chain_squareness_correction(truth, o)
        np.testing.assert_allclose(recovered, truth.squareness_urad, atol=0.01, err_msg=str(at))


@pytest.mark.parametrize("model", MODELS)
def test_squareness_measured_at_an_offset_loads_to_the_true_squareness(model: str) -> None:
    truth = truth_machine(model)
    o = np.array([400.0, 700.0, 450.0])
    measured = measure_squareness(truth, o)
    data = machine_dict(
        model,
        truth.description["errors"],
        **dict(zip(SQUARENESS_TARGETS, measured.tolist(), strict=True)),
        offset=o.tolist(),
    )
    loaded = Machine.from_dict(data)
    np.testing.assert_allclose(loaded.squareness_urad, truth.squareness_urad, atol=0.05)
