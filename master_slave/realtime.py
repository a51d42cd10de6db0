"""A fixed-rate loop scheduler on ``time.perf_counter``: sleep until close, then spin.

Tick ``k`` is due at ``start + k * period``. :meth:`RateLoop.wait` sleeps until ``spin_s``
before the deadline (``time.sleep`` wakes up late by tens of microseconds, more on a loaded
machine) and then busy-waits the rest, so ticks start within a few microseconds of their
deadline when the machine is not overloaded. A tick that starts after the *next* deadline has
overrun: the loop counts it and catches up by running late ticks back to back (a simulated
plant must not skip ticks). When it has fallen more than ``max_lag_s`` behind, it gives up
catching up and re-anchors its schedule to now (counted in ``resyncs``).

Wall-clock time (``time.time_ns``) is never used for scheduling, only for message stamps:
:attr:`RateLoop.stamp_ns` gives tick ``k``'s nominal wall time, ``anchor + k * period``,
which stays strictly increasing and exactly periodic between resyncs.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from teleop_force.errors import ConfigurationError
from teleop_force.transport.stream_stats import LatencyHistogram


@dataclass(frozen=True)
class LoopConfig:
    """Timing of a :class:`RateLoop`.

    Attributes:
        rate_hz: Ticks per second.
        spin_s: How long before a deadline the loop stops sleeping and starts spinning.
        max_lag_s: Lateness beyond which the schedule is re-anchored instead of caught up.

    """

    rate_hz: float = 1000.0
    spin_s: float = 50e-6
    max_lag_s: float = 0.1

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

    def __init__(self, config: LoopConfig | None = None) -> None:
        """Create the loop; the schedule starts at the first :meth:`wait`."""
        self.config = config if config is not None else LoopConfig()
        self.tick = -1
        self.overruns = 0
        self.resyncs = 0
        self.lateness = LatencyHistogram()
        self._period_s = self.config.period_s
        self._period_ns = self.config.period_ns
        self._start_s = 0.0
        self._anchor_ns = 0
        self._anchor_tick = 0
        self._started_s = 0.0

    def start(self) -> None:
        """Anchor the schedule now: tick 0 is due immediately."""
        self._start_s = time.perf_counter()
        self._started_s = self._start_s
        self._anchor_ns = time.time_ns()
        self._anchor_tick = 0
        self.tick = -1

    def wait(self) -> int:
        """Block until the next tick is due; return its index."""
        if self.tick < 0 and self._started_s == 0.0:
            self.start()
        self.tick += 1
        deadline = self._start_s + (self.tick - self._anchor_tick) * self._period_s
        now = time.perf_counter()
        late = now - deadline
        if late > self._period_s:
            self.overruns += 1
            if late > self.config.max_lag_s:
                self.resyncs += 1
                self._start_s = now
                self._anchor_ns += (self.tick - self._anchor_tick) * self._period_ns + round(
                    late * 1e9
                )
                self._anchor_tick = self.tick
                self.lateness.add(late)
                return self.tick
        if late < 0.0:
            remaining = -late - self.config.spin_s
            if remaining > 0.0:
                time.sleep(remaining)
            while time.perf_counter() < deadline:
                pass
            late = time.perf_counter() - deadline
        self.lateness.add(late)
        return self.tick

    @property
    def stamp_ns(self) -> int:
        """Nominal wall-clock time of the current tick [ns since the epoch]."""
        return self._anchor_ns + (self.tick - self._anchor_tick) * self._period_ns

    @property
    def elapsed_s(self) -> float:
        """Time since :meth:`start` [s]."""
        return time.perf_counter() - self._started_s if self._started_s else 0.0

    def stats(self) -> dict[str, Any]:
        """Ticks, overruns, resyncs and the start lateness percentiles [ms] as a JSON dict."""
        elapsed = self.elapsed_s
        return {
            "ticks": self.tick + 1,
            "rate_hz": round((self.tick + 1) / elapsed, 2) if elapsed > 0 else 0.0,
            "overruns": self.overruns,
            "resyncs": self.resyncs,
            "lateness_ms": self.lateness.summary_ms(),
        }
