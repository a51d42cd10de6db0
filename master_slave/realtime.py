"""A fixed-rate loop scheduler on ``time.perf_counter`` that sleeps to each deadline.

Tick ``k`` is due at ``start + k * period``. :meth:`RateLoop.wait` sleeps for the time left to
the deadline (``time.sleep``: ``clock_nanosleep`` on Linux) and returns; it does not spin by
default, so a loop costs only its own work. ``time.sleep`` wakes up late by the thread's
*timer slack* (50 us by default on Linux) plus the scheduling delay: :meth:`RateLoop.start`
lowers the slack of the loop's thread to ``timer_slack_ns`` (1 us) with
``prctl(PR_SET_TIMERSLACK)`` where it exists. A positive ``spin_s`` brings back the old
behaviour: sleep until ``spin_s`` before the deadline, then busy-wait (a few microseconds of
jitter, at the price of a core spinning).

Python's cyclic garbage collector is the other source of long stalls: a full collection
walks every tracked object, and a process with numpy, pinocchio and Zenoh loaded holds about
100 000 of them (measured: 93 ms for one full collection of the slave process). The loop
allocates a few short-lived containers per tick, so full collections do come. With
``freeze_gc``, :meth:`RateLoop.start` collects once and then *freezes* what is
alive (``gc.freeze``): later collections see only objects created after the start, and stay
well under a millisecond. It is process-wide, so it is off by default (a test suite creating
loops keeps its collector); the master and slave processes turn it on
(:func:`master_slave.process_args.loop_config_from_args`).

Counting, honestly:

- a tick that starts after the *next* deadline (more than one period late) is an
  **overrun**. The loop catches up by running late ticks back to back (a simulated plant must
  not skip ticks: its time advances one period per tick), so a stall of ``s`` seconds shows as
  about ``s * rate`` overruns in a row;
- when it has fallen more than ``max_lag_s`` behind, it stops catching up and re-anchors its
  schedule to now (a **resync**). The deadlines it jumps over are ticks that never ran: they
  are counted in ``missed_ticks``, so ``ticks + missed_ticks`` is about ``expected_ticks``
  (elapsed time x rate) however the loop was stalled.

Wall-clock time (``time.time_ns``) is never used for scheduling, only for message stamps:
:attr:`RateLoop.stamp_ns` gives tick ``k``'s nominal wall time, ``anchor + k * period``,
which stays strictly increasing and exactly periodic between resyncs.
"""

from __future__ import annotations

import ctypes
import gc
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

from teleop_force.errors import ConfigurationError
from teleop_force.transport.stream_stats import LatencyHistogram

_PR_SET_TIMERSLACK: Final = 29
_PR_GET_TIMERSLACK: Final = 30


