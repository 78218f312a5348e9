"""The daemon's session log: every message of a session in MCAP (JSON messages), and replay.

* :mod:`.schemas` - the topics' JSON Schemas and the log's time conversions;
* :mod:`.records` - compact record tuples the hot path logs instead of dicts;
* :mod:`.logger` - :class:`SessionLogger`, the protocol both writers implement, their shared
  :class:`LogSettings`, :class:`LoggerStats` and never-blocking queue;
* :mod:`.encoding` - one message to strict JSON, or the error record that replaces it;
* :mod:`.writer` - one session file: naming (and rotating an existing name), opening, finishing;
* :mod:`.mcapfile` - :class:`McapFileWriter`, a chunked MCAP file with every index, written from
  the format's specification (:mod:`.mcapwire`: the records as bytes; :mod:`.summary`: the chunk
  index spooled to disk, the summary section);
* :mod:`.thread_writer` - :class:`McapLogger`, a writer thread in the daemon's process;
* :mod:`.process_writer` - :class:`McapProcessLogger`, the writing in a child process
  (:mod:`.writer_child` is that child's side);
* :mod:`.reader` - read sessions back (rolled sets, files cut by a crash);
* :mod:`.recover` - rewrite a file cut by a crash as a complete, indexed file;
* :mod:`.replay` - re-correct a session offline, or re-send what the controller sent to a bus.

See docs/mcap.md.
"""

import lazy_loader as _lazy

# Names are listed once, in __init__.pyi (type checkers read it); each loads on first use, so
# importing one submodule never drags in the whole package.
__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
