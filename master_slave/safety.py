"""The slave's safety state machine: follow the master only while it is alive and fresh.

States (:class:`~teleop_force.transport.messages.SafetyState`)::

    STARTING  --(token present, setpoints fresh, resume_count received)-->  FOLLOWING
    FOLLOWING --(token gone, or last setpoint older than stale_s)-------->  HOLDING
    HOLDING   --(token present, setpoints fresh, resume_count new ones)-->  FOLLOWING

The monitor is pure logic (time is passed in), evaluated once per control tick; the slave
applies the hold in the same tick it is decided, so the hold starts within one tick of the
detection. "Fresh" is measured on the slave's monotonic clock from the *arrival* of the last
setpoint, so it does not depend on the master's clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from teleop_force.errors import ConfigurationError
from teleop_force.transport.messages import SafetyState


@dataclass(frozen=True)
class SafetyConfig:
    """Thresholds of :class:`SafetyMonitor`.

    Attributes:
        stale_s: A setpoint older than this makes the slave hold [s].
        resume_count: Setpoints that must arrive while holding (or starting) before the
            slave follows again (a burst of one stray message is not enough).

    """

    stale_s: float = 0.05
    resume_count: int = 10

    def __post_init__(self) -> None:
        """Check the ranges."""
        if not (math.isfinite(self.stale_s) and 0.0 < self.stale_s <= 10.0):
            raise ConfigurationError(f"stale_s must be in (0, 10], got {self.stale_s}")
        if self.resume_count < 1:
            raise ConfigurationError(f"resume_count must be >= 1, got {self.resume_count}")


@dataclass(frozen=True)
class SafetyDecision:
    """The state after one evaluation, why, and whether it just changed."""

    state: SafetyState
    reason: str
    changed: bool

    def __post_init__(self) -> None:
        """Normalise the state to a :class:`SafetyState`."""
        object.__setattr__(self, "state", SafetyState(self.state))


class SafetyMonitor:
    """Decide each tick whether the slave follows the master or holds (module docstring)."""

    def __init__(self, config: SafetyConfig | None = None) -> None:
        """Start in STARTING."""
        self.config = config if config is not None else SafetyConfig()
        self.state = SafetyState.STARTING
        self.reason = "waiting for the master"
        self.holds = 0
        self._count_at_hold = 0
        self._unchanged = SafetyDecision(self.state, self.reason, False)

    def update(
        self,
        now_s: float,
        master_alive: bool,
        last_setpoint_s: float | None,
        setpoints_received: int,
    ) -> SafetyDecision:
        """Evaluate at monotonic time ``now_s``.

        Args:
            now_s: Current monotonic time [s].
            master_alive: Whether the master's liveliness token is present.
            last_setpoint_s: Monotonic arrival time of the latest setpoint (``None``: none yet).
            setpoints_received: Number of valid setpoints received so far.

        """
        age_s = math.inf if last_setpoint_s is None else now_s - last_setpoint_s
        fresh = age_s <= self.config.stale_s
        if self.state == SafetyState.FOLLOWING:
            if not master_alive:
                return self._enter(
                    SafetyState.HOLDING, "master liveliness token lost", setpoints_received
                )
            if not fresh:
                return self._enter(
                    SafetyState.HOLDING,
                    f"master setpoint stale: {age_s * 1e3:.1f} ms "
                    f"> {self.config.stale_s * 1e3:g} ms",
                    setpoints_received,
                )
            return self._unchanged
        if self.state in (SafetyState.STARTING, SafetyState.HOLDING):
            new = setpoints_received - self._count_at_hold
            if master_alive and fresh and new >= self.config.resume_count:
                return self._enter(
                    SafetyState.FOLLOWING, "following the master", setpoints_received
                )
        return self._unchanged

    def stop(self, reason: str) -> SafetyDecision:
        """Enter STOPPED (the process is shutting down)."""
        return self._enter(SafetyState.STOPPED, reason, self._count_at_hold)

    def _enter(self, state: SafetyState, reason: str, count: int) -> SafetyDecision:
        if state == SafetyState.HOLDING:
            self.holds += 1
        self.state = state
        self.reason = reason
        self._count_at_hold = count
        self._unchanged = SafetyDecision(state, reason, False)  # what the next ticks return
        return SafetyDecision(state, reason, True)
