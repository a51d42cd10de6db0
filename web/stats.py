"""Per-stream receive statistics computed locally: rate, latency, lost and malformed messages.

Everything comes from rmw_zenoh's attachment of each sample
(:class:`~teleop_force.ros2.attachment.Attachment`), not from the message itself. Lost
messages are counted from gaps in each publisher's sequence number (per GID: two publishers
on one topic do not spoil each other's count). A publisher seen after the first one (a
restarted process has a new GID), or a sequence number that goes backwards or jumps by more
than :data:`RESTART_GAP` (a restart with the same GID), is counted as a restart, not a loss.
Latency is ``time.time_ns()`` at arrival minus the attachment's source timestamp: across
hosts it is meaningful only with synchronised clocks (chrony, PTP). Rates and ages use
``time.perf_counter``.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.ros2.attachment import Attachment

#: A sequence jump larger than this is a restart of the publisher, not lost messages.
RESTART_GAP: Final = 1_000_000
#: Publishers (GIDs) whose last sequence number is kept per stream, least recent dropped.
MAX_PUBLISHERS: Final = 64
#: Shown wherever latency is: what it is and when it means something.
LATENCY_NOTE: Final = (
    "Latency = arrival time - the publisher's source timestamp (rmw_zenoh attachment); "
    "across hosts it needs synchronised clocks (chrony, PTP)."
)
_HISTORY: Final = 4096


@dataclass(frozen=True)
class StreamSnapshot:
    """Statistics of one stream at one instant.

    Attributes:
        received: Messages decoded so far.
        malformed: Messages dropped: no valid attachment, not decodable, wrong joint count.
        lost: Messages missing from the publishers' sequence numbers.
        restarts: Publishers seen after the first, and sequence numbers that went backwards
            or jumped by more than :data:`RESTART_GAP`.
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
        self._last_seq: OrderedDict[bytes, int] = OrderedDict()  # per publisher GID
        self._last_arrival = -np.inf
        self._lock = threading.Lock()

    def record(self, attachment: Attachment, arrival_s: float, now_ns: int) -> None:
        """Count one decoded message (``arrival_s`` from perf_counter, ``now_ns`` wall clock)."""
        seq, gid = attachment.sequence_number, attachment.gid
        with self._lock:
            last = self._last_seq.get(gid)
            if last is None:
                if self._last_seq:
                    self._restarts += 1
            else:
                gap = seq - last - 1
                if gap < 0 or gap > RESTART_GAP:
                    self._restarts += 1
                else:
                    self._lost += gap
                self._last_seq.move_to_end(gid)
            self._last_seq[gid] = seq
            if len(self._last_seq) > MAX_PUBLISHERS:
                self._last_seq.popitem(last=False)
            i = self._next
            self._arrival[i] = arrival_s
            self._latency_ms[i] = (now_ns - attachment.source_timestamp_ns) / 1e6
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


__all__ = ["LATENCY_NOTE", "MAX_PUBLISHERS", "RESTART_GAP", "StreamSnapshot", "StreamStats"]
