"""The contracts of cmm-comp with the outside world: the CAN message set and the Modbus TCP
register map with their codecs (the bus), and the session log's topics (the file every reader
of a session gets: :mod:`.session_topics`).

Pure codecs and contracts only (no daemon logic). ``protocol`` imports nothing from ``daemon``
or ``sim_controller``. See docs/can.md, docs/modbus.md and docs/formats.md §6.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
