"""Fixed-size numpy ring buffers of timestamped rows, and the decimation used for plotting.

The Zenoh callbacks only :meth:`RingBuffer.append` (one row copy under a lock, no
allocation); the render thread takes a :meth:`RingBuffer.window` copy a few tens of times a
second and reduces it with :func:`bin_mean` to a few hundred time bins before sending it to
the browser, so the browser never sees the 1 kHz stream sample by sample.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Window:
    """A chronological copy of the rows of a ring buffer.

    Attributes:
        t_s: Sample times [s], ascending, shape (N,).
        values: Rows, shape (N, width).

    """

    t_s: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        """Return the number of rows."""
        return int(self.t_s.shape[0])


class RingBuffer:
    """Thread-safe ring of the last ``capacity`` rows ``(t, values[width])``."""

    def __init__(self, capacity: int, width: int) -> None:
        """Allocate ``capacity`` rows of ``width`` float64 values (NaN until written)."""
        if capacity < 1 or width < 1:
            raise ValueError(f"capacity and width must be >= 1, got {capacity}, {width}")
        self._t = np.zeros(capacity)
        self._v = np.full((capacity, width), np.nan)
        self._next = 0
        self._count = 0
        self._lock = threading.Lock()

    @property
    def capacity(self) -> int:
        """Maximum number of rows kept."""
        return int(self._t.shape[0])

    @property
    def width(self) -> int:
        """Values per row."""
        return int(self._v.shape[1])

    def __len__(self) -> int:
        """Return the number of rows held (at most ``capacity``)."""
        return self._count

    def append(self, t_s: float, values: Sequence[float] | np.ndarray) -> None:
        """Store one row, overwriting the oldest when full; ``values`` needs ``width`` items."""
        with self._lock:
            i = self._next
            self._t[i] = t_s
            self._v[i] = values
            self._next = (i + 1) % self._t.shape[0]
            if self._count < self._t.shape[0]:
                self._count += 1

    def clear(self) -> None:
        """Forget every row."""
        with self._lock:
            self._next = 0
            self._count = 0

    def latest(self) -> tuple[float, np.ndarray] | None:
        """Return the newest ``(t, row copy)``, or ``None`` when empty."""
        with self._lock:
            if self._count == 0:
                return None
            i = (self._next - 1) % self._t.shape[0]
            return float(self._t[i]), self._v[i].copy()

    def window(self, t_from_s: float | None = None) -> Window:
        """Return the rows with ``t >= t_from_s`` (all rows if ``None``), oldest first.

        Rows are in arrival order; times are assumed non-decreasing in that order.
        """
        with self._lock:
            n, cap, nxt = self._count, self._t.shape[0], self._next
            oldest = 0 if n < cap else nxt
            order_t = self._t[:n] if n < cap else np.concatenate((self._t[nxt:], self._t[:nxt]))
            start = 0
            if t_from_s is not None and order_t.size:
                start = int(np.searchsorted(order_t, t_from_s, side="left"))
            rows = (oldest + start + np.arange(n - start)) % cap  # only the rows asked for
            t = order_t[start:].copy()
            v = self._v[rows]
        return Window(t, v)


def bin_mean(
    t: np.ndarray, values: np.ndarray, t_start: float, t_end: float, n_bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """Average ``(t (N,), values (N, k))`` into ``n_bins`` equal time bins over [t_start, t_end).

    Returns the bin centres (n_bins,) and per bin and column the mean of the finite values
    that fell in it, NaN where there are none (so gaps and missing estimates stay visible).
    Samples outside the interval are ignored. Different streams binned over the same interval
    share their time axis, which is what a uPlot chart needs.
    """
    if n_bins < 1:
        raise ValueError(f"n_bins must be >= 1, got {n_bins}")
    if not t_end > t_start:
        raise ValueError(f"need t_end > t_start, got {t_start}, {t_end}")
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[0] != t.shape[0]:
        raise ValueError(f"t has {t.shape[0]} samples, values {v.shape[0]}")
    width = (t_end - t_start) / n_bins
    centres = t_start + width * (np.arange(n_bins) + 0.5)
    if t.size > 1 and np.any(np.diff(t) < 0):  # rows in arrival order need not be sorted
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
    # Bins are contiguous runs of the sorted samples: sum each run with one reduceat.
    bounds = np.searchsorted(t, t_start + width * np.arange(n_bins + 1), side="left")
    starts, stops = bounds[:-1], bounds[1:]
    nonempty = stops > starts
    out = np.full((n_bins, v.shape[1]), np.nan)
    if not np.any(nonempty):
        return centres, out
    rows = v[: bounds[-1]]
    finite = np.isfinite(rows)
    sums = np.add.reduceat(np.where(finite, rows, 0.0), starts[nonempty], axis=0)
    counts = np.add.reduceat(finite.astype(np.int64), starts[nonempty], axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        out[nonempty] = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    return centres, out


__all__ = ["RingBuffer", "Window", "bin_mean"]
