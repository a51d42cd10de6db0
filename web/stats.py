"""Per-stream receive statistics computed locally: rate, latency, lost and malformed messages.

Lost messages are counted from ``seq`` gaps (:func:`teleop_force.transport.messages.sequence_gap`);
a
jump of more than :data:`RESTART_GAP` (or backwards) is taken as a publisher restart, not a
loss. Latency is ``time.time_ns() - t_ns`` at arrival (meaningful on clock-synchronised
machines). Rates and ages use ``time.perf_counter``.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.transport.messages import sequence_gap

#: A seq jump larger than this is a restart of the publisher, not lost messages.
RESTART_GAP: Final = 1_000_000
_HISTORY: Final = 4096


@dataclass(frozen=True)
class StreamSnapshot:
    """Statistics of one stream at one instant.

    Attributes:
        received: Messages decoded so far.
        malformed: Messages that failed to decode (or had the wrong joint count).
        lost: Messages missing from the ``seq`` sequence.
        restarts: Publisher restarts seen (``seq`` jumped backwards or very far).
        rate_hz: Messages received in the last ``window_s`` seconds, per second.
        latency_ms_mean: Mean source-to-arrival latency over that window (NaN if none).
        latency_ms_max: Largest latency over that window (NaN if none).
        age_s: Seconds since the last message (``inf`` if none yet).

    """

    received: int
    malformed: int
    lost: int
    restarts: int
    rate_hz: float
    latency_ms_mean: float
    latency_ms_max: float
    age_s: float


class StreamStats:
    """Thread-safe counters of one subscribed stream."""

    def __init__(self, history: int = _HISTORY) -> None:
        """Keep the arrival time and latency of the last ``history`` messages."""
        self._arrival = np.full(history, -np.inf)
        self._latency_ms = np.full(history, np.nan)
        self._next = 0
        self._received = 0
        self._malformed = 0
        self._lost = 0
        self._restarts = 0
        self._last_seq: int | None = None
        self._last_arrival = -np.inf
        self._lock = threading.Lock()

    def record(self, seq: int, t_ns: int, arrival_s: float, now_ns: int) -> None:
        """Count one decoded message (``arrival_s`` from perf_counter, ``now_ns`` wall clock)."""
        with self._lock:
            if self._last_seq is not None:
                gap = sequence_gap(self._last_seq, seq)
                if gap > RESTART_GAP:
                    self._restarts += 1
                else:
                    self._lost += gap
            self._last_seq = seq
            i = self._next
            self._arrival[i] = arrival_s
            self._latency_ms[i] = (now_ns - t_ns) / 1e6
            self._next = (i + 1) % self._arrival.shape[0]
            self._received += 1
            self._last_arrival = arrival_s

    def record_malformed(self) -> None:
        """Count one message that could not be used."""
        with self._lock:
            self._malformed += 1

    def snapshot(self, now_s: float, window_s: float = 1.0) -> StreamSnapshot:
        """Statistics over the last ``window_s`` seconds before ``now_s`` (perf_counter)."""
        with self._lock:
            recent = self._arrival > now_s - window_s
            count = int(np.count_nonzero(recent))
            latencies = self._latency_ms[recent]
            result = (
                self._received,
                self._malformed,
                self._lost,
                self._restarts,
                self._last_arrival,
            )
        received, malformed, lost, restarts, last = result
        return StreamSnapshot(
            received=received,
            malformed=malformed,
            lost=lost,
            restarts=restarts,
            rate_hz=count / window_s,
            latency_ms_mean=float(np.mean(latencies)) if latencies.size else float("nan"),
            latency_ms_max=float(np.max(latencies)) if latencies.size else float("nan"),
            age_s=max(0.0, now_s - last) if np.isfinite(last) else float("inf"),
        )


__all__ = ["RESTART_GAP", "StreamSnapshot", "StreamStats"]
