"""The bundled examples are executed, so they never rot."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cmm_comp.compensation import Machine, diagonals_um

ROOT = Path(__file__).resolve().parents[1]


def test_case_study_generator_reproduces_the_committed_machines(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, str(ROOT / "examples" / "generate_case_studies.py"), str(tmp_path)],
        check=True,
        capture_output=True,
        timeout=60,
    )
    for path in sorted(tmp_path.glob("*.toml")):
        committed = ROOT / "examples" / "machines" / path.name
        assert committed.read_text() == path.read_text(), (
            f"{committed} is stale: rerun the generator"
        )


@pytest.mark.parametrize(
    ("name", "model", "bandwidths"),
    [
        ("gec-mh2", "MH2", {"dx_x": 65.59, "ey_x": 74.95}),
        ("npl-bridge", "MB1", {"dx_x": 6.15, "dy_x": 3.40, "ey_x": 11.18}),
    ],
)
def test_case_studies_have_the_papers_shape(
    name: str, model: str, bandwidths: dict[str, float]
) -> None:
    """Section 6: the model, volume and the bandwidths the paper reports for these tables."""
    m = Machine.from_toml(ROOT / "examples" / "machines" / f"{name}.toml")
    assert m.model == model
    for comp, pv in bandwidths.items():
        assert np.ptp(m.tables[comp].value) == pytest.approx(pv, abs=0.01)
    assert all(np.isfinite(diagonals_um(m)))
