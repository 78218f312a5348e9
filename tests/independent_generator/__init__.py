"""An independent session generator for the discovery benchmark (issue 11, item 3).

Written apart from the diagnosis' candidate code: every hidden effect is a physical forward model
(bending beams, twisting bridges, lagging structures, ...) pushed through this package's own
first-order rigid-body chain (:mod:`.chains`), never the diagnosis' design matrices.

Modules:

* :mod:`.chains`   - first-order kinematic chain of the ten models (µm from µm / µrad, mm arms);
* :mod:`.effects`  - hidden effects with random shape variants and the identity to be named;
* :mod:`.machines` - random nominal machine descriptions (dicts for ``Machine.from_dict``);
* :mod:`.sessions` - session designs producing ``Measurements`` (points, styli, temperatures);
* :mod:`.scoring`  - case drawing, diagnosis and the naming rule.

Importable as ``independent_generator`` with ``tests/`` on ``sys.path`` (pytest's rootdir
conftest puts it there; the benchmark inserts it).

Units everywhere: positions mm, linear errors µm, angles µrad, temperatures °C, time s.
Error convention (docs/conventions.md): error = true − indicated.
"""
