"""daemon: the compensation daemon that runs beside a CMM controller.

Loads a correction grid, receives raw scale readings over CAN (any python-can interface) or
Modbus TCP together with temperatures, answers corrected coordinates with a status at once, and
logs every message to MCAP off the hot path (:mod:`.sessionlog`). ``cmm-comp daemon --config daemon.toml``.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
