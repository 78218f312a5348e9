"""The API an outside user meets (issue 10, item 7): one stylus default everywhere, machines built
in Python, readable model names."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation import (
    MODEL_CHAINS,
    Machine,
    MachineFileError,
    ParametricErrors,
    Probe,
    Volume,
    describe_model,
    diagonal_endpoints,
    diagonals_um,
    length_error_um,
    line_report,
    model_code,
    model_table,
    volumetric_map,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "machines"


# ----------------------------------------------------------------------------- stylus default
@pytest.fixture(scope="module")
def npl() -> Machine:
    machine = Machine.from_toml(EXAMPLES / "npl-bridge.toml")
    assert np.any(machine.probe.offset_mm)  # the default must matter for this test to mean much
    return machine


def test_default_stylus_is_the_probe_everywhere(npl: Machine) -> None:
    probe = npl.probe.offset_mm.copy()
    temps = {"T_x": 21.5}
    point = np.array([450.0, 575.0, 200.0])
    oracle = npl.volumetric_error(point[None, :], stylus_mm=probe, temps_C=temps)[0]
    zero = npl.volumetric_error(point[None, :], stylus_mm=(0.0, 0.0, 0.0), temps_C=temps)[0]
    assert np.max(np.abs(oracle - zero)) > 0.1  # µm: stylus (0,0,0) would be visibly different

    # 1. volumetric_error
    np.testing.assert_array_equal(npl.volumetric_error(point, temps_C=temps)[0], oracle)
    # 2. the map, at the node that is the point (steps put a node there)
    vmap = volumetric_map(npl, steps=(3, 3, 3), temps_C=temps)
    node = np.flatnonzero(np.all(vmap.points_mm == point, axis=1))
    assert node.size == 1
    np.testing.assert_allclose(vmap.error_um[node[0]], oracle, atol=1e-12)
    np.testing.assert_array_equal(vmap.stylus_mm, probe)
    # 3. a line through the point (the middle sample is the point)
    line = line_report(npl, "y", point, samples=3, temps_C=temps)
    np.testing.assert_array_equal(line.position_mm[1], point[1])
    np.testing.assert_allclose(line.error_um[1], oracle, atol=1e-12)
    # 4. diagonals: the length error from the oracle's errors at both ends
    lengths = diagonals_um(npl, temps_C=temps)
    for (a, b), got in zip(diagonal_endpoints(npl), lengths, strict=True):
        e = npl.volumetric_error(np.stack([a, b]), stylus_mm=probe, temps_C=temps) / 1000.0
        expected = (np.linalg.norm(b + e[1] - a - e[0]) - np.linalg.norm(b - a)) * 1000.0
        assert got == pytest.approx(expected, abs=1e-9)
        assert length_error_um(npl, a, b, temps_C=temps) == got
    # the random part takes the same default
    np.testing.assert_array_equal(npl.random_error(point), npl.random_error(point, stylus_mm=probe))


# ----------------------------------------------------------------------------- Python constructor
HAND_TOML = """
name = "hand"
model = "moving_bridge"

[volume]
x = [0, 800]
y = [0, 600]
z = [0, 400]
reference = [0, 0, 0]

[probe]
offset = [5, -5, -100]

[squareness]
alpha = 3.0
beta1 = -2.0

[errors.dx_x]
polynomial = [0.0, 0.004, -2e-6]

[errors.EBX]
polynomial = [1.0, 0.01]

[errors.dz_z]
polynomial = [0.0, -0.003]
random_band = 0.4

[errors.dy_x]
position = [0, 200, 400, 600, 800]
value = [0.0, 1.5, 2.0, 1.0, 0.0]
random = [0.1, 0.1, 0.2, 0.1, 0.1]

[errors.ez_y]
position = [0, 300, 600]
value = [0.0, 4.0, 2.0]

