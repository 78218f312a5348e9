"""What people look at: volumetric maps, diagonals and line reports (:mod:`.maps`), PNG plots
(:mod:`.plots`), ISO 230-2 evaluation (:mod:`.iso230`) and the 6-DOF capture of node poses
(:mod:`.sixdof`). Units: positions mm, errors µm, angles µrad.

The plot and 6-DOF names are imported on first use (they pull in matplotlib and the grid's
numba kernels), so ``import cmm_comp.compensation`` stays light.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
