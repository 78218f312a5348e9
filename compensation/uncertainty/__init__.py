"""uncertainty: every corrected point with its uncertainty — a virtual CMM after ISO/TS 15530-4,
evaluated by the Monte Carlo method of JCGM 101 (docs/uncertainty.md).

* :mod:`.model` — the ``[uncertainty]`` section of ``machine.toml``, defaults resolved and flagged;
* :mod:`.fields` — a table's calibration error as one smooth random function along its axis;
* :mod:`.virtual_cmm` — whole virtual machines drawn from the model, vectorised over trials;
* :mod:`.adaptive` — JCGM 101 statistics and the adaptive number of trials (§7.9);
* :mod:`.tasks` — U of corrected points; lengths, the E0 test, sphere centres, flatness;
* :mod:`.gum` — first-order (GUM) propagation, the Monte Carlo's analytic counterpart;
* :mod:`.grid_field` — U at the nodes of a correction grid (carried into the grid file);
* :mod:`.plots` — U over the volume and histograms of the Monte Carlo outputs (PNG).

Every function that draws takes an explicit ``rng: numpy.random.Generator``. Units: positions
mm, residuals and uncertainties µm, angles µrad, temperatures °C. Residual = true − corrected.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# the machine parser can read the model without importing the Monte Carlo machinery.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
