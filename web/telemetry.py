"""Everything the dashboard receives over Zenoh, kept in ring buffers and counters.

The ``on_*`` handlers run on Zenoh's threads: they decode one message, append one row and
update the counters -- nothing else (no drawing, no allocation beyond the decode). Times in
the rings are the messages' own source stamps in seconds since the epoch (``t_ns * 1e-9``),
so estimated and true forces line up whatever the transport delay; ages and rates use
``time.perf_counter``.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import zenoh

from teleop_force.transport import keys
from teleop_force.transport.messages import (
    ContactForce,
    ForceEstimateMessage,
    JointSetpoint,
    JointState,
    SafetyState,
    Status,
)
from web.buffers import RingBuffer
from web.stats import StreamSnapshot, StreamStats

#: The Omni's joint count; messages with another count are counted as malformed.
N_JOINTS: Final = 3
#: Rows kept per 1 kHz stream (a bit more than 16 s at 1 kHz).
DEFAULT_CAPACITY: Final = 16384

# Columns of the joint-state ring.
JS_Q: Final = slice(0, 3)
JS_QD: Final = slice(3, 6)
JS_EFFORT: Final = slice(6, 9)
JS_WIDTH: Final = 9
# Columns of the force-estimate ring.
FE_F: Final = slice(0, 3)
FE_TAU_EXT: Final = slice(3, 6)
FE_COVERAGE: Final = slice(6, 9)
FE_TAU_MOTOR: Final = slice(9, 12)
FE_TAU_MODEL: Final = slice(12, 15)
FE_TRAINED: Final = slice(15, 18)
FE_SOURCE_SEQ: Final = 18
FE_WIDTH: Final = 19

#: Stream names used in statistics tables.
STREAMS: Final = ("measured_js", "estimated_cf", "measured_cf", "setpoint_js", "status")


@dataclass(frozen=True)
class StatusSample:
    """The last safety status received and when (perf_counter seconds)."""

    state: SafetyState
    reason: str
    arrival_s: float


class Telemetry:
    """Ring buffers and counters of one slave (and the setpoints of its master)."""

    def __init__(
        self,
        capacity: int = DEFAULT_CAPACITY,
        clock: Callable[[], float] = time.perf_counter,
        wall_clock_ns: Callable[[], int] = time.time_ns,
    ) -> None:
        """Allocate the rings; ``clock`` and ``wall_clock_ns`` are injectable for tests."""
        self.joint_state = RingBuffer(capacity, JS_WIDTH)
        self.estimate = RingBuffer(capacity, FE_WIDTH)
        self.contact = RingBuffer(capacity, 3)
        self.setpoint = RingBuffer(256, N_JOINTS)
        self.stats = {name: StreamStats() for name in STREAMS}
        self._clock = clock
        self._wall_ns = wall_clock_ns
        self._status: StatusSample | None = None
        self._status_lock = threading.Lock()
        self._last_untrained = np.full(N_JOINTS, -math.inf)  # perf time, per joint
        self._estimate_arrival = -math.inf
        self._joint_state_arrival = -math.inf

    # -- handlers (Zenoh threads) ------------------------------------------------------

    def on_joint_state(self, payload: bytes) -> None:
        """Decode and store one JointState."""
        stats = self.stats["measured_js"]
        try:
            msg = JointState.decode(payload)
        except Exception:
            stats.record_malformed()
            return
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        arrival = self._clock()
        stats.record(msg.seq, msg.t_ns, arrival, self._wall_ns())
        self.joint_state.append(msg.t_ns * 1e-9, msg.q_rad + msg.qd_rad_s + msg.effort_nm)
        self._joint_state_arrival = arrival

    def on_estimate(self, payload: bytes) -> None:
        """Decode and store one ForceEstimate message."""
        stats = self.stats["estimated_cf"]
        try:
            msg = ForceEstimateMessage.decode(payload)
        except Exception:
            stats.record_malformed()
            return
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        arrival = self._clock()
        stats.record(msg.seq, msg.t_ns, arrival, self._wall_ns())
        trained = tuple(1.0 if flag else 0.0 for flag in msg.on_trained_ground)
        row = (
            msg.f_n + msg.tau_ext_nm + msg.coverage_weight + msg.tau_motor_filtered_nm
            + msg.tau_model_filtered_nm + trained + (float(msg.source_seq),)
        )  # fmt: skip
        self.estimate.append(msg.t_ns * 1e-9, row)
        for j, flag in enumerate(msg.on_trained_ground):
            if not flag:
                self._last_untrained[j] = arrival
        self._estimate_arrival = arrival

    def on_contact(self, payload: bytes) -> None:
        """Decode and store one ground-truth ContactForce."""
        stats = self.stats["measured_cf"]
        try:
            msg = ContactForce.decode(payload)
        except Exception:
            stats.record_malformed()
            return
        stats.record(msg.seq, msg.t_ns, self._clock(), self._wall_ns())
        self.contact.append(msg.t_ns * 1e-9, msg.f_n)

    def on_setpoint(self, payload: bytes) -> None:
        """Decode and store one master JointSetpoint."""
        stats = self.stats["setpoint_js"]
        try:
            msg = JointSetpoint.decode(payload)
        except Exception:
            stats.record_malformed()
            return
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        stats.record(msg.seq, msg.t_ns, self._clock(), self._wall_ns())
        self.setpoint.append(msg.t_ns * 1e-9, msg.q_rad)

    def on_status(self, payload: bytes) -> None:
        """Decode and keep the latest Status."""
        stats = self.stats["status"]
        try:
            msg = Status.decode(payload)
        except Exception:
            stats.record_malformed()
            return
        arrival = self._clock()
        stats.record(msg.seq, msg.t_ns, arrival, self._wall_ns())
        with self._status_lock:
            self._status = StatusSample(msg.state, msg.reason, arrival)

    # -- readers (render thread) -------------------------------------------------------

    def status(self) -> StatusSample | None:
        """Return the last Status received, if any."""
        with self._status_lock:
            return self._status

    def status_age_s(self) -> float:
        """Seconds since the last Status arrived (``inf`` if none)."""
        status = self.status()
        return math.inf if status is None else self._clock() - status.arrival_s

    def estimate_age_s(self) -> float:
        """Seconds since the last ForceEstimate arrived (``inf`` if none)."""
        return self._clock() - self._estimate_arrival

    def joint_state_age_s(self) -> float:
        """Seconds since the last JointState arrived (``inf`` if none)."""
        return self._clock() - self._joint_state_arrival

    def untrained_joints(self, hold_s: float) -> tuple[int, ...]:
        """Joints reported off trained ground within the last ``hold_s`` seconds."""
        since = self._clock() - self._last_untrained
        return tuple(int(j) for j in np.flatnonzero(since <= hold_s))

    def snapshots(self, window_s: float = 1.0) -> dict[str, StreamSnapshot]:
        """Statistics of every stream."""
        now = self._clock()
        return {name: s.snapshot(now, window_s) for name, s in self.stats.items()}


class Subscriptions:
    """The Zenoh subscribers feeding a :class:`Telemetry`; undeclared by :meth:`close`."""

    def __init__(
        self, session: zenoh.Session, telemetry: Telemetry, device: str, master_device: str
    ) -> None:
        """Subscribe to the slave's streams and the master's setpoints."""
        routes: list[tuple[str, Callable[[bytes], None]]] = [
            (keys.measured_js(device), telemetry.on_joint_state),
            (keys.estimated_cf(device), telemetry.on_estimate),
            (keys.measured_cf(device), telemetry.on_contact),
            (keys.status(device), telemetry.on_status),
            (keys.setpoint_js(master_device), telemetry.on_setpoint),
        ]
        self.keys = tuple(key for key, _ in routes)
        self._subscribers: list[Any] = []
        try:
            for key, handler in routes:
                self._subscribers.append(
                    session.declare_subscriber(key, _payload_callback(handler))
                )
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Undeclare every subscriber (idempotent)."""
        while self._subscribers:
            sub = self._subscribers.pop()
            with contextlib.suppress(Exception):  # the session may already be closed
                sub.undeclare()


def _payload_callback(handler: Callable[[bytes], None]) -> Callable[[zenoh.Sample], None]:
    def callback(sample: zenoh.Sample) -> None:
        handler(sample.payload.to_bytes())

    return callback


__all__ = [
    "DEFAULT_CAPACITY",
    "FE_COVERAGE",
    "FE_F",
    "FE_SOURCE_SEQ",
    "FE_TAU_EXT",
    "FE_TAU_MODEL",
    "FE_TAU_MOTOR",
    "FE_TRAINED",
    "FE_WIDTH",
    "JS_EFFORT",
    "JS_Q",
    "JS_QD",
    "JS_WIDTH",
    "N_JOINTS",
    "STREAMS",
    "StatusSample",
    "Subscriptions",
    "Telemetry",
]
