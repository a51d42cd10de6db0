"""Running statistics of a message stream: losses (sequence gaps), latency percentiles, rate.

Used by the force-estimation service, the master and slave processes and the demo supervisor.
Nothing here reads a clock by itself except :class:`RateMeter` (``time.perf_counter``), so
the numbers are reproducible in tests::

    seqs = SequenceTracker()
    seqs.observe(7)            # first message
    seqs.observe(10)           # 8 and 9 are lost -> seqs.lost == 2
    latency = LatencyHistogram()
    latency.add(0.4e-3)
    latency.summary_ms()       # {"p50": 0.4, "p99": 0.4, "max": 0.4, "count": 1}
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.transport.messages import sequence_gap

#: A sequence number this far *behind* the last one (mod 2**32) is a restart, not a huge loss.
RESTART_WINDOW: Final = 1 << 31


@dataclass(frozen=True)
class SequenceEvent:
    """What :meth:`SequenceTracker.observe` concluded about one sequence number.

    Attributes:
        lost: Messages missing between the previous one and this one.
        restarted: The sequence went backwards or jumped: a new stream began.
        duplicate: The same sequence number as the previous message.

    """

    lost: int = 0
    restarted: bool = False
    duplicate: bool = False

    def __post_init__(self) -> None:
        """Check that ``lost`` is not negative."""
        if self.lost < 0:
            raise ConfigurationError(f"lost must be >= 0, got {self.lost}")


_FIRST: Final = SequenceEvent()


class SequenceTracker:
    """Count lost messages from gaps in the ``seq`` numbers of one publisher.

    A sequence number that goes backwards, or forwards by more than ``max_gap``, is taken as a
    new stream (the publisher restarted, or a recording is being replayed) and counted in
    :attr:`restarts`, not as losses.
    """

    def __init__(self, max_gap: int = 100_000) -> None:
        """Create a tracker; gaps above ``max_gap`` messages count as a restart."""
        if max_gap < 1:
            raise ConfigurationError(f"max_gap must be >= 1, got {max_gap}")
        self.max_gap = int(max_gap)
        self.last_seq: int | None = None
        self.received = 0
        self.lost = 0
        self.restarts = 0
        self.duplicates = 0

    def observe(self, seq: int) -> SequenceEvent:
        """Account for a received ``seq``; return what it means."""
        self.received += 1
        previous = self.last_seq
        self.last_seq = seq
        if previous is None:
            return _FIRST
        if seq == previous:
            self.duplicates += 1
            return SequenceEvent(duplicate=True)
        gap = sequence_gap(previous, seq)
        if gap >= RESTART_WINDOW - 1 or gap > self.max_gap:
            self.restarts += 1
            return SequenceEvent(restarted=True)
        self.lost += gap
        return SequenceEvent(lost=gap) if gap else _FIRST

    def to_dict(self) -> dict[str, int]:
        """Counters as a JSON-ready dict."""
        return {
            "received": self.received,
            "lost": self.lost,
            "restarts": self.restarts,
            "duplicates": self.duplicates,
        }


class LatencyHistogram:
    """Latencies [s] in a log-spaced histogram: O(1) to add, cheap percentiles, whole run.

    Bins are ``bins_per_decade`` per factor of ten from ``min_s`` to ``max_s`` (values outside
    go to the end bins), so a percentile is exact to the bin width (0.5 % by default) whatever
    the number of samples, and computing one never stalls a real-time loop. The maximum and
    the count are exact; negative values (clocks of two processes disagreeing) are counted in
    :attr:`negative` and put in the lowest bin.
    """

    def __init__(self, min_s: float = 1e-7, max_s: float = 1e3, bins_per_decade: int = 200) -> None:
        """Allocate the bins."""
        if not (0.0 < min_s < max_s) or bins_per_decade < 1:
            raise ConfigurationError("need 0 < min_s < max_s and bins_per_decade >= 1")
        self._log_min = math.log10(min_s)
        self._per_decade = float(bins_per_decade)
        self._n_bins = math.ceil((math.log10(max_s) - self._log_min) * bins_per_decade)
        self._counts = np.zeros(self._n_bins + 1, dtype=np.int64)
        self.count = 0
        self.negative = 0
        self.max_s = -math.inf

    def add(self, latency_s: float) -> None:
        """Record one latency [s] (non-finite values are ignored)."""
        if not math.isfinite(latency_s):
            return
        if latency_s <= 0.0:
            if latency_s < 0.0:
                self.negative += 1
            index = 0
        else:
            index = int((math.log10(latency_s) - self._log_min) * self._per_decade)
            index = 0 if index < 0 else (self._n_bins if index > self._n_bins else index)
        self._counts[index] += 1
        self.count += 1
        if latency_s > self.max_s:
            self.max_s = latency_s

    def percentile_s(self, q: float) -> float:
        """Return the ``q``-th percentile (0..100) [s]: the geometric centre of its bin."""
        if self.count == 0:
            return math.nan
        rank = min(self.count - 1, max(0, math.ceil(q / 100.0 * self.count) - 1))
        index = int(np.searchsorted(np.cumsum(self._counts), rank, side="right"))
        centre = 10.0 ** (self._log_min + (index + 0.5) / self._per_decade)
        return min(centre, self.max_s)

    def summary_ms(self) -> dict[str, float | int | None]:
        """``{"p50", "p99", "max"}`` in milliseconds (``None`` when empty) and ``count``."""
        if self.count == 0:
            return {"p50": None, "p99": None, "max": None, "count": 0}
        return {
            "p50": round(self.percentile_s(50.0) * 1e3, 4),
            "p99": round(self.percentile_s(99.0) * 1e3, 4),
            "max": round(self.max_s * 1e3, 4),
            "count": self.count,
        }


class RateMeter:
    """Events per second over the last completed one-second window, and since the start."""

    def __init__(self, window_s: float = 1.0) -> None:
        """Start counting now."""
        if not window_s > 0.0:
            raise ConfigurationError(f"window_s must be > 0, got {window_s}")
        self.window_s = float(window_s)
        self.total = 0
        self._started_s = time.perf_counter()
        self._window_start_s = self._started_s
        self._window_count = 0
        self._rate_hz = 0.0

    def tick(self, n: int = 1) -> None:
        """Count ``n`` events now."""
        self.total += n
        self._window_count += n
        self._roll(time.perf_counter())

    def _roll(self, now_s: float) -> None:
        elapsed = now_s - self._window_start_s
        if elapsed >= self.window_s:
            self._rate_hz = self._window_count / elapsed
            self._window_start_s = now_s
            self._window_count = 0

    @property
    def rate_hz(self) -> float:
        """Events per second in the last complete window (0 when none arrived for a while)."""
        now = time.perf_counter()
        self._roll(now)
        if now - self._window_start_s > 2.0 * self.window_s:
            return 0.0
        return self._rate_hz

    @property
    def mean_rate_hz(self) -> float:
        """Events per second since the meter was created."""
        elapsed = time.perf_counter() - self._started_s
        return self.total / elapsed if elapsed > 0.0 else 0.0


__all__ = [
    "LatencyHistogram",
    "RateMeter",
    "SequenceEvent",
    "SequenceTracker",
]
