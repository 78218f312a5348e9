"""The identification's observation models and gauge analysis against independent oracles:

* the first-order Jacobian the solver steps with against central finite differences of the exact
  model, for every reading kind (laser quantities and squareness, plate centres with their pose
  and ball parameters, multilateration lengths with station and dead path);
* the exact chain against the paper's first-order form: their difference is second order (it
  shrinks 100× when the errors shrink 10×);
* identifiability by brute force: a direction the gauge report says no reading sees changes no
  reading (finite differences of the exact model, nuisance re-fitted by least squares), a
  direction it does not list does; the rigid rotations are unseen by every kind;
* the written machine predicts the data through the test simulator's own formulas (public
  machine API) with the scatter of the noise.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibration_sim import Setup, random_machine, simulate

from cmm_comp.compensation.calibration.calibrate import calibrate
from cmm_comp.compensation.calibration.datasets import build_problem, load_datasets
from cmm_comp.compensation.calibration.plan import read_plan

SETUP = Setup(
    lower=np.zeros(3), upper=np.array([600.0, 500.0, 400.0]), stylus=np.array([0.0, 0.0, -100.0])
)


@pytest.fixture(scope="module")
def mixed(tmp_path_factory: pytest.TempPathFactory) -> tuple[object, Path]:
    folder = tmp_path_factory.mktemp("mixed")
    rng = np.random.default_rng(7)
    return simulate(
        folder, "FB1", SETUP, ("laser", "plate", "multilateration"), rng, nodes=7, wave=False
    )


def _problem(plan_path: Path):  # type: ignore[no-untyped-def]
    plan = read_plan(plan_path)
    return build_problem(plan, load_datasets(plan))


def test_jacobians_match_finite_differences_of_the_exact_model(mixed) -> None:  # type: ignore[no-untyped-def]
    _, plan_path = mixed
    problem = _problem(plan_path)
    rng = np.random.default_rng(3)
    theta = rng.normal(0.0, 3.0, problem.p)  # µm, µrad: a machine of a few µm
    states = [b.initial_state(problem.model, theta) for b in problem.blocks]
    for block, state in zip(problem.blocks, states, strict=True):
        lin = block.linearize(problem.model, theta, state)
        typical = float(np.max(np.abs(lin.jac_machine)))
        # machine parameters
        for j in rng.choice(problem.p, 12, replace=False):
            h = 1e-3
            d = np.zeros(problem.p)
            d[j] = h
            up = block.linearize(problem.model, theta + d, state).residual
            dn = block.linearize(problem.model, theta - d, state).residual
            fd = (up - dn) / (2 * h)
            # first order vs exact: the difference is of the order of the angles (~1e-5 here)
            tol = 1e-3 * float(np.max(np.abs(fd))) + 1e-4 * typical
            assert np.max(np.abs(fd - lin.jac_machine[:, j])) < tol, (block.kind, j)
        # nuisance parameters (poses, balls, stations, dead paths): exact derivatives
        for j in range(min(block.n_nuisance, 16)):
            h = 1e-2
            d = np.zeros(block.n_nuisance)
            d[j] = h
            up = block.linearize(problem.model, theta, block.advance(state, d)).residual
            dn = block.linearize(problem.model, theta, block.advance(state, -d)).residual
            fd = (up - dn) / (2 * h)
            assert np.max(np.abs(fd - lin.jac_nuisance[:, j])) < 1e-5 * max(
                1.0, np.max(np.abs(fd))
            ), (block.kind, j)


def test_exact_minus_first_order_is_second_order(mixed) -> None:  # type: ignore[no-untyped-def]
    _, plan_path = mixed
    problem = _problem(plan_path)
    rng = np.random.default_rng(5)
    direction = rng.normal(0.0, 1.0, problem.p)
    pts = problem.blocks[1].pts  # the plate's centres, with its stylus
    gaps = []
    for scale in (20.0, 2.0):
        theta = scale * direction
        exact, _ = problem.model.exact(theta, pts)
        first = np.einsum("nip,p->ni", problem.model.error_jacobian(pts), theta)
        gaps.append(float(np.max(np.abs(exact - first))))
    assert gaps[1] > 0
    assert 60.0 < gaps[0] / gaps[1] < 140.0  # quadratic: 10× smaller errors, 100× smaller gap


def _refit_change(problem, theta, states, v, h=1.0):  # type: ignore[no-untyped-def]
    """RMS change of every reading when θ moves by h·v, the nuisance re-fitted (one exact
    Gauss–Newton step from finite differences): ≈ 0 when no reading sees v."""
    changes = []
    for block, state in zip(problem.blocks, states, strict=True):
        base = block.linearize(problem.model, theta, state)
        moved = block.linearize(problem.model, theta + h * v, state)
        dr = moved.residual - base.residual
        if block.n_nuisance:
            coef, *_ = np.linalg.lstsq(base.jac_nuisance, -dr, rcond=None)
            dr = dr + base.jac_nuisance @ coef
        changes.append(float(np.sqrt(np.mean(dr**2))))
    return changes


@pytest.mark.timeout(900)  # a full calibration plus ~25 re-fits: minutes on a loaded 2-core machine
def test_unseen_directions_change_no_reading_and_seen_ones_do(mixed) -> None:  # type: ignore[no-untyped-def]
    _, plan_path = mixed
    result = calibrate(read_plan(plan_path))
    problem, sol = result.problem, result.solution
    theta, states = sol.theta, sol.states
    # rigid rotations of the whole volume: no data kind sees them
    for k in range(3):
        r = problem.rotations[:, k]
        assert max(_refit_change(problem, theta, states, r, 10.0)) < 1e-3  # 10 µrad → < 1 nm
        assert "rotation" in result.gauge["rigid_body"][3 + k]["freedom"]
        assert result.gauge["rigid_body"][3 + k]["seen_by"] == []
    # the pinned null directions (in θ), and a random direction for contrast
    root = np.sqrt(problem.ridge_internal)
    null = problem.null
    assert null.shape[1] > 0  # one stylus, lines through the middle: some combinations unseen
    for i in range(null.shape[1]):
        x = null[:, i] / root
        v = problem.theta(x)
        v = v / np.max(np.abs(v))
        assert max(_refit_change(problem, theta, states, v, 1.0)) < 2e-3, i
    rng = np.random.default_rng(11)
    v = rng.normal(0.0, 1.0, problem.p)
    assert max(_refit_change(problem, theta, states, v / np.max(np.abs(v)), 1.0)) > 1e-2


@pytest.mark.timeout(900)  # a full calibration
def test_written_machine_predicts_the_data_to_the_noise(tmp_path: Path) -> None:
    """The laser readings predicted by the written machine through the simulator's own formulas
    (relative runs, straightness lines removed) differ from the data by the noise only."""
    from calibration_sim import laser_file

    from cmm_comp.compensation.calibration.report import write_outputs

    rng = np.random.default_rng(21)
    truth = random_machine(rng, "MH1", SETUP, wave=False)
    laser_file(truth, SETUP, rng, tmp_path / "laser.csv")
    from calibration_sim import write_plan

    plan_path = write_plan(tmp_path, "MH1", SETUP, ("laser",), None, nodes=11)
    result = calibrate(read_plan(plan_path))
    write_outputs(result, tmp_path / "machine.toml", None)
    from cmm_comp.compensation import Machine

    written = Machine.from_toml(tmp_path / "machine.toml")
    noise_free = tmp_path / "predicted.csv"
    laser_file(
        written,
        Setup(SETUP.lower, SETUP.upper, SETUP.stylus, 0.0, 0.0),
        np.random.default_rng(0),
        noise_free,
    )
    data = np.genfromtxt(tmp_path / "laser.csv", delimiter=",", skip_header=2, dtype=str)
    pred = np.genfromtxt(noise_free, delimiter=",", skip_header=2, dtype=str)
    linear = data[:, 1] == "linear_um"
    d = data[linear, 3].astype(float) - pred[linear, 3].astype(float)
    runs = data[linear, 5]
    resid = np.concatenate([d[runs == r] - np.mean(d[runs == r]) for r in np.unique(runs)])
    assert 0.12 < np.sqrt(np.mean(resid**2)) < 0.3  # the simulated σ is 0.2 µm


def test_schur_eliminated_normal_matrix_equals_the_dense_inverse(mixed) -> None:  # type: ignore[no-untyped-def]
    """The solver's factor with the multilateration points' offsets eliminated (Schur complement,
    :mod:`.normal`) against brute force: the whole normal matrix assembled here from the
    prior, the pins and every group's JᵀJ, inverted densely by numpy. The flat priors (poses,
    stations) and the rigid-rotation pins make the real matrix too ill-conditioned (≈ 1e13) for
    any inverse to serve as an oracle, so here every prior precision is at least 1e-2 and the
    pins are off (condition ≈ 2e5): the algebra under test is the same."""
    from cmm_comp.compensation.calibration.normal import GAUGE_PRECISION, Normal

    _, plan_path = mixed
    problem = _problem(plan_path)
    assert problem.local.size > 0 and problem.local.size % 3 == 0
    theta = np.zeros(problem.p)
    states = [b.initial_state(problem.model, theta) for b in problem.blocks]
    res, jac = problem.linearize(theta, states)
    stats = problem.group_stats(res, jac)
    problem.base_precision = np.maximum(problem.base_precision, 1e-2)
    problem.pins = problem.pins[:0]
    rng = np.random.default_rng(5)
    lam = {c: 10.0 ** rng.uniform(-4, 0) for c in problem.classes}
    for g in problem.groups:
        g.sigma = g.sigma0 * rng.uniform(0.5, 2.0)
    x = problem.absolute(theta, states) + rng.normal(0.0, 0.1, problem.n)
    h = np.diag(problem.precision(lam)) + GAUGE_PRECISION * problem.pins.T @ problem.pins
    grad = problem.precision(lam) * x + GAUGE_PRECISION * problem.pins.T @ (problem.pins @ x)
    for g, (a, b, _) in zip(problem.groups, stats, strict=True):
        h += a / g.sigma**2
        grad += b / g.sigma**2
    scale = 1.0 / np.sqrt(np.diag(h))
    dense = np.linalg.inv(h * np.outer(scale, scale)) * np.outer(scale, scale)
    normal = Normal(problem, stats, x, lam)
    inv = normal.inverse()
    np.testing.assert_allclose(inv, dense, rtol=0, atol=1e-9 * np.abs(dense).max())
    step = -dense @ grad
    np.testing.assert_allclose(normal.step(), step, rtol=0, atol=1e-7 * np.abs(step).max())
    np.testing.assert_allclose(normal.diagonal(), np.diag(dense), rtol=1e-9)
    for a, _, _ in stats:
        assert normal.trace(a) == pytest.approx(float(np.sum(dense * a)), rel=1e-8)
    kept = normal.kept_inverse()
    np.testing.assert_allclose(
        kept, dense[np.ix_(problem.kept, problem.kept)], atol=1e-9 * np.abs(dense).max()
    )


def test_plate_gaps_are_the_stretches_no_placement_along_the_axis_reaches() -> None:
    """Hand-made placements (the answer known by construction): two flat plates at x 0–400 and
    900–1300 mm leave x 400–900 unseen; a plate standing across x at x ≈ 650 does not close the
    gap (it sees none of the rise along x); a laser linear run along x, or a multilateration,
    does."""
    from types import SimpleNamespace as NS

    from cmm_comp.compensation.calibration.gaps import gap_warning, plate_gaps

    g = np.linspace(0.0, 400.0, 5)
    flat = np.array([[u, v, 50.0] for u in g for v in g])  # an XY plate, 25 balls
    across = np.array([[650.0 + 0.01 * v, u, v] for u in g for v in g])  # a YZ plate
    q = np.vstack([flat, flat + np.array([900.0, 0.0, 0.0]), across])
    placement = np.repeat([0, 1, 2], 25)
    plate = NS(kind="plate", data=NS(placements=("a", "b", "c"), placement=placement, q_mm=q))
    lower, upper = np.zeros(3), np.array([1300.0, 400.0, 400.0])
    gaps = plate_gaps([plate], lower, upper)
    assert [(x["error"], x["from_mm"], x["to_mm"]) for x in gaps] == [("dx_x", 400.0, 900.0)]
    assert "dx_x between x = 400 and 900 mm" in (gap_warning(gaps) or "")
    linear_x = NS(kind="laser", data=NS(runs=(NS(kind="linear", axis=0),)))
    linear_y = NS(kind="laser", data=NS(runs=(NS(kind="linear", axis=1),)))
    assert plate_gaps([plate, linear_x], lower, upper) == []
    assert len(plate_gaps([plate, linear_y], lower, upper)) == 1
    assert plate_gaps([plate, NS(kind="multilateration", data=None)], lower, upper) == []
    assert gap_warning([]) is None


def test_end_weighted_roughness_against_the_closed_form() -> None:
    """The smoothness penalty's end weight (docs/calibration.md §3) against closed forms: per
    node interval the mean of 1.5·(1 − s²) is 1.5·[s − s³/3]/Δs (its mean over the travel is 1),
    and for a spline holding a function ``f`` its penalty ``L⁵∫w f‴²`` equals the analytic
    integral — a cubic (f‴ = 6a constant) costs what it costs unweighted, ``36a²L⁶``, a quartic
    (f‴ = 24b·q) ``L⁵·∫w(q)·(24bq)²dq`` by Gauss–Legendre on the polynomial integrand. A wrong
    weight, a wrong normalisation or a penalty built on the wrong intervals fails."""
    from cmm_comp.compensation.calibration.basis import END_WEIGHT_POWER, Layout, end_weight

    assert END_WEIGHT_POWER == 1.0  # the closed forms below are for (1 − s²)¹
    nodes = np.linspace(-100.0, 500.0, 13)
    s = 2.0 * (nodes - nodes[0]) / 600.0 - 1.0
    antiderivative = s - s**3 / 3.0
    expected = 1.5 * np.diff(antiderivative) / np.diff(s)
    np.testing.assert_allclose(end_weight(nodes), expected, rtol=1e-12)

    layout = Layout(
        np.array([-100.0, 0.0, 0.0]),
        np.array([500.0, 400.0, 300.0]),
        basis="spline",
        nodes=(13, 9, 9),
        order=(3, 3, 3),
        components=("ex_x",),  # angular: no fixed reference, every node free
    )
    fn = layout.functions[0]
    k = fn.curvature(3)
    span = 600.0
    a = 2e-7  # µrad/mm³: a cubic
    cubic = a * (nodes - 37.0) ** 3
    assert float(cubic @ k @ cubic) == pytest.approx(36.0 * a**2 * span**6, rel=1e-9)
    b = 3e-10  # a quartic: f‴ = 24·b·q, not constant; the spline (not-a-knot) is not exact for
    quartic = b * nodes**4  # it, so compare within the spline's own third-derivative error
    g, gw = np.polynomial.legendre.leggauss(8)
    q = nodes[0] + (g + 1.0) / 2.0 * span
    weight = 1.5 * (1.0 - g**2)
    exact = span**5 * float(np.sum(gw / 2.0 * span * weight * (24.0 * b * q) ** 2))
    assert float(quartic @ k @ quartic) == pytest.approx(exact, rel=0.05)
