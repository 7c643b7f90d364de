"""Optional numba: ``njit`` and ``HAVE_NUMBA`` for the compiled kernels of the simulator.

numba is a dependency of the package, but the simulator also runs without it (every kernel has
a numpy reference path that gives identical results). ``MIVECC_NO_NUMBA=1`` forces the numpy
reference paths (for tests and for comparing speed).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

try:
    if os.environ.get("MIVECC_NO_NUMBA", "") not in ("", "0"):
        raise ImportError("disabled by MIVECC_NO_NUMBA")
    from numba import njit as _njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised when numba is missing
    _njit = None
    HAVE_NUMBA = False


def njit(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Compile ``fn`` with numba (cached on disk, no fast-math), or return it unchanged."""
    if _njit is None:  # pragma: no cover
        return fn
    return _njit(cache=True, nogil=True)(fn)
