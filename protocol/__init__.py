"""Bus contracts of cmm-comp: the CAN message set, the Modbus TCP register map, their codecs.

Pure codecs and contracts only (no daemon logic). ``protocol`` imports nothing from ``daemon``
or ``sim_controller``. See docs/can.md and docs/modbus.md.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