[errors.dx_y]
position = [0, 150, 300, 450, 600]
value = [0.0, 0.8, 1.4, 0.9, 0.2]
offset = [200, 0, 100]
criterion = "end_points"
"""


def test_machine_from_python_parts_equals_the_toml(tmp_path: Path) -> None:
    path = tmp_path / "hand.toml"
    path.write_text(HAND_TOML, encoding="utf-8")
    from_file = Machine.from_toml(path)

    errors = ParametricErrors.from_polynomials(
        {"dx_x": [0.0, 0.004, -2e-6], "ey_x": [1.0, 0.01], "dz_z": [0.0, -0.003]},
        random_band={"dz_z": 0.4},
        squareness_urad=(3.0, -2.0, 0.0),
    ).combined(
        ParametricErrors.from_tables(
            {
                "dy_x": ([0, 200, 400, 600, 800], [0.0, 1.5, 2.0, 1.0, 0.0]),
                "ez_y": ([0, 300, 600], [0.0, 4.0, 2.0]),
                "dx_y": ([0, 150, 300, 450, 600], [0.0, 0.8, 1.4, 0.9, 0.2]),
            },
            random={"dy_x": [0.1, 0.1, 0.2, 0.1, 0.1]},
            offsets_mm={"dx_y": (200, 0, 100)},
            criteria={"dx_y": "end_points"},
        )
    )
    built = Machine.from_parts(
        model="moving_bridge",
        volume=[(0, 800), (0, 600), (0, 400)],
        errors=errors,
        probe=(5, -5, -100),
        name="hand",
    )
    assert built.model == from_file.model == "MB1"
    rng = np.random.default_rng(7)
    pts = rng.uniform([0, 0, 0], [800, 600, 400], size=(200, 3))
    for stylus in (None, (0.0, 0.0, 0.0), (10.0, 20.0, -150.0)):
        np.testing.assert_allclose(
            built.volumetric_error(pts, stylus), from_file.volumetric_error(pts, stylus), atol=1e-12
        )
    np.testing.assert_allclose(built.random_error(pts), from_file.random_error(pts), atol=1e-12)
    assert np.any(built.volumetric_error(pts))  # not trivially zero

    # the built machine writes a file that loads back to the same model
    built.to_toml(tmp_path / "built.toml")
    again = Machine.from_toml(tmp_path / "built.toml")
    np.testing.assert_allclose(again.volumetric_error(pts), built.volumetric_error(pts), atol=1e-12)


def test_from_parts_takes_objects_and_defaults() -> None:
    volume = Volume(
        lower_mm=np.zeros(3), upper_mm=np.array([500.0, 400.0, 300.0]), reference_mm=np.zeros(3)
    )
    probe = Probe(offset_mm=np.array([0.0, 0.0, -80.0]))
    m = Machine.from_parts(model="FB1", volume=volume, probe=probe)
    assert m.model == "FB1" and not m.tables
    np.testing.assert_array_equal(m.volumetric_error([[100.0, 100.0, 100.0]]), [[0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(m.probe.offset_mm, [0.0, 0.0, -80.0])


def test_parametric_errors_reject_bad_names_and_duplicates() -> None:
    with pytest.raises(ValueError, match="unknown error component 'dq_x'"):
        ParametricErrors.from_polynomials({"dq_x": [0.0]})
    with pytest.raises(ValueError, match="given twice"):
        ParametricErrors.from_polynomials({"dx_x": [0.0], "EXX": [1.0]})
    with pytest.raises(ValueError, match="squareness goes in squareness_urad"):
        ParametricErrors.from_polynomials({"alpha": [1.0]})
    with pytest.raises(ValueError, match="errors given twice: dx_x"):
        ParametricErrors.from_polynomials({"dx_x": [0.0]}).combined(
            ParametricErrors.from_tables({"dx_x": ([0, 1], [0, 1])})
        )
    # problems only the full check sees come back as the file's errors would
    with pytest.raises(MachineFileError, match=r"<python>: errors\.dx_x\.position"):
        Machine.from_parts(
            model="MB1",
            volume=[(0, 1), (0, 1), (0, 1)],
            errors=ParametricErrors.from_tables({"dx_x": ([0, 2, 1], [0, 1, 2])}),
        )


# ----------------------------------------------------------------------------- model names
def test_model_aliases_and_descriptions() -> None:
    assert model_code("moving_bridge") == "MB1"
    assert model_code("Moving-Bridge") == "MB1"
    assert model_code("MB1") == "MB1"
    assert model_code("fixed_horizontal_arm_y") == "FH2"
    assert model_code("no such model") is None
    table = model_table().splitlines()
    assert [line.split()[0] for line in table] == list(MODEL_CHAINS)
    assert len({line.split()[1] for line in table}) == 10  # one alias each, all different
    for code in MODEL_CHAINS:
        line = describe_model(code)
        assert line.startswith(code) and "\n" not in line
        assert MODEL_CHAINS[code].describe() in line
    assert describe_model("moving_bridge") == describe_model("MB1")
    with pytest.raises(ValueError, match=r"unknown model 'XX9'.*MB1/moving_bridge"):
        describe_model("XX9")


def test_toml_accepts_alias_and_keeps_the_code() -> None:
    base = {"name": "m", "volume": {"x": [0, 1], "y": [0, 1], "z": [0, 1]}}
    by_alias = Machine.from_dict({**base, "model": "column_y"})
    assert by_alias.model == "CY1" and by_alias.description["model"] == "CY1"
    assert by_alias.chain == MODEL_CHAINS["CY1"]
    with pytest.raises(MachineFileError, match=r"unknown model 'bridge'.*MB1/moving_bridge"):
        Machine.from_dict({**base, "model": "bridge"})
