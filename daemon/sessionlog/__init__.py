"""The daemon's session log: every message of a session in MCAP (JSON messages).

* :mod:`.encoding` - one message to the JSON of its Struct, or the error record that replaces it;
* :mod:`.logger` - :class:`SessionLogger`, the protocol the daemon types against,
  :class:`LogSettings`, :class:`LoggerStats` and what the writers share;
* :mod:`.writer` - session files: naming (and rotating an existing name), opening, finishing,
  and :class:`SessionWriter`, which writes messages into them in the calling thread;
* :mod:`.mcapfile` - :class:`McapFileWriter`, a chunked MCAP file with every index (records
  built by ``mcap.records``; the message path and the chunk index spooled to disk are ours);
* :mod:`.process_writer` - :class:`McapProcessLogger`, the daemon's log: a :class:`SessionWriter`
  in a child process (:mod:`..childproc`), fed straight from shared memory;

Every topic's messages are defined once, in :mod:`cmm_comp.protocol.session_topics` (the
contract with every reader of a session). Reading a log back (the reader, ``mcap recover``,
replay) is offline work, never done in the daemon's processes: :mod:`cmm_comp.cli.sessionlog`.

See docs/mcap.md.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
