"""The leak detectors of conftest.py can fail: they see a live child process and thread."""

from __future__ import annotations

import subprocess
import sys

from conftest import _child_pids


def test_child_process_detector_sees_a_live_child() -> None:
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        assert proc.pid in _child_pids()
    finally:
        proc.kill()
        proc.wait()
    assert proc.pid not in _child_pids()
