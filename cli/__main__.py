"""``python -m cmm_comp.cli …`` is ``cmm-comp …``."""

import sys

from .main import main

sys.exit(main())
