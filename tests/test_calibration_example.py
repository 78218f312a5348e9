"""The worked example of docs/calibration.md, run exactly as the page prints it (each line of its
first ``bash`` block, in a fresh folder holding a copy of ``examples/``, through the CLI's own
``main()`` in this process: what the installed script calls), and the example's data regenerated
bit for bit by ``examples/calibration/generate.py``. The page's two ``calibrate`` lines are the
README's too: they run once per test run (tests/worked_example.py) and their outputs are copied
here. This is the test that checks the calibration report's figures (the other calibrations of
the suite pass ``--no-figures``).

Oracles independent of the calibration code: the truth the example was simulated from
(``truth.toml``, through the public machine API), the grid file read back by the daemon's own
trust checks (``daemon --check``), and the regenerated files compared byte by byte.
"""

from __future__ import annotations

import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from doc_commands import cli
from matplotlib.image import imread
from worked_example import LINES, calibrated_example, take

from cmm_comp.compensation import Machine

sys.path.insert(0, str(Path(__file__).resolve().parent))
from calibration_sim import rigid_free

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "calibration.md"
EXAMPLE = ROOT / "examples" / "calibration"


def _commands() -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    start = text.index("```bash\n") + len("```bash\n")
    block = text[start : text.index("```", start)]
    return [line for line in block.splitlines() if line.strip() and not line.startswith("#")]


@pytest.mark.timeout(900)
def test_worked_example_runs_as_printed(
    tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
) -> None:
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    # the one change to what the page runs: the copied daemon.toml's metrics port 9108 becomes
    # 0 (any free port), so another test's daemon on this host cannot make --check fail with
    # "Address already in use" (tests run in parallel: tests/README.md)
    cfg = tmp_path / "examples" / "daemon.toml"
    text = cfg.read_text(encoding="utf-8")
    assert "\nport = 9108\n" in text
    cfg.write_text(text.replace("\nport = 9108\n", "\nport = 0\n"), encoding="utf-8")
    commands = _commands()
    assert commands[0].startswith("cmm-comp calibrate examples/calibration/calibration.toml")
    for line in commands:
        argv = shlex.split(line)
        assert argv[0] == "cmm-comp"
        if line in LINES:  # run once per test run (the README prints it too): its outputs
            shared = take(line, calibrated_example(tmp_path_factory), tmp_path)
            assert shared["code"] == 0, f"{line}\n{shared['err']}"
            continue
        proc = cli(*argv[1:], cwd=tmp_path)
        assert proc.returncode == 0, f"{line}\n{proc.stdout}\n{proc.stderr}"
    # the daemon accepted the signed grid of the calibrated machine
    assert "ok; grid machine.grid" in proc.stdout
    report = json.loads((tmp_path / "calibration-report" / "calibration.json").read_text())
    # the report's figures: each decodes (Pillow) to a real image and the page shows it
    page = (tmp_path / "calibration-report" / "index.html").read_text()
    for png in ("errors.png", "residuals.png", "volumetric_u.png"):
        image = imread(tmp_path / "calibration-report" / png)
        assert image.ndim == 3 and min(image.shape[:2]) > 100, png
        assert f'src="{png}"' in page, png
    assert report["checks"]["resimulation"]["max_abs"] < 1e-9
    # the identified machine against the machine the data were simulated from
    machine = Machine.from_toml(tmp_path / "machine.toml")
    truth = Machine.from_toml(EXAMPLE / "truth.toml")
    data = np.loadtxt(
        tmp_path / "calibration-report" / "volumetric_u.csv", delimiter=",", skiprows=1
    )
    q = data[:, :3]
    mine = machine.volumetric_error(q, machine.probe.offset_mm)
    np.testing.assert_allclose(mine, data[:, 3:6], atol=2e-6)  # the CSV is the machine's
    diff = rigid_free(q, mine - truth.volumetric_error(q, machine.probe.offset_mm))
    true = rigid_free(q, truth.volumetric_error(q, machine.probe.offset_mm))
    assert np.sqrt(np.mean(diff**2)) < 0.2 * np.sqrt(np.mean(true**2))
    assert np.mean(np.abs(diff) <= data[:, 6:9]) > 0.8
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert 0 < max(plan["volumetric_U_um"]["max_um"]) < 5 * max(report["volumetric_U_um"]["max_um"])


def test_example_data_regenerate_bit_for_bit(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, str(EXAMPLE / "generate.py"), str(tmp_path)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    for name in (
        "calibration.toml",
        "laser.csv",
        "plate.toml",
        "plate.csv",
        "trac.csv",
        "truth.toml",
    ):
        assert (tmp_path / name).read_bytes() == (EXAMPLE / name).read_bytes(), name
