"""numba kernels compiled with an on-disk cache where one is writable, and without it elsewhere.

``numba.njit(cache=True)`` raises ``RuntimeError: cannot cache function …: no locator
available`` *at import* when it finds no writable place for its cache: not the package's own
``__pycache__`` (a read-only install), not ``$NUMBA_CACHE_DIR`` (unset) and not the user's cache
folder (no home: a system account, or a systemd unit with ``ProtectHome=true``). Every kernel of
the project is decorated with :func:`njit_cached` instead, which asks numba for the cache and,
when no locator exists for that function in this process, compiles it without one: the process
then pays the compile time at its first call (``cmm-comp daemon`` logs that at start) instead of
dying. The decision is made per function at decoration time from what numba itself finds (the
environment and the file system of this process); nothing global is set or changed.

:func:`kernel_cache_dir` says where (or whether) a kernel's compiled code is cached.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba

__all__ = ["kernel_cache_dir", "njit_cached"]

_NO_LOCATOR = "no locator available"
"""numba's message when no cache folder is usable (``numba/core/caching.py``, 0.59 … 0.68)."""


def njit_cached(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)`` where numba finds a writable cache for the
    function, else ``numba.njit(**options)`` (compiled in memory at the first call)."""

    def decorate(func: Callable[..., Any]) -> Any:
        try:
            return numba.njit(cache=True, **options)(func)
        except RuntimeError as exc:
            if _NO_LOCATOR not in str(exc):
                raise
        return numba.njit(**options)(func)

    return decorate


def kernel_cache_dir(kernel: Any) -> str | None:
    """The folder a :func:`njit_cached` kernel's compiled code is cached in, or None when it
    is compiled anew in every process (no writable cache folder was found)."""
    path = kernel.stats.cache_path
    return None if path is None else str(path)
