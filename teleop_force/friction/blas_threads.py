"""Run blocks of linear algebra with one OpenBLAS thread.

The batch fit's BLAS and LAPACK calls are small (Gram products of a few thousand rows by a
few hundred columns, Cholesky factors of a few hundred): one thread does each in a few
milliseconds. OpenBLAS's worker threads, though, busy-wait between calls, and NumPy and SciPy
each bring their own OpenBLAS with its own pool: on a machine whose cores are shared (the
2-core development machine with other jobs running), the calls then wait for descheduled
workers, and were measured 10 to 400 times slower than with one thread (a 300 x 300
Cholesky 1.4 ms -> 0.6 s, a 1639 x 300 Gram product 5 ms -> 80 ms).

:func:`single_threaded_blas` sets every loaded OpenBLAS (NumPy's, SciPy's) to one thread with
``openblas_set_num_threads_local`` (OpenBLAS >= 0.3.27, what the wheels ship) and restores the
previous count when the last block still open ends. Despite its name that setting is
**process-wide** in these (pthreads) builds (checked: a thread sees the count another thread
set), so the blocks are reference-counted: several threads may be inside at once (the batch
fit runs one per joint group), and other threads' BLAS calls in the meantime run on one
thread too. Where no such OpenBLAS is loaded (another BLAS, an older OpenBLAS, not Linux),
it does nothing.
"""

from __future__ import annotations

import ctypes
import glob
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_GETTERS = (
    "openblas_get_num_threads",
    "openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads64_",
    "scipy_openblas_get_num_threads",
)
_lock = threading.Lock()
_depth = 0
_saved: list[int] = []
_libraries: list[tuple[Any, Any]] | None = None


def _loaded_openblas_paths() -> list[str]:
    """Paths of the OpenBLAS libraries mapped into this process (NumPy's, SciPy's, ...)."""
    paths: set[str] = set()
    try:
        with open("/proc/self/maps") as maps:
            for line in maps:
                path = line.rstrip("\n").split(maxsplit=5)[-1]
                if "openblas" in os.path.basename(path).lower() and os.path.isfile(path):
                    paths.add(path)
    except OSError:
        import numpy
        import scipy

        for module in (numpy, scipy):
            folder = os.path.join(os.path.dirname(module.__file__ or ""), os.pardir)
            paths.update(glob.glob(os.path.join(folder, f"{module.__name__}.libs", "*openblas*")))
    return sorted(paths)


def _openblas() -> list[tuple[Any, Any]]:
    """``(set_num_threads_local, get_num_threads)`` of every loaded OpenBLAS."""
    global _libraries
    if _libraries is None:
        import scipy.linalg  # noqa: F401  (maps SciPy's OpenBLAS before looking)

        found: list[tuple[Any, Any]] = []
        for path in _loaded_openblas_paths():
            try:
                library = ctypes.CDLL(path)
                setter = library.openblas_set_num_threads_local
            except (OSError, AttributeError):
                continue
            setter.argtypes = [ctypes.c_int]
            setter.restype = ctypes.c_int
            getter = None
            for name in _GETTERS:
                getter = getattr(library, name, None)
                if getter is not None:
                    getter.argtypes = []
                    getter.restype = ctypes.c_int
                    break
            found.append((setter, getter))
        _libraries = found
    return _libraries


def blas_thread_counts() -> list[int]:
    """Return the thread count of every loaded OpenBLAS that tells it (tests, reports)."""
    return [getter() for _, getter in _openblas() if getter is not None]


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Within the block, OpenBLAS calls run on one thread (process-wide, see the module doc)."""
    global _depth, _saved
    libraries = _openblas()
    with _lock:
        if _depth == 0:
            _saved = [setter(1) for setter, _ in libraries]
        else:
            for setter, _ in libraries:
                setter(1)  # this thread too, should a build keep the count per thread
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                for (setter, _), count in zip(libraries, _saved, strict=True):
                    setter(count)
