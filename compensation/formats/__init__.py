"""The files a machine and its measurements live in (docs/formats.md §1–2):

* :mod:`.machine_toml`, :mod:`.machine_parser`: ``machine.toml`` read, validated into a
  machine's parts, written back;
* :mod:`.measurements`: the verification measurements CSV;
* :mod:`.seedfiles`: the paper's own data-file sets (``<spec>S.CTL``, ``.DPX`` …);
* :mod:`.realdata`: importers of real instrument data (ISO 230-2 ``.dat`` runs, camonitor logs).

Only the first two are re-exported here: they sit below :class:`~..machine.Machine`
(``Machine.from_toml`` uses them), while the seed-file and real-data importers build machines
and reports on top of it. Import those from their modules (or the seed-file functions from
``cmm_comp.compensation``). Units: positions mm, errors µm, angles µrad, temperatures °C.
"""

from __future__ import annotations

from .machine_parser import ParsedMachine, parse_machine
from .machine_toml import description_from_parts, read_machine_toml, write_machine_toml
from .measurements import (
    TEMPERATURE_COLUMNS,
    Measurements,
    measurements_from_columns,
    read_measurements,
    write_measurements,
)

__all__ = [
    "TEMPERATURE_COLUMNS",
    "Measurements",
    "ParsedMachine",
    "description_from_parts",
    "measurements_from_columns",
    "parse_machine",
    "read_machine_toml",
    "read_measurements",
    "write_machine_toml",
    "write_measurements",
]
