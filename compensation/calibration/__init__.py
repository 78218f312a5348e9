"""calibration: from what a calibration lab measures to the machine description —
``cmm-comp calibrate`` and ``cmm-comp calibrate plan`` (docs/calibration.md).

* :mod:`.plan` — the plan ``calibration.toml``; :mod:`.csvtable`, :mod:`.laser`, :mod:`.plate`,
  :mod:`.multilateration` — the data files, read and checked;
* :mod:`.basis` — the error functions' parametrisation (what ``machine.toml`` evaluates);
* :mod:`.model`, :mod:`.obs_laser`, :mod:`.obs_artefacts` — the observation models on the
  project's exact chain;
* :mod:`.solver` — Gauss–Newton with nuisance poses/stations, variance groups, smoothness;
  :mod:`.posterior` — U marginalised over the smoothness (the residuals before the fit are the
  solver's first stage, :attr:`.solver.Solution.before`);
* :mod:`.gauge` — what the data cannot see; :mod:`.covariance` — U of every identified error
  and of the volumetric error;
* :mod:`.writer` — ``machine.toml`` with ``[uncertainty]``; :mod:`.report` — JSON, PNG, HTML;
* :mod:`.planner` — predicted U of a plan on the virtual CMM; :mod:`.simulate` — readings of a
  machine through the public machine API.

Units: positions mm, linear errors µm, angles µrad, temperatures °C; error = true − indicated.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
