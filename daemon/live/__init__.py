"""The live view: the daemon's session-log topics and a 3-D scene of the corrections, streamed
over the Foxglove WebSocket protocol (``foxglove-sdk``, optional extra ``live``; docs/live.md).

* :mod:`.settings` - the ``[live]`` configuration section and its checks;
* :mod:`.scene` - the correction vectors as ``foxglove.SceneUpdate`` arrows;
* :mod:`.server` - the ``foxglove-sdk`` side: its own context, the channels, the server;
* :mod:`.decimate` - which messages of an update are sent (the high-rate topics decimated);
* :mod:`.sink` - :class:`LiveSink`: updates (``tick``), WebSocket server: what
  runs in the view's process;
* :mod:`.process` - :class:`LiveProcessSink`, the daemon's live view: the daemon copies the
  watched records into shared memory (:mod:`..childproc`: no thread, no system call), a child
  process (:mod:`.child`) runs the rest;
* :mod:`.fanout` - :class:`LiveFanOut`: the MCAP logger and the sink behind one
  ``SessionLogger``.

``foxglove`` is imported only when a sink starts.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
