"""Session logs read back, offline: the other side of :mod:`cmm_comp.daemon.sessionlog`,
which writes them. Nothing here runs in the daemon's processes; the commands
(``cmm-comp daemon replay``, ``cmm-comp mcap recover``, ``cmm-comp fleet replay``) and the
tests use it.

* :mod:`.reader` - read sessions back (rolled sets, files cut by a crash);
* :mod:`.recover` - rewrite a file cut by a crash as a complete, indexed file;
* :mod:`.replay` - re-correct a session offline, or re-send what the controller sent to a bus.

See docs/mcap.md.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
