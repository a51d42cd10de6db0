"""Keep a Python thread state on the Zenoh threads that run callbacks directly.

A ``Callback(indirect=False)`` runs on a thread of Zenoh's runtime, which Python does not
know. Each call takes the GIL with ``PyGILState_Ensure`` and gives it back with
``PyGILState_Release``; on a thread without a thread state of its own that creates one and
destroys it again, every sample: in CPython 3.11 a ``gettid`` and a 16 KiB ``mmap`` for the
frame stack, then a ``munmap`` (which interrupts the process's threads on the other cores to
flush their TLBs). :func:`pin_thread_state` takes one more ``PyGILState_Ensure`` the first time
a thread calls it and never releases it, so the thread keeps one thread state for its life and
later calls reuse it (docs/architecture.md, "One thread state per Zenoh thread").
"""

from __future__ import annotations

import ctypes
import threading

_pinned: set[int] = set()
_lock = threading.Lock()


def pin_thread_state() -> None:
    """Keep the calling thread's Python thread state until the thread ends (idempotent).

    Call it with the GIL held (from Python code); cheap after the thread's first call.
    """
    ident = threading.get_ident()
    if ident in _pinned:
        return
    with _lock:
        if ident not in _pinned:
            ctypes.pythonapi.PyGILState_Ensure()
            _pinned.add(ident)


def pinned_threads() -> int:
    """Return how many threads keep their thread state."""
    return len(_pinned)
