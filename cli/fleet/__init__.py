"""``cmm-comp fleet``: every session of a fleet of machines, diagnosed or replayed on Dask.

Modules: :mod:`.commands` (the subcommands), :mod:`.discover` (sessions under ROOT and their
content keys), :mod:`.tasks` (what a worker runs: the one-by-one commands' own functions),
:mod:`.engine` (the cluster, the bounded window of tasks, progress), :mod:`.store` (results
stored next to OUT, OUT written as a stream), :mod:`.results` (the per-machine sections),
:mod:`.report` (trend plots), :mod:`.generate` (a simulated fleet). docs/fleet.md.
"""

from .commands import add_parsers

__all__ = ["add_parsers"]
