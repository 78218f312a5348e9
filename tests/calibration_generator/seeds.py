"""The seeds policy: development seeds for tests, fresh ones for the benchmark, never shared.

* Development seeds are 0 … 999 999. Everything in ``tests/`` uses them (the hidden-truth test in
  CI: ``CI_CASES``, seeds 1000 … 1009). Whoever works on the identification may look at these
  cases as much as they like.
* Benchmark seeds are drawn fresh from the OS's entropy at every run in [2⁴⁰, 2⁶²), so they are
  disjoint from the development seeds by construction and nobody has seen them before the run;
  the benchmark records them in its JSON, and ``--seeds`` replays a recorded set (a replay of a
  seen set is no longer a fresh measurement: the JSON says so).
"""

from __future__ import annotations

import secrets

from .case import KINDS, MODELS

DEV_SEED_LIMIT = 1_000_000
FRESH_LOW, FRESH_HIGH = 2**40, 2**62

#: the CI's hidden-truth cases (seed, model, kind): every model once, the kinds in turn
CI_CASES: tuple[tuple[int, str, str], ...] = tuple(
    (1000 + i, model, KINDS[i % len(KINDS)]) for i, model in enumerate(MODELS)
)


def is_development_seed(seed: int) -> bool:
    return 0 <= seed < DEV_SEED_LIMIT


def fresh_seeds(n: int) -> list[int]:
    """``n`` distinct seeds nobody has used: OS entropy, outside the development range."""
    out: set[int] = set()
    while len(out) < n:
        out.add(FRESH_LOW + secrets.randbelow(FRESH_HIGH - FRESH_LOW))
    return sorted(out)
