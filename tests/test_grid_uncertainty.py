"""A correction grid carrying U (issue 13, item 4): interpolated U, the versioned file, old files,
signatures, statuses, and the untouched correction path.

Oracles: U of off-node points and styli against first-order propagation written out in
test_uncertainty_mc.py (not the grid's covariance formula); the file's SHA-256 and signature
recomputed from the archive members with hashlib and ``cryptography`` (docs/formats.md §7); a
version-1 file written by the pre-uncertainty writer (tests/data/grid_v1_analytic.md).
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import load_pem_public_key
from test_uncertainty_mc import _first_order_u, _machine_with_everything

from cmm_comp.compensation import Machine
from cmm_comp.compensation.grid import (
    CorrectionGrid,
    GridFileError,
    GridSignatureError,
    generate_signing_key,
    sign_grid,
)
from cmm_comp.compensation.grid.field import AnalyticErrorField
from cmm_comp.compensation.grid.file import read_grid_contents, write_grid_members
from cmm_comp.compensation.grid.signing import load_public_key, verify_signature
from cmm_comp.compensation.grid.uncertainty import GridUncertainty
from cmm_comp.compensation.uncertainty.grid_field import add_uncertainty

DATA = Path(__file__).resolve().parent / "data"
TRIALS = 3000
TEMPS = {"T_x": 23.0, "T_y": 17.5, "T_wp": 24.0}


@pytest.fixture(scope="module")
def machine() -> Machine:
    return _machine_with_everything()


@pytest.fixture(scope="module")
def plain(machine: Machine) -> CorrectionGrid:
    return CorrectionGrid.build(machine, steps=(7, 6, 5))


@pytest.fixture(scope="module")
def with_u(plain: CorrectionGrid, machine: Machine) -> CorrectionGrid:
    return add_uncertainty(plain, machine, rng=np.random.default_rng(8), seed=8, trials=TRIALS)


def test_interpolated_U_matches_first_order_at_any_point_and_stylus(
    with_u: CorrectionGrid, machine: Machine
) -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(machine.volume.lower_mm, machine.volume.upper_mm, (12, 3))
    for stylus in (np.array([0.0, 0.0, -100.0]), np.array([60.0, -45.0, -210.0])):
        _, status, u_grid = with_u.correct_with_uncertainty(pts, stylus, TEMPS)
        assert np.all(status == "ok")
        oracle = 2.0 * _first_order_u(machine, pts, np.broadcast_to(stylus, pts.shape), TEMPS)
        # Monte Carlo at the nodes: 4 standard errors of a u from TRIALS; plus interpolation
        tol = 4.0 / np.sqrt(2 * (TRIALS - 1)) + 0.02
        assert np.all(np.abs(u_grid / oracle - 1.0) < tol), u_grid / oracle
    single, st = with_u.uncertainty_point(pts[3], stylus, TEMPS)
    assert st == "ok" and np.allclose(single, u_grid[3], rtol=1e-12)


def test_correction_is_untouched_by_carrying_U(
    plain: CorrectionGrid, with_u: CorrectionGrid
) -> None:
    pts = np.random.default_rng(1).uniform(plain.lower_mm, plain.upper_mm, (300, 3))
    a, sa = plain.correct(pts, (0, 0, -100), TEMPS)
    b, sb, _ = with_u.correct_with_uncertainty(pts, (0, 0, -100), TEMPS)
    c, sc = with_u.correct(pts, (0, 0, -100), TEMPS)
    assert np.array_equal(a, b) and np.array_equal(a, c)
    assert list(sa) == list(sb) == list(sc)
    assert plain.correct_point(pts[0], (0, 0, -100), TEMPS) == with_u.correct_point(
        pts[0], (0, 0, -100), TEMPS
    )
    assert len(with_u.correct(pts[:1], (0, 0, -100), TEMPS)) == 2  # U only when asked by name
    with pytest.raises(TypeError, match="with_uncertainty"):
        with_u.correct(pts, (0, 0, -100), TEMPS, with_uncertainty=True)  # type: ignore[call-arg]


def test_U_is_nan_unless_the_status_is_ok(plain: CorrectionGrid, with_u: CorrectionGrid) -> None:
    pts = np.array([[100, 100, 100], [np.nan, 0, 0], [5000, 0, 0], [100, 100, 100.0]])
    temps = {"T_x": np.array([20.0, 20.0, 20.0, np.nan]), "T_y": 20.0, "T_wp": 20.0}
    _, status, u = with_u.correct_with_uncertainty(pts, (0, 0, -100), temps)
    assert list(status) == ["ok", "invalid_input", "outside_volume", "no_temperature"]
    assert np.all(np.isfinite(u[0])) and np.all(np.isnan(u[1:]))
    _, status, u = with_u.correct_with_uncertainty(pts, (0, 0, -100), temps, outside="clamp")
    assert status[2] == "clamped_outside_volume" and np.all(np.isnan(u[2]))
    scalars = {"T_x": 20.0, "T_y": 20.0, "T_wp": 20.0}
    _, _, none = plain.correct_with_uncertainty(pts[:1], (0, 0, -100), scalars)
    assert not plain.has_uncertainty and np.all(np.isnan(none))
    u_plain, st = plain.uncertainty_point(pts[0], (0, 0, -100), scalars)
    assert st == "ok" and np.all(np.isnan(u_plain))
    assert not with_u.with_uncertainty(None).has_uncertainty
    u_bad, st = with_u.uncertainty_point(pts[1], (0, 0, 0), scalars)
    assert st == "invalid_input" and np.all(np.isnan(u_bad))
    u_warm, st = with_u.uncertainty_point(pts[0], (0, 0, -100), {**scalars, "T_x": None})
    assert st == "no_temperature" and np.all(np.isnan(u_warm))


def test_file_round_trip_is_version_2_and_hashes_the_U_member(
    with_u: CorrectionGrid, tmp_path: Path
) -> None:
    path = tmp_path / "u.grid"
    sha = with_u.save(path)
    loaded = CorrectionGrid.load(path)
    assert loaded.sha256 == sha and loaded.has_uncertainty
    pts = np.random.default_rng(2).uniform(with_u.lower_mm, with_u.upper_mm, (40, 3))
    _, _, u0 = with_u.correct_with_uncertainty(pts, (0, 0, -100), TEMPS)
    _, _, u1 = loaded.correct_with_uncertainty(pts, (0, 0, -100), TEMPS)
    assert np.array_equal(u0, u1)
    with zipfile.ZipFile(path) as zf:
        members = {n.removesuffix(".npy"): np.load(io.BytesIO(zf.read(n))) for n in zf.namelist()}
    header = json.loads(members["header"].tobytes())
    assert header["format_version"] == 2
    assert members["uncertainty_covariance"].shape == (*with_u.steps, 15)
    u_head = header["uncertainty"]
    assert u_head["coverage_factor"] == 2.0 and u_head["trials"] == TRIALS and u_head["seed"] == 8
    assert "defaulted" in u_head and u_head["machine_sha256"] == header["machine"]["sha256"]
    # the SHA-256 of docs/formats.md §7, recomputed here, covers the U member
    digest = hashlib.sha256()
    for name in sorted(n for n in members if n not in ("header", "sha256", "signature")):
        arr = np.ascontiguousarray(members[name])
        digest.update(name.encode() + arr.dtype.str.encode() + repr(arr.shape).encode())
        digest.update(arr.tobytes())
    digest.update(members["header"].tobytes())
    assert digest.hexdigest() == members["sha256"].tobytes().decode()
    # one flipped byte in the U member is caught
    with zipfile.ZipFile(path) as zf:
        raw = {n: zf.read(n) for n in zf.namelist()}
    cov = bytearray(raw["uncertainty_covariance.npy"])
    cov[-3] ^= 0x10
    raw["uncertainty_covariance.npy"] = bytes(cov)
    bad = tmp_path / "bad.grid"
    with zipfile.ZipFile(bad, "w") as zf:
        for n, b in raw.items():
            zf.writestr(n, b)
    with pytest.raises(GridFileError, match=r"bad\.grid: SHA-256 mismatch"):
        CorrectionGrid.load(bad)
    # the U member stripped (SHA-256 recomputed): version 2 without it is refused
    c = read_grid_contents(path)
    arrays = {k: v for k, v in c.arrays.items() if k != "uncertainty_covariance"}
    write_grid_members(tmp_path / "strip.grid", c.header_bytes, arrays, "0" * 64, None)
    with pytest.raises(GridFileError, match="version 2 needs the uncertainty member"):
        CorrectionGrid.load(tmp_path / "strip.grid")


def test_a_grid_without_U_is_still_written_as_version_1(
    plain: CorrectionGrid, tmp_path: Path
) -> None:
    plain.save(tmp_path / "p.grid")
    with np.load(tmp_path / "p.grid", allow_pickle=False) as npz:
        assert "uncertainty_covariance" not in npz.files
        assert json.loads(npz["header"].tobytes())["format_version"] == 1


def test_the_old_version_1_file_still_loads_and_corrects() -> None:
    old = CorrectionGrid.load(DATA / "grid_v1_analytic.grid")
    assert old.sha256 == "64920c99317020ef15a1398a286c8d7df80823087ff851cc07582d0a1ca8bdcb"
    assert not old.has_uncertainty
    now = CorrectionGrid.build(AnalyticErrorField(), steps=(4, 5, 4))
    pts = np.random.default_rng(3).uniform(now.lower_mm, now.upper_mm, (50, 3))
    temps = {"T_x": 22.0, "T_top": 19.0}
    assert np.array_equal(
        old.correct(pts, (0, 0, -80), temps)[0], now.correct(pts, (0, 0, -80), temps)[0]
    )


def test_signed_grid_with_U_verifies_and_a_U_edit_breaks_the_signature(
    with_u: CorrectionGrid, tmp_path: Path
) -> None:
    path = tmp_path / "s.grid"
    with_u.save(path)
    private, public = generate_signing_key(tmp_path / "keys")
    sign_grid(path, private)
    c = read_grid_contents(path)
    assert "uncertainty_covariance" in c.arrays
    sig = json.loads(c.signature or b"{}")
    key = load_pem_public_key(public.read_bytes())
    assert isinstance(key, Ed25519PublicKey)
    key.verify(  # independent of the project's verifier
        bytes.fromhex(sig["signature"]),
        b"cmm-comp grid signature v1\n" + c.sha256.encode() + b"\n" + c.header_bytes,
    )
    verify_signature(c, load_public_key(public))
    # an attacker halves U and recomputes the SHA-256: the signature no longer verifies
    arrays = dict(c.arrays)
    arrays["uncertainty_covariance"] = arrays["uncertainty_covariance"] * 0.25
    digest = hashlib.sha256()
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        digest.update(name.encode() + arr.dtype.str.encode() + repr(arr.shape).encode())
        digest.update(arr.tobytes())
    digest.update(c.header_bytes)
    write_grid_members(path, c.header_bytes, arrays, digest.hexdigest(), c.signature)
    edited = read_grid_contents(path)  # integrity alone is fine …
    with pytest.raises(GridSignatureError, match="changed after signing"):
        verify_signature(edited, load_public_key(public))  # … origin is not


def test_grid_with_U_pickles(with_u: CorrectionGrid) -> None:
    again = pickle.loads(pickle.dumps(with_u))
    pts = np.array([[100.0, 200.0, 300.0]])
    assert np.array_equal(
        again.correct_with_uncertainty(pts, (0, 0, 0), TEMPS)[2],
        with_u.correct_with_uncertainty(pts, (0, 0, 0), TEMPS)[2],
    )


def test_bad_uncertainty_data_is_refused(with_u: CorrectionGrid, tmp_path: Path) -> None:
    gu = with_u.uncertainty
    assert gu is not None
    cov = gu.covariance.copy()
    cov[0, 0, 0, 4] = np.nan
    with pytest.raises(ValueError, match="must be finite"):
        GridUncertainty(cov, gu.probe_um, gu.thermal)
    cov = gu.covariance.copy()
    cov[1, 1, 1, 0] = -1.0
    with pytest.raises(ValueError, match="variances must be ≥ 0"):
        GridUncertainty(cov, gu.probe_um, gu.thermal)
    with pytest.raises(ValueError, match="probe_um"):
        GridUncertainty(gu.covariance, float("inf"), gu.thermal)
    with pytest.raises(ValueError, match="nodes"):
        with_u.with_uncertainty(GridUncertainty(gu.covariance[:-1], gu.probe_um, gu.thermal))
    # a header whose covariance layout is not this version's: one GridFileError line
    path = tmp_path / "u.grid"
    with_u.save(path)
    c = read_grid_contents(path)
    header = dict(c.header)
    header["uncertainty"] = {**header["uncertainty"], "covariance_components": ["a", "b"]}
    header_bytes = json.dumps(header, sort_keys=True, indent=1).encode()
    from cmm_comp.compensation.grid.file import payload_sha256

    write_grid_members(path, header_bytes, c.arrays, payload_sha256(c.arrays, header_bytes), None)
    with pytest.raises(GridFileError, match=r"invalid grid content.*covariance_components"):
        CorrectionGrid.load(path)


def test_compiled_U_equals_the_numpy_formulas(with_u: CorrectionGrid) -> None:
    """The compiled batch and single-reading paths against the same rule written in numpy
    (``variance_from_covariance``, ``ThermalUncertainty.variance_um2``): per point styli and
    temperatures."""
    from cmm_comp.compensation.grid.uncertainty import eval_spline, variance_from_covariance

    gu = with_u.uncertainty
    assert gu is not None
    rng = np.random.default_rng(4)
    n = 300
    pts = rng.uniform(with_u.lower_mm, with_u.upper_mm, (n, 3))
    sty = rng.normal(0.0, 80.0, (n, 3))
    temps = {"T_x": rng.uniform(17, 25, n), "T_y": 21.0, "T_wp": rng.uniform(18, 24, n)}
    _, status, u = with_u.correct_with_uncertainty(pts, sty, temps)
    assert np.all(status == "ok")
    cov = np.empty((n, 15))
    tables = tuple(with_u.kernel_tables.spline)
    eval_spline(pts, tables, gu.coefficients(with_u.axes), cov)
    full = {k: np.broadcast_to(np.asarray(v, float), (n,)) for k, v in temps.items()}
    var = variance_from_covariance(cov, sty) + gu.thermal.variance_um2(pts, full) + gu.probe_um**2
    assert np.allclose(u, 2.0 * np.sqrt(var), rtol=1e-12, atol=1e-12)
    for i in range(0, n, 37):
        one = {k: float(np.broadcast_to(v, (n,))[i]) for k, v in temps.items()}
        single, st = with_u.uncertainty_point(pts[i], sty[i], None, one)  # temperatures as inputs
        assert st == "ok" and np.allclose(single, u[i], rtol=1e-12)
