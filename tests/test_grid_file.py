"""Grid file: round trip, and one clear GridFileError for every kind of bad file."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation.grid import CorrectionGrid, GridFileError
from cmm_comp.compensation.grid.field import AnalyticErrorField


@pytest.fixture(scope="module")
def field() -> AnalyticErrorField:
    return AnalyticErrorField()


@pytest.fixture(scope="module")
def grid(field: AnalyticErrorField) -> CorrectionGrid:
    return CorrectionGrid.build(field, steps=(6, 5, 4))


def test_round_trip_is_exact_and_self_describing(grid: CorrectionGrid, tmp_path: Path) -> None:
    path = tmp_path / "m.grid"
    sha = grid.save(path)
    loaded = CorrectionGrid.load(path)
    assert loaded.sha256 == sha
    np.testing.assert_array_equal(loaded.q_work_stylus, grid.q_work_stylus)
    np.testing.assert_array_equal(loaded.sensitivity_rotation_urad, grid.sensitivity_rotation_urad)
    pts = np.random.default_rng(0).uniform(grid.lower_mm, grid.upper_mm, (50, 3))
    temps = {"T_x": 23.0, "T_top": 18.0}
    np.testing.assert_array_equal(
        loaded.correct(pts, (0, 0, -100), temps)[0], grid.correct(pts, (0, 0, -100), temps)[0]
    )
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(npz["header"].tobytes())
    assert header["format"] == "cmm-grid" and header["format_version"] == 1
    assert header["machine"]["name"] == "analytic"
    assert header["steps"] == [6, 5, 4]
    assert {s["name"] for s in header["signals"]} == {"T_x", "T_top"}
    for key in ("units", "reference_C", "stylus_convention", "built_utc", "library_version"):
        assert key in header
    assert loaded.header()["built_utc"] == header["built_utc"]


def test_expect_machine(grid: CorrectionGrid, field: AnalyticErrorField, tmp_path: Path) -> None:
    path = tmp_path / "m.grid"
    grid.save(path)
    CorrectionGrid.load(path, expect_machine=field)
    other = AnalyticErrorField(rotation_urad=31.0)
    with pytest.raises(GridFileError, match=r"m\.grid: grid was built for machine 'analytic'"):
        CorrectionGrid.load(path, expect_machine=other)
    with pytest.raises(GridFileError, match="rebuild the grid"):
        CorrectionGrid.load(path, expect_machine="0" * 64)


def test_truncated_and_corrupt_files(grid: CorrectionGrid, tmp_path: Path) -> None:
    path = tmp_path / "m.grid"
    grid.save(path)
    data = path.read_bytes()
    trunc = tmp_path / "trunc.grid"
    trunc.write_bytes(data[: len(data) // 2])
    with pytest.raises(GridFileError, match=r"trunc\.grid: not a readable grid file"):
        CorrectionGrid.load(trunc)
    # flip one byte inside the stored translation array: checksum must catch it
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    raw = bytearray(members["translation_um.npy"])
    raw[-5] ^= 0x40
    members["translation_um.npy"] = bytes(raw)
    bad = tmp_path / "bad.grid"
    with zipfile.ZipFile(bad, "w") as zf:
        for n, b in members.items():
            zf.writestr(n, b)
    with pytest.raises(GridFileError, match=r"bad\.grid: SHA-256 mismatch"):
        CorrectionGrid.load(bad)
    with pytest.raises(GridFileError, match="no such grid file"):
        CorrectionGrid.load(tmp_path / "absent.grid")
    junk = tmp_path / "junk.grid"
    junk.write_text("hello")
    with pytest.raises(GridFileError, match=r"junk\.grid"):
        CorrectionGrid.load(junk)


def _rewrite_header(src: Path, dst: Path, **changes: object) -> None:
    with zipfile.ZipFile(src) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    with np.load(src, allow_pickle=False) as npz:
        header = json.loads(npz["header"].tobytes())
    header.update(changes)
    import io

    buf = io.BytesIO()
    np.save(buf, np.frombuffer(json.dumps(header).encode(), dtype=np.uint8))
    members["header.npy"] = buf.getvalue()
    with zipfile.ZipFile(dst, "w") as zf:
        for n, b in members.items():
            zf.writestr(n, b)


def test_wrong_version_and_format(grid: CorrectionGrid, tmp_path: Path) -> None:
    path = tmp_path / "m.grid"
    grid.save(path)
    v3 = tmp_path / "v3.grid"
    _rewrite_header(path, v3, format_version=3)
    with pytest.raises(GridFileError, match=r"v3\.grid: unsupported grid format version 3"):
        CorrectionGrid.load(v3)
    v2 = tmp_path / "v2.grid"  # version 2 is a grid carrying U: its members must be there
    _rewrite_header(path, v2, format_version=2)
    with pytest.raises(
        GridFileError, match=r"v2\.grid: grid format version 2 needs the uncertainty"
    ):
        CorrectionGrid.load(v2)
    other = tmp_path / "other.grid"
    _rewrite_header(path, other, format="something-else")
    with pytest.raises(GridFileError, match="not a cmm-comp grid"):
        CorrectionGrid.load(other)
    edited = tmp_path / "edited.grid"
    _rewrite_header(path, edited, steps=[6, 5, 4], outside_policy="clamp")
    with pytest.raises(GridFileError, match="SHA-256 mismatch"):
        CorrectionGrid.load(edited)


def test_no_pickle_objects_are_ever_loaded(grid: CorrectionGrid, tmp_path: Path) -> None:
    path = tmp_path / "m.grid"
    grid.save(path)
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    import io

    buf = io.BytesIO()
    np.save(buf, np.array([{"evil": 1}], dtype=object), allow_pickle=True)
    members["q_work_stylus.npy"] = buf.getvalue()
    bad = tmp_path / "pickle.grid"
    with zipfile.ZipFile(bad, "w") as zf:
        for n, b in members.items():
            zf.writestr(n, b)
    with pytest.raises(GridFileError, match=r"pickle\.grid"):
        CorrectionGrid.load(bad)


def test_save_is_atomic(
    grid: CorrectionGrid, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "m.grid"
    grid.save(path)
    before = path.read_bytes()

    def boom(*args: object, **kwargs: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(OSError, match="disk full"):
        grid.save(path)
    assert path.read_bytes() == before  # the old grid is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.grid"]  # no temp file left