def set_timer_slack_ns(slack_ns: int) -> int | None:
    """Set the calling thread's timer slack [ns] (Linux); return the new slack, else ``None``.

    The slack is how late the kernel may wake a sleeping thread to batch wake-ups; it is
    per thread, so call this from the thread that runs the loop.
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0) != 0:
            return None
        return int(libc.prctl(_PR_GET_TIMERSLACK, 0, 0, 0, 0))
    except (OSError, AttributeError):
        return None


@dataclass(frozen=True)
class LoopConfig:
    """Timing of a :class:`RateLoop`.

    Attributes:
        rate_hz: Ticks per second.
        spin_s: How long before a deadline the loop stops sleeping and busy-waits (0: never).
        max_lag_s: Lateness beyond which the schedule is re-anchored instead of caught up.
        timer_slack_ns: Timer slack of the loop's thread set at :meth:`RateLoop.start`
            (0: leave the thread's slack as it is).
        freeze_gc: At :meth:`RateLoop.start`, collect garbage once and move every object
            alive to the collector's permanent generation (``gc.freeze``; process-wide).

    """

    rate_hz: float = 1000.0
    spin_s: float = 0.0
    max_lag_s: float = 0.1
    timer_slack_ns: int = 1000
    freeze_gc: bool = False

    def __post_init__(self) -> None:
        """Check the ranges."""
        if not (math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 20_000.0):
            raise ConfigurationError(f"rate_hz must be in [1, 20000], got {self.rate_hz}")
        if not (math.isfinite(self.spin_s) and 0.0 <= self.spin_s <= 1.0 / self.rate_hz):
            raise ConfigurationError(
                f"spin_s must be in [0, one period = {1.0 / self.rate_hz}], got {self.spin_s}"
            )
        if not (math.isfinite(self.max_lag_s) and self.max_lag_s > 1.0 / self.rate_hz):
            raise ConfigurationError(f"max_lag_s must exceed one period, got {self.max_lag_s}")
        if not 0 <= self.timer_slack_ns <= 50_000_000:
            raise ConfigurationError(
                f"timer_slack_ns must be in [0, 50 ms], got {self.timer_slack_ns}"
            )

    @property
    def period_s(self) -> float:
        """One tick [s]."""
        return 1.0 / self.rate_hz

    @property
    def period_ns(self) -> int:
        """One tick [ns], rounded."""
        return round(1e9 / self.rate_hz)


class RateLoop:
    """Deadline scheduler of a fixed-rate loop (see the module docstring)."""

    def __init__(
        self,
        config: LoopConfig | None = None,
        *,
        clock: Callable[[], float] = time.perf_counter,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        """Create the loop; the schedule starts at the first :meth:`wait`.

        ``clock`` (monotonic seconds) and ``sleep`` are ``time.perf_counter`` and
        ``time.sleep`` but for tests.
        """
        self.config = config if config is not None else LoopConfig()
        self._clock = clock
        self._sleep = sleep
        self.tick = -1
        self.overruns = 0
        self.resyncs = 0
        #: Ticks whose deadlines a resync jumped over (they never ran).
        self.missed_ticks = 0
        #: Timer slack of the loop's thread after :meth:`start` [ns] (``None``: not set).
        self.timer_slack_ns: int | None = None
        #: Objects moved to the collector's permanent generation by :meth:`start`.
        self.gc_frozen_objects = 0
        self.lateness = LatencyHistogram()
        self._period_s = self.config.period_s
        self._period_ns = self.config.period_ns
        self._spin_s = self.config.spin_s
        self._max_lag_s = self.config.max_lag_s
        self._start_s = 0.0
        self._anchor_ns = 0
        self._anchor_tick = 0
        self._started_s = 0.0
        self._started = False

    def start(self) -> None:
        """Lower the timer slack, freeze the heap, anchor the schedule: tick 0 is due now."""
        if self.config.timer_slack_ns > 0:
            self.timer_slack_ns = set_timer_slack_ns(self.config.timer_slack_ns)
        if self.config.freeze_gc:
            gc.collect()
            gc.freeze()
            # counted once: gc.get_freeze_count() walks the whole list (ms for 100k objects)
            self.gc_frozen_objects = gc.get_freeze_count()
        self._start_s = self._clock()
        self._started_s = self._start_s
        self._started = True
        self._anchor_ns = time.time_ns()
        self._anchor_tick = 0
        self.tick = -1

    def wait(self) -> int:
        """Block until the next tick is due; return its index."""
        if not self._started:
            self.start()
        self.tick += 1
        deadline = self._start_s + (self.tick - self._anchor_tick) * self._period_s
        clock = self._clock
        late = clock() - deadline
        if late < 0.0:
            spin = self._spin_s
            if -late > spin:
                self._sleep(-late - spin)
            if spin > 0.0:
                while clock() < deadline:
                    pass
            late = clock() - deadline  # a sleep can overshoot, too
        if late > self._period_s:
            self.overruns += 1
            if late > self._max_lag_s:
                self._resync(deadline + late, late)
        self.lateness.add(late)
        return self.tick

    def _resync(self, now_s: float, late_s: float) -> None:
        """Run the current tick now and re-anchor; the deadlines passed meanwhile are missed."""
        self.resyncs += 1
        self.missed_ticks += int(late_s / self._period_s)
        self._start_s = now_s
        self._anchor_ns += (self.tick - self._anchor_tick) * self._period_ns + round(late_s * 1e9)
        self._anchor_tick = self.tick

    @property
    def stamp_ns(self) -> int:
        """Nominal wall-clock time of the current tick [ns since the epoch]."""
        return self._anchor_ns + (self.tick - self._anchor_tick) * self._period_ns

    @property
    def elapsed_s(self) -> float:
        """Time since :meth:`start` [s]."""
        return self._clock() - self._started_s if self._started else 0.0

    def stats(self) -> dict[str, Any]:
        """Tick counts against the clock, overruns, resyncs and the start lateness [ms].

        ``expected_ticks`` is the elapsed time times the rate; ``ticks_fraction`` is
        ``ticks / expected_ticks``, ``overrun_fraction`` is ``overruns / ticks``.
        """
        elapsed = self.elapsed_s
        ticks = self.tick + 1
        expected = elapsed * self.config.rate_hz
        return {
            "ticks": ticks,
            "expected_ticks": round(expected, 1),
            "ticks_fraction": round(ticks / expected, 6) if expected >= 1.0 else None,
            "rate_hz": round(ticks / elapsed, 2) if elapsed > 0 else 0.0,
            "overruns": self.overruns,
            "overrun_fraction": round(self.overruns / ticks, 6) if ticks > 0 else 0.0,
            "missed_ticks": self.missed_ticks,
            "resyncs": self.resyncs,
            "timer_slack_ns": self.timer_slack_ns,
            "gc_frozen_objects": self.gc_frozen_objects,
            "gc_full_collections": gc.get_stats()[-1]["collections"],
            "lateness_ms": self.lateness.summary_ms(),
        }
