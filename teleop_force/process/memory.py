"""Resident memory of a long-running process: measure it, and hand freed memory back.

A process with Zenoh's threads and an estimator thread allocates from several glibc malloc
arenas (one per thread that allocates, each a 64 MiB-aligned heap). When the machine starves
the process for a while, queues fill (Zenoh's buffers, the inbox, the recorder's backlog);
once they drain, the memory is free again but glibc keeps the arenas' pages, so the resident
set (RSS) steps up with every starvation episode and never comes down, although nothing is
live. Measured on the demo's service (2-core machine, both cores loaded for a minute): the
steps were in those arenas, not in Python's own (pymalloc) arenas or in the libraries.

:class:`MemoryTrimmer` does two things:

- it pins glibc's mmap threshold (``mallopt(M_MMAP_THRESHOLD)``, 128 KiB by default). glibc
  raises that threshold each time a large mmapped block is freed (up to 32 MiB), after which
  large buffers (message batches, numpy arrays, the dashboard's plot payloads) come from the
  arenas and stay resident once freed. Measured on the demo's dashboard under the soak (1 Hz
  samples): a 10 s sawtooth of 20-35 MB between trims without the pin, about 3 MB with it.
  Pinned, a block above the threshold is mapped on its own and returned when freed;
- it calls ``malloc_trim(0)`` periodically from a daemon thread: it returns the free pages of
  every arena to the system (``madvise(MADV_DONTNEED)``), so RSS follows what is live.

On a C library without them (musl, macOS) it does nothing and says so
(:attr:`MemoryTrimmer.available`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import resource
import sys
import threading
import time

from teleop_force.errors import ConfigurationError

#: How often the service hands free memory back [s]. One trim of a ~200 MB process takes
#: about a millisecond, on the trimmer's own thread.
DEFAULT_TRIM_PERIOD_S = 10.0
#: Blocks at least this large are mapped on their own and returned to the system when freed
#: [bytes] (glibc's own initial value, kept from growing).
DEFAULT_MMAP_THRESHOLD_BYTES = 128 * 1024
_M_MMAP_THRESHOLD = -3  # glibc's <malloc.h>


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        return ctypes.CDLL(name)
    except OSError:
        return None


def _c_function(
    libc: ctypes.CDLL | None, name: str, argtypes: list[type]
) -> ctypes._CFuncPtr | None:  # type: ignore[name-defined]
    """``libc.<name>`` returning an int, or None where the C library lacks it."""
    try:
        function = None if libc is None else getattr(libc, name)
    except AttributeError:
        return None
    if function is not None:
        function.argtypes = argtypes
        function.restype = ctypes.c_int
    return function


def read_status_kb(pid: int | str, field: str) -> int | None:
    """Read a ``kB`` field (``VmHWM``, ``VmRSS``) of ``/proc/<pid>/status`` (None: unreadable)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def resident_memory_mb(pid: int | str = "self") -> float | None:
    """Resident set size of a process [MB = 2^20 B] (``VmRSS``), or None where unreadable."""
    kb = read_status_kb(pid, "VmRSS")
    return None if kb is None else kb / 1024.0


def peak_rss_mb(pid: int | None = None) -> float | None:
    """High-water mark of the resident set of ``pid`` (default: this process) [MB = 2^20 B].

    Linux: ``VmHWM`` of ``/proc/<pid>/status``; elsewhere, for this process only,
    :func:`resource.getrusage` (``ru_maxrss``: kB on Linux, bytes on macOS).
    """
    kb = read_status_kb("self" if pid is None else pid, "VmHWM")
    if kb is not None:
        return kb / 1024.0
    if pid is not None:
        return None
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return maxrss / (1024.0 * 1024.0) if sys.platform == "darwin" else maxrss / 1024.0


class MemoryTrimmer:
    """A daemon thread that returns the process's free malloc pages to the system."""

    def __init__(
        self,
        period_s: float = DEFAULT_TRIM_PERIOD_S,
        mmap_threshold_bytes: int | None = DEFAULT_MMAP_THRESHOLD_BYTES,
    ) -> None:
        """Prepare a trimmer; :meth:`start` pins the mmap threshold and starts its thread.

        ``mmap_threshold_bytes=None`` leaves glibc's dynamic threshold alone.
        """
        if not (math.isfinite(period_s) and period_s > 0):
            raise ConfigurationError(f"period_s must be > 0, got {period_s}")
        if mmap_threshold_bytes is not None and not (
            4096 <= mmap_threshold_bytes <= 32 * 1024 * 1024
        ):
            raise ConfigurationError(
                f"mmap_threshold_bytes must be in [4096, 32 MiB], got {mmap_threshold_bytes}"
            )
        self.period_s = float(period_s)
        self.mmap_threshold_bytes = mmap_threshold_bytes
        libc = _libc()
        self._trim = _c_function(libc, "malloc_trim", [ctypes.c_size_t])
        self._mallopt = _c_function(libc, "mallopt", [ctypes.c_int, ctypes.c_int])
        self.threshold_pinned = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.trims = 0
        self.released_mb = 0.0
        self.last_trim_ms: float | None = None

    @property
    def available(self) -> bool:
        """Whether the C library has ``malloc_trim`` (glibc)."""
        return self._trim is not None

    def trim_now(self) -> float:
        """Trim once; return the RSS it released [MB] (0 where trimming is not available)."""
        if self._trim is None:
            return 0.0
        before = resident_memory_mb()
        started = time.perf_counter()
        self._trim(0)
        elapsed_ms = (time.perf_counter() - started) * 1e3
        after = resident_memory_mb()
        released = max(0.0, before - after) if before is not None and after is not None else 0.0
        with self._lock:
            self.trims += 1
            self.released_mb += released
            self.last_trim_ms = elapsed_ms
        return released

    def pin_mmap_threshold(self) -> bool:
        """Pin glibc's mmap threshold at :attr:`mmap_threshold_bytes`; return whether it took."""
        if self._mallopt is None or self.mmap_threshold_bytes is None:
            return False
        self.threshold_pinned = self._mallopt(_M_MMAP_THRESHOLD, self.mmap_threshold_bytes) == 1
        return self.threshold_pinned

    def start(self) -> MemoryTrimmer:
        """Pin the mmap threshold and trim every :attr:`period_s` (where glibc allows)."""
        if not self.threshold_pinned:
            self.pin_mmap_threshold()
        if self._trim is not None and self._thread is None:
            self._thread = threading.Thread(target=self._run, name="memory-trim", daemon=True)
            self._thread.start()
        return self

    def __enter__(self) -> MemoryTrimmer:
        """Start (see :meth:`start`) for the ``with`` block."""
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        """Stop at the end of the ``with`` block."""
        self.stop()

    def stop(self) -> None:
        """Stop the thread (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def stats(self) -> dict[str, object]:
        """Counters for the service's statistics."""
        rss = resident_memory_mb()
        pinned = self.mmap_threshold_bytes if self.threshold_pinned else None
        with self._lock:
            return {
                "available": self.available,
                "period_s": self.period_s,
                "mmap_threshold_bytes": pinned,
                "trims": self.trims,
                "released_mb": round(self.released_mb, 2),
                "last_trim_ms": None if self.last_trim_ms is None else round(self.last_trim_ms, 3),
                "rss_mb": None if rss is None else round(rss, 2),
            }

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.trim_now()
