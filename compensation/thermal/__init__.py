"""thermal: every thermal term of the model, in one place.

* :mod:`.roles` — the temperature role names (``T_x`` … ``T_air``), defined once;
* :mod:`.expansion` — the machine's scale and workpiece expansion (:class:`Thermal`) and the
  effects that correct it;
* :mod:`.distortion` — bending with a temperature gradient, squareness drift;
* :mod:`.lag` — the first-order lag filter, the thermal-lag effect and the typed
  :class:`SignalFilter` contract the grid writes and the daemon applies.

The role names import nothing else (the daemon's configuration and the CLI read them without
numpy); the terms are imported on first use. Units: temperatures °C, expansion µm/(m·°C), angles µrad, time s.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
