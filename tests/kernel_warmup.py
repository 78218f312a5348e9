"""The project's numba kernels compiled once per checkout, split between pytest-xdist's workers.

numba caches a kernel's compiled code on disk (in the sources' ``__pycache__`` of an editable
install) when a process first compiles it; on a fresh checkout (CI) every worker would otherwise
compile the same kernels side by side before either has written them. :func:`warm_up` runs two
groups of public calls that between them compile every kernel (the grid's, and the virtual
CMM's chain kernels), each group under its own exclusive lock file: a worker starts with the
group its index names and then takes the other, so two workers compile the two groups at once,
and a group a worker reaches after another has compiled it loads from numba's cache in a
fraction of a second. A worker holds one lock at a time: no deadlock. Fresh cache, measured on
this machine at load ~4: ~25 s of CPU for the grid kernels, ~4 s for the chain kernels; the
grid's kernels are one group because its batch kernels call the serial ones (split across two
workers they were compiled twice: 36 s of CPU instead of 25, no shorter wall).
"""

from __future__ import annotations

import fcntl
import hashlib
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["GROUPS", "warm_up"]

ROOT = Path(__file__).resolve().parents[1]
NPL_GRID = ROOT / "tests" / "data" / "grid_golden_npl.grid"
NPL_MACHINE = ROOT / "examples" / "machines" / "npl-bridge.toml"


def _grid_inputs() -> tuple:
    import numpy as np

    from cmm_comp.compensation import CorrectionGrid

    grid = CorrectionGrid.load(NPL_GRID)
    rng = np.random.default_rng(0)
    n = 2 * 256  # from PARALLEL_MIN points on, the batch runs the thread-pool kernel
    pts = grid.lower_mm + rng.random((n, 3)) * (grid.upper_mm - grid.lower_mm)
    temps = {s.name: 20.0 for s in grid.signals}
    return grid, pts, temps


def _grid() -> None:
    """Loading a grid, correcting a few points (serial and quaternion kernels), a batch with U
    past the thread-pool threshold (parallel and uncertainty kernels), U of a few points and of
    one point (serial uncertainty kernels). One group: the batch kernels call the serial ones
    (compiled in two processes at once they would be compiled twice)."""
    grid, pts, temps = _grid_inputs()
    _, status = grid.correct(pts[:4], (0.0, 0.0, 0.0), temps)
    assert (status == "ok").all(), "the kernels' warm-up must reach every kernel"
    for m in (len(pts), 4):
        _, status, _ = grid.correct_with_uncertainty(pts[:m], (0.0, 0.0, 0.0), temps)
        assert (status == "ok").all(), "the kernels' warm-up must reach every kernel"
    grid.uncertainty_point(pts[0], (0.0, 0.0, 0.0), temps)


def _chain() -> None:
    """A few virtual-CMM trials: the chain kernels ``cmm-comp uncertainty`` and ``grid build
    --uncertainty`` run (independent of the grid's); and the diagnosis' period-scan kernel."""
    import numpy as np

    from cmm_comp.compensation import Machine
    from cmm_comp.compensation.uncertainty.virtual_cmm import VirtualCMM

    cmm = VirtualCMM(Machine.from_toml(NPL_MACHINE))
    prep = cmm.prepare(np.array([[100.0, 200.0, -100.0], [500.0, 300.0, -200.0]]))
    rng = np.random.default_rng(0)
    next(cmm.residuals(prep, 2, rng))
    next(cmm.pose_residuals(prep, 2, rng))
    # and the diagnosis' period-scan kernel (a scan large enough to use it)
    from cmm_comp.compensation.effects.harmonic_kernel import COMPILED_FROM, harmonic_columns

    periods = tuple(np.linspace(1.0, 2.0, -(-COMPILED_FROM // 1000)))
    harmonic_columns(np.linspace(0.0, 10.0, 1000), periods, 0.0, 1)


GROUPS: tuple[tuple[str, Callable[[], None]], ...] = (("grid", _grid), ("chain", _chain))


def warm_up(worker: str) -> None:
    """Every group once, each under its lock (one per checkout and group, in the system's
    temporary folder: concurrent runs of the same checkout share its cache). A worker starts
    with the group of its index (``gw1`` → the second) and takes next whichever remaining group
    no other worker holds; only when every remaining one is held does it wait (for the first:
    then it loads that group from the cache the other worker wrote)."""
    tag = hashlib.sha256(str(ROOT).encode()).hexdigest()[:16]
    index = int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 0
    left = [GROUPS[(index + k) % len(GROUPS)] for k in range(len(GROUPS))]
    while left:
        taken = next((g for g in left if _run_locked(g, tag, wait=False)), None)
        if taken is None:
            taken = left[0]
            _run_locked(taken, tag, wait=True)
        left.remove(taken)


def _run_locked(group: tuple[str, Callable[[], None]], tag: str, *, wait: bool) -> bool:
    """Run ``group`` under its lock; False (not run) when another process holds the lock and
    ``wait`` is false."""
    name, run = group
    with open(Path(tempfile.gettempdir()) / f"cmm-comp-kernels-{tag}-{name}.lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            return False
        run()
    return True
