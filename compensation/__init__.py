"""compensation: the parametric volumetric error model of a CMM and its correction grid.

Fixed entry points (docs/formats.md §5)::

    from cmm_comp.compensation import Machine, CorrectionGrid
    machine = Machine.from_toml("machine.toml")
    err_um = machine.volumetric_error(points_mm, temps_C=None)  # stylus: machine.probe.offset_mm

or in Python, without a file::

    errors = ParametricErrors.from_polynomials({"dx_x": [0.0, 2e-3], "ez_x": [0.0, 0.0, 1e-5]})
    machine = Machine.from_parts(model="moving_bridge", volume=[(0, 900), (0, 1150), (0, 400)],
                                 errors=errors, probe=(0, 0, -120))

Every function taking ``stylus_mm`` defaults it to the machine's probe offset. The ten models:
:func:`model_table`, :func:`describe_model` (``"MB1"`` ↔ ``"moving_bridge"``).

Units: positions mm, linear errors µm, angles µrad, temperatures °C; error = true − indicated.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
