"""The ``[uncertainty]`` section (docs/formats.md §1.11): values, defaults and their flags, bad
input as one line; and the calibration random function's correlation.

Oracles: the documented defaults and precedence rules, read from the docs' tables (not from the
parser's constants); the squared-exponential correlation exp(−Δ²/2ℓ²) written out here, against
the Karhunen–Loève features and against the sample covariance of draws.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cmm_comp.compensation import Machine, MachineFileError
from cmm_comp.compensation.uncertainty import squared_exponential_basis

ROOT = Path(__file__).resolve().parents[1]
NPL = ROOT / "examples" / "machines" / "npl-bridge.toml"


def _small(uncertainty: dict[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "name": "u-test",
        "model": "MB1",
        "volume": {"x": [0.0, 600.0], "y": [0.0, 500.0], "z": [0.0, 400.0]},
        "thermal": {"expansion": {"x": 11.5, "y": 0.0, "z": 10.0}},
        "errors": {
            "dx_x": {"position": [0.0, 200.0, 400.0, 600.0], "value": [0.0, 1.0, 1.5, 2.0]},
            "EBX": {"polynomial": [0.0, 0.004]},
            "dy_x": {"position": [0.0, 300.0, 600.0], "value": [0.0, 1.0, 0.0]},
        },
        **extra,
    }
    if uncertainty is not None:
        data["uncertainty"] = uncertainty
    return data


def test_defaults_are_the_documented_ones_and_each_is_flagged() -> None:
    m = Machine.from_dict(_small())
    u = m.uncertainty_model()
    # docs/uncertainty.md, "Defaults": positional 0.2 µm + 0.5 µm/m; angular 0.3 µrad,
    # 0.06 µrad/m, 0.12 %; straightness 0.3 µm, 0.1 µm/m, 0.3 %
    assert (u.tables["dx_x"].u, u.tables["dx_x"].u_per_m, u.tables["dx_x"].u_relative) == (
        0.2,
        0.5,
        0.0,
    )
    assert (u.tables["ey_x"].u, u.tables["ey_x"].u_per_m, u.tables["ey_x"].u_relative) == (
        0.3,
        0.06,
        0.0012,
    )
    assert u.tables["dy_x"].u_relative == 0.003
    # correlation length: the mean spacing of the calibration targets, a quarter span for curves
    assert u.tables["dx_x"].correlation_mm == 200.0
    assert u.tables["dy_x"].correlation_mm == 300.0
    assert u.tables["ey_x"].correlation_mm == 150.0
    assert list(u.squareness_urad) == [1.0, 1.0, 1.0]
    # thermal: 0.1 °C sensors and 10 % of α, only for axes that have a thermal term
    assert list(u.scale_temperature_C) == [0.1, 0.0, 0.1]
    assert u.expansion[0] == pytest.approx(1.15) and u.expansion[1] == 0.0
    assert u.probe_um == 0.5
    flagged = set(u.defaulted)
    for key in (
        "uncertainty.errors.dx_x.u",
        "uncertainty.errors.ey_x.correlation_mm",
        "uncertainty.squareness.beta2",
        "uncertainty.scale_temperature_C.x",
        "uncertainty.expansion.z",
        "uncertainty.probe_um",
    ):
        assert key in flagged
    assert "uncertainty.scale_temperature_C.y" not in flagged  # no thermal term: nothing needed
    # components without a table are zero and said so
    assert "dz_z" not in u.tables
    assert any("dz_z" in note and "exactly zero" in note for note in u.notes)


def test_given_values_win_over_class_values_over_defaults_and_are_not_flagged() -> None:
    m = Machine.from_dict(
        _small(
            {
                "probe_um": 0.35,
                "squareness": 2.0,  # one number for all three
                "scale_temperature_C": {"x": 0.05},
                "expansion": 0.4,
                "angular": {"u": 0.5, "correlation_mm": 90.0},
                "errors": {
                    "EXX": {"u": 0.1, "u_per_m": 0.2, "u_relative": 0.0, "correlation_mm": 50.0},
                    "dz_z": {"u": 1.5},  # an unmeasured error: zero ± 1.5 µm
                },
            }
        )
    )
    u = m.uncertainty_model()
    t = u.tables["dx_x"]
    assert (t.u, t.u_per_m, t.u_relative, t.correlation_mm) == (0.1, 0.2, 0.0, 50.0)
    assert u.tables["ey_x"].u == 0.5 and u.tables["ey_x"].correlation_mm == 90.0
    assert u.tables["ey_x"].u_per_m == 0.06  # not in the class table: the default
    assert "uncertainty.errors.ey_x.u_per_m" in u.defaulted
    assert "uncertainty.errors.ey_x.u" not in u.defaulted
    assert u.tables["dz_z"].u == 1.5 and u.tables["dz_z"].u_per_m == 0.0
    assert u.tables["dz_z"].correlation_mm == 100.0  # quarter of z travel, flagged
    assert "uncertainty.errors.dz_z.correlation_mm" in u.defaulted
    assert list(u.squareness_urad) == [2.0, 2.0, 2.0]
    assert u.scale_temperature_C[0] == 0.05 and u.scale_temperature_C[2] == 0.1
    assert list(u.expansion) == [0.4, 0.4, 0.4]
    assert u.probe_um == 0.35
    for key in ("uncertainty.probe_um", "uncertainty.squareness.alpha", "uncertainty.expansion.x"):
        assert key not in u.defaulted


def test_probe_from_the_machine_file_is_its_2sigma_halved() -> None:
    m = Machine.from_toml(NPL)  # [probe] random_um = 0.5 (2σ)
    u = m.uncertainty_model()
    assert u.probe_um == 0.25
    assert "uncertainty.probe_um" not in u.defaulted


def test_section_round_trips_and_changes_the_machine_identity(tmp_path: Path) -> None:
    a = Machine.from_dict(_small({"probe_um": 0.3}))
    b = Machine.from_dict(_small({"probe_um": 0.4}))
    assert a.identity_sha256() != b.identity_sha256()
    a.to_toml(tmp_path / "a.toml")
    again = Machine.from_toml(tmp_path / "a.toml")
    assert again.uncertainty_model().probe_um == 0.3
    assert again.identity_sha256() == a.identity_sha256()


@pytest.mark.parametrize(
    ("section", "match"),
    [
        ({"probe_um": -0.1}, r"uncertainty\.probe_um = -0\.1; allowed: 0 \.\. 1e\+09 µm"),
        ({"probe_um": math.nan}, r"uncertainty\.probe_um = nan; allowed: 0"),
        ({"probe_um": math.inf}, r"uncertainty\.probe_um = inf; allowed: 0"),
        ({"probe_um": "0.3"}, r"uncertainty\.probe_um: '0\.3' must be a number"),
        ({"probe_um": True}, r"uncertainty\.probe_um: True must be a number"),
        ({"prob_um": 0.3}, r"unknown key uncertainty\.prob_um; allowed: angular, errors"),
        (
            {"squareness": {"gamma": 1.0}},
            r"unknown key uncertainty\.squareness\.gamma; allowed: alpha, beta1, beta2",
        ),
        ({"errors": {"dq_x": {"u": 1.0}}}, r"uncertainty\.errors\.dq_x: unknown error component"),
        ({"errors": {"dx_x": {"u": 1.0}, "EXX": {"u": 2.0}}}, r"given twice"),
        (
            {"errors": {"dx_x": {"sigma": 1.0}}},
            r"unknown key uncertainty\.errors\.dx_x\.sigma; allowed: correlation_mm",
        ),
        (
            {"errors": {"dx_x": {"correlation_mm": 0.0}}},
            r"uncertainty\.errors\.dx_x\.correlation_mm = 0\.0; allowed: > 0",
        ),
        ({"errors": {"dx_x": {"u": -1e300}}}, r"dx_x\.u = -1e\+300; allowed: 0 \.\."),
        ({"errors": {"dx_x": 3.0}}, r"\[uncertainty\.errors\.dx_x\] must be a table, got 3\.0"),
        ({"errors": 3.0}, r"uncertainty\.errors: 3\.0 must be a table"),
        ({"angular": {"u": math.nan}}, r"uncertainty\.angular\.u = nan; allowed: 0"),
    ],
)
def test_bad_sections_are_one_clear_line(section: dict[str, Any], match: str) -> None:
    with pytest.raises(MachineFileError, match=match) as info:
        Machine.from_dict(_small(section), source="m.toml")
    assert "\n" not in str(info.value)
    assert str(info.value).startswith("m.toml: ") and "uncertainty" in str(info.value)


def test_bad_section_in_a_file_names_the_file(tmp_path: Path) -> None:
    text = NPL.read_text() + "\n[uncertainty]\nprobe_um = nan\n"
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(MachineFileError, match=r"bad\.toml: uncertainty\.probe_um = nan; allowed"):
        Machine.from_toml(path)


def test_with_effects_keeps_the_section() -> None:
    m = Machine.from_dict(_small({"probe_um": 0.123}))
    copy_ = m.with_effects([])
    assert copy_.uncertainty_model().probe_um == 0.123
    assert copy.deepcopy(m).uncertainty_model().probe_um == 0.123


# ------------------------------------------------------------------ the random function


@pytest.mark.parametrize(("lo", "hi", "ell"), [(0.0, 900.0, 50.0), (-100.0, 300.0, 400.0)])
def test_features_reproduce_the_squared_exponential_correlation(
    lo: float, hi: float, ell: float
) -> None:
    basis = squared_exponential_basis(lo, hi, ell)
    q = np.random.default_rng(1).uniform(lo, hi, 60)  # off the mesh on purpose
    f = basis.features(q)
    oracle = np.exp(-0.5 * ((q[:, None] - q[None, :]) / ell) ** 2)
    assert np.abs(f @ f.T - oracle).max() < 1e-5
    assert np.allclose(np.linalg.norm(f, axis=1), 1.0)


def test_draws_have_the_stated_covariance() -> None:
    basis = squared_exponential_basis(0.0, 600.0, 120.0)
    q = np.array([0.0, 60.0, 250.0, 599.0])
    draws = basis.sample(q, 40_000, np.random.default_rng(7))
    cov = np.cov(draws, rowvar=False)
    oracle = np.exp(-0.5 * ((q[:, None] - q[None, :]) / 120.0) ** 2)
    # standard error of a sample covariance of unit-variance normals ≈ √((1 + ρ²)/M)
    se = np.sqrt((1 + oracle**2) / draws.shape[0])
    assert np.all(np.abs(cov - oracle) < 5 * se)


def test_basis_rejects_bad_spans() -> None:
    with pytest.raises(ValueError, match="correlation_mm must be finite and > 0"):
        squared_exponential_basis(0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="span must be finite"):
        squared_exponential_basis(0.0, math.inf, 1.0)
    point = squared_exponential_basis(5.0, 5.0, 1.0)  # a zero-length span: a constant
    assert np.allclose(point.features(np.array([5.0, 7.0])), 1.0)


def test_the_formats_doc_example_section_loads(tmp_path: Path) -> None:
    """docs/formats.md §1.11's example, appended to a machine, loads with the values it shows."""
    import re

    text = (ROOT / "docs" / "formats.md").read_text(encoding="utf-8")
    blocks = [b for b in re.findall(r"```toml\n(.*?)```", text, re.S) if "[uncertainty]" in b]
    assert len(blocks) == 1
    path = tmp_path / "m.toml"
    path.write_text(NPL.read_text() + "\n" + blocks[0])
    u = Machine.from_toml(path).uncertainty_model()
    assert u.probe_um == 0.25 and list(u.squareness_urad) == [1.0, 1.0, 1.5]
    assert u.tables["dx_x"].correlation_mm == 50.0 and u.tables["ex_x"].u == 0.3
    assert u.tables["dz_y"].u == 1.5 and u.workpiece_expansion == 1.2
    assert "uncertainty.probe_um" not in u.defaulted
