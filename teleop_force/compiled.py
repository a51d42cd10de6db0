"""Compilation of the model's numerical terms with numba (nopython), cached on disk.

Every model term (friction, wavelets, coverage trust, found effects) is one
:func:`njit_cached` function on plain floats and arrays, so the batch fits, the streaming
estimator and other compiled code call the same definition.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba


def njit_cached(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, nogil=True, **options)``; in memory where no cache can be written.

    The compiled code is cached next to the module, or where numba's cache locator finds a
    writable place; when there is none it is compiled on first use in every process.
    """
    options = {"nogil": True, **options}

    def wrap(fn: Callable[..., Any]) -> Any:
        try:
            return numba.njit(cache=True, **options)(fn)
        except RuntimeError:  # numba found no writable cache location
            return numba.njit(cache=False, **options)(fn)

    return wrap
