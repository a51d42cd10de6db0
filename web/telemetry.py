"""Everything the dashboard receives over ROS 2, kept in ring buffers and counters.

:class:`Subscriptions` makes the dashboard a ROS 2 node (:data:`NODE_NAME`) and subscribes
with :func:`teleop_force.ros2.streams.subscribe` to the slave's ``measured_js``,
``estimated_cf`` (with its ``estimate_diagnostics``), ``true_cf`` and ``status`` and the
master's ``setpoint_js``. The ``on_*`` handlers of :class:`Telemetry` get one decoded message
value and its rmw_zenoh attachment on a Zenoh callback thread: they append one row and update
the counters -- nothing else (no drawing, no allocation beyond the row). Times in the rings
are the messages' own header stamps in seconds since the epoch (``t_ns * 1e-9``), so
estimated and true forces line up whatever the transport delay; loss and latency come from
the attachment (:mod:`web.stats`); ages and rates use ``time.perf_counter``. A sample that
does not decode, has the wrong joint count or no valid attachment is counted per stream as
malformed and dropped.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.errors import MessageError
from teleop_force.ros2 import streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Subscription
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

#: The dashboard's ROS 2 node name.
NODE_NAME: Final = "teleop_force_dashboard"
#: The Omni's joint count; messages with another count are counted as malformed.
N_JOINTS: Final = 3
#: Estimate halves (WrenchStamped, EstimateDiagnostics) one may wait for the other: they come
#: on two threads, which a loaded machine can hold apart for seconds at 1 kHz.
MAX_UNPAIRED_HALVES: Final = 8192
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
STREAMS: Final = ("measured_js", "estimated_cf", "true_cf", "setpoint_js", "status")


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

    def on_joint_state(self, msg: JointState, attachment: Attachment) -> None:
        """Store one JointState of the slave."""
        stats = self.stats["measured_js"]
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        arrival = self._clock()
        stats.record(attachment, arrival, self._wall_ns())
        self.joint_state.append(msg.t_ns * 1e-9, msg.q_rad + msg.qd_rad_s + msg.effort_nm)
        self._joint_state_arrival = arrival

    def on_estimate(self, msg: ForceEstimateMessage, attachment: Attachment) -> None:
        """Store one force estimate (the WrenchStamped and its diagnostics, joined)."""
        stats = self.stats["estimated_cf"]
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        arrival = self._clock()
        stats.record(attachment, arrival, self._wall_ns())
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

    def on_contact(self, msg: ContactForce, attachment: Attachment) -> None:
        """Store one true tip force (``true_cf``)."""
        self.stats["true_cf"].record(attachment, self._clock(), self._wall_ns())
        self.contact.append(msg.t_ns * 1e-9, msg.f_n)

    def on_setpoint(self, msg: JointSetpoint, attachment: Attachment) -> None:
        """Store one setpoint of the master."""
        stats = self.stats["setpoint_js"]
        if msg.n_joints != N_JOINTS:
            stats.record_malformed()
            return
        stats.record(attachment, self._clock(), self._wall_ns())
        self.setpoint.append(msg.t_ns * 1e-9, msg.q_rad)

    def on_status(self, msg: Status, attachment: Attachment) -> None:
        """Keep the latest Status of the slave."""
        arrival = self._clock()
        self.stats["status"].record(attachment, arrival, self._wall_ns())
        with self._status_lock:
            self._status = StatusSample(msg.state, msg.reason, arrival)

    def on_malformed(self, stream: str) -> None:
        """Count one dropped sample of ``stream`` (one of :data:`STREAMS`)."""
        self.stats[stream].record_malformed()

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
    """The ROS 2 subscriptions feeding a :class:`Telemetry`; undeclared by :meth:`close`."""

    def __init__(self, node: Node, telemetry: Telemetry, device: str, master_device: str) -> None:
        """Subscribe on ``node`` to the slave's streams and the master's setpoints."""
        routes: list[tuple[str, topics.Topic, str, streams.MessageCallback]] = [
            ("measured_js", topics.MEASURED_JS, device, telemetry.on_joint_state),
            ("estimated_cf", topics.ESTIMATED_CF, device, telemetry.on_estimate),
            ("true_cf", topics.TRUE_CF, device, telemetry.on_contact),
            ("status", topics.STATUS, device, telemetry.on_status),
            ("setpoint_js", topics.SETPOINT_JS, master_device, telemetry.on_setpoint),
        ]
        self._telemetry = telemetry
        self._by_stream: dict[str, list[Subscription]] = {}
        try:
            for stream, topic, owner, handler in routes:
                # Not ``direct``: the decode (rosbags) runs on a Python thread, off Zenoh's.
                self._by_stream[stream] = streams.subscribe(
                    node, owner, topic, handler, _malformed_counter(telemetry, stream),
                    n_joints=N_JOINTS, max_unpaired=MAX_UNPAIRED_HALVES,
                )  # fmt: skip
        except BaseException:
            self.close()
            raise
        self.keys = tuple(sub.key for subs in self._by_stream.values() for sub in subs)

    def snapshots(self, window_s: float = 1.0) -> dict[str, StreamSnapshot]:
        """:meth:`Telemetry.snapshots`, samples without a valid attachment counted as malformed."""
        snaps = self._telemetry.snapshots(window_s)
        for stream, subs in self._by_stream.items():
            dropped = sum(sub.malformed for sub in subs)
            if dropped:
                snap = snaps[stream]
                snaps[stream] = dataclasses.replace(snap, malformed=snap.malformed + dropped)
        return snaps

    def close(self) -> None:
        """Undeclare every subscription (idempotent; the session may already be closed)."""
        while self._by_stream:
            _, subs = self._by_stream.popitem()
            for sub in subs:
                sub.close()


def _malformed_counter(telemetry: Telemetry, stream: str) -> streams.MalformedCallback:
    def on_malformed(_topic: str, _error: MessageError) -> None:
        telemetry.on_malformed(stream)

    return on_malformed


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
    "NODE_NAME",
    "N_JOINTS",
    "STREAMS",
    "StatusSample",
    "Subscriptions",
    "Telemetry",
]
