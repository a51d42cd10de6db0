"""Teleoperation through two drivers: the slave follows the master, the master feels the force.

    python -m master_slave.driver_teleop --master master --slave slave --connect tcp/...

sawSensablePhantom takes no joint-space command; what it accepts for following is
``servo_cp`` (``geometry_msgs/msg/PoseStamped``, a translation-only PD in the driver). So
every ``1 / rate_hz`` s (default 500 Hz, the driver's rate) this process

- forwards the master's latest ``/<master>/measured_cp`` to ``/<slave>/servo_cp`` (the two
  devices share the base frame's convention; the pose is sent as received). A pose older than
  ``stale_s``, none yet, or one that is not a number sends ``/<slave>/hold``
  (``std_msgs/msg/Empty``) once, and nothing more until a fresh pose arrives: a lost master
  makes the slave hold;
- publishes on
  ``/<master>/servo_cf`` (``geometry_msgs/msg/WrenchStamped``, frame ``base``) the force
  :func:`feedback_force_n` makes of the latest ``/<slave>/estimated_cf``: ``-scale F``,
  clipped to ``max_force_n`` (the driver's own clamp is 2.0 N).

The master driver keeps the last force with no timeout, so "no feedback" is always sent as a
zero force, never as silence:

- an estimate older than ``stale_s`` (a lost service, a lost link), none yet, or one that is
  not a number gives a zero force on the next tick;
- on exit (SIGINT, SIGTERM, ``--duration``, an error) a zero force and ``/<master>/free``, and
  ``/<slave>/hold``;
- when this process dies any other way (SIGKILL, a crash), its
  :mod:`~master_slave.force_watchdog` child, started before the first command, sends them.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from master_slave.force_watchdog import (
    HOLD,
    ForceWatchdog,
    ZeroForceSender,
    start_force_watchdog,
)
from master_slave.master import FeedbackInbox
from teleop_force.errors import ConfigurationError, MessageError, TeleopForceError
from teleop_force.process.lifetime import StopSignal, log, write_json
from teleop_force.ros2 import interfaces
from teleop_force.ros2 import topics as ros2_topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.codec import decode_pose, encode_empty, encode_wrench
from teleop_force.ros2.node import Node
from teleop_force.transport.session import add_zenoh_arguments, open_session, options_from_args

ROLE: Final = "driver-teleop"
SERVO_CP: Final = "servo_cp"
MEASURED_CP: Final = "measured_cp"
#: sawSensablePhantom's force clamp (``m_max_force = 2.0``) [N].
DRIVER_MAX_FORCE_N: Final = 2.0


@dataclass(frozen=True)
class FeedbackConfig:
    """Settings of the feedback process.

    Attributes:
        master: The master driver's namespace (its ``measured_cp`` is followed, its
            ``servo_cf`` commanded).
        slave: The slave driver's namespace (its ``servo_cp`` is commanded) and the device
            whose ``estimated_cf`` is fed back.
        scale: Force scaling, 0..1.
        max_force_n: Clip of the commanded force's norm [N].
        stale_s: An estimate older than this gives a zero force, a master pose older than
            this makes the slave hold [s].
        rate_hz: Command rate.
        duration_s: Stop after this long (``None``: until SIGINT / SIGTERM).
        watchdog: Start the watchdog child (off only in tests of the process's own exit).

    """

    master: str = "master"
    slave: str = "slave"
    scale: float = 0.5
    max_force_n: float = DRIVER_MAX_FORCE_N
    stale_s: float = 0.05
    rate_hz: float = 500.0
    duration_s: float | None = None
    watchdog: bool = True

    def __post_init__(self) -> None:
        """Validate the names and ranges."""
        ros2_topics.validate_device(self.master)
        ros2_topics.validate_device(self.slave)
        if not (math.isfinite(self.scale) and 0.0 <= self.scale <= 1.0):
            raise ConfigurationError(f"scale must be in [0, 1], got {self.scale}")
        for name in ("max_force_n", "stale_s", "rate_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigurationError(f"{name} must be finite and > 0, got {value}")
        if self.duration_s is not None and not self.duration_s > 0.0:
            raise ConfigurationError(f"duration_s must be > 0, got {self.duration_s}")


def feedback_force_n(
    estimate_n: np.ndarray, age_s: float | None, config: FeedbackConfig
) -> np.ndarray:
    """Return ``-scale F`` clipped to ``max_force_n``; zero if stale, missing or NaN."""
    if age_s is None or not age_s <= config.stale_s or not np.all(np.isfinite(estimate_n)):
        return np.zeros(3)
    force = -config.scale * np.asarray(estimate_n, dtype=float)
    norm = float(np.linalg.norm(force))
    if norm > config.max_force_n:
        force *= config.max_force_n / norm
    return force


class SlaveFollower:
    """The master's pose forwarded to the slave's ``servo_cp``; ``hold`` when it goes stale."""

    def __init__(self, node: Node, config: FeedbackConfig) -> None:
        """Subscribe to the master's pose, declare the slave's command publishers."""
        self.config = config
        self._lock = threading.Lock()
        self._pose: bytes | None = None
        self._arrival_s: float | None = None
        self.following = False
        self.forwarded = 0
        self.holds = 0
        self.malformed = 0
        node.subscription(f"/{config.master}/{MEASURED_CP}", interfaces.POSE_STAMPED, self._on_pose)
        self._servo_cp = node.publisher(f"/{config.slave}/{SERVO_CP}", interfaces.POSE_STAMPED)
        self._hold = node.publisher(f"/{config.slave}/{HOLD}", interfaces.EMPTY)
        self._empty = encode_empty()

    def _on_pose(self, payload: bytes, attachment: Attachment) -> None:
        try:
            position_m = decode_pose(payload).position_m
        except MessageError:
            position_m = (math.nan, math.nan, math.nan)
        with self._lock:
            if not all(math.isfinite(v) for v in position_m):
                self.malformed += 1  # counted and dropped: the pose goes stale, the slave holds
                return
            self._pose, self._arrival_s = bytes(payload), time.perf_counter()

    def tick(self) -> bool:
        """Forward the latest pose if fresh, else hold once; return whether it follows."""
        with self._lock:
            pose, arrival_s = self._pose, self._arrival_s
        fresh = arrival_s is not None and time.perf_counter() - arrival_s <= self.config.stale_s
        if fresh and pose is not None:
            self._servo_cp.publish(pose)
            self.forwarded += 1
            self.following = True
        elif self.following or self.holds == 0:
            self.hold()
        return self.following

    def hold(self) -> None:
        """Send ``hold`` to the slave driver."""
        self._hold.publish(self._empty)
        self.holds += 1
        self.following = False

    def stats(self) -> dict[str, Any]:
        """Poses forwarded, holds sent, malformed poses dropped."""
        with self._lock:
            malformed = self.malformed
        return {"forwarded": self.forwarded, "holds": self.holds, "malformed": malformed}


class DriverFeedback:
    """The subscription, the command publisher, the zero-force sender and the counters."""

    def __init__(self, node: Node, config: FeedbackConfig) -> None:
        """Subscribe to the estimate and declare the driver's command publishers."""
        self.config = config
        self.inbox = FeedbackInbox()
        self.sent = 0
        self.zeros_sent = 0
        node.subscription(
            ros2_topics.topic_name(config.slave, ros2_topics.ESTIMATED_CF),
            ros2_topics.ESTIMATED_CF.ros_type,
            self.inbox.on_sample,
        )
        self.zero = ZeroForceSender(node, config.master)  # its servo_cf publisher is ours too

    def tick(self) -> np.ndarray:
        """Command the force of the latest estimate (zero if none is fresh); return it."""
        estimate_n, arrival_s = self.inbox.latest()
        age_s = None if arrival_s is None else time.perf_counter() - arrival_s
        force = feedback_force_n(estimate_n, age_s, self.config)
        self.zero.servo_cf.publish(
            encode_wrench(time.time_ns(), force.tolist(), ros2_topics.BASE_FRAME)
        )
        self.sent += 1
        if not force.any():
            self.zeros_sent += 1
        return force

    def stats(self) -> dict[str, Any]:
        """Commands sent, of which zero, and the estimate stream's counters."""
        return {"sent": self.sent, "zeros_sent": self.zeros_sent, "estimates": self.inbox.stats()}


def run(config: FeedbackConfig, args: argparse.Namespace, stop: StopSignal) -> dict[str, Any]:
    """Arm the watchdog, command at ``rate_hz`` until stopped, then zero, free, hold; stats."""
    options = options_from_args(args)
    watchdog: ForceWatchdog | None = None
    if config.watchdog:
        watchdog = start_force_watchdog(config.master, options.connect, hold=(config.slave,))
    try:
        session = open_session(options)
        try:
            node = Node(session, "teleop_force_driver_teleop")
            follower = SlaveFollower(node, config)
            feedback = DriverFeedback(node, config)
            try:
                period_s = 1.0 / config.rate_hz
                started_s = next_s = time.monotonic()
                while not stop.is_set():
                    if config.duration_s is not None and next_s - started_s >= config.duration_s:
                        break
                    follower.tick()
                    feedback.tick()
                    next_s += period_s
                    stop.wait(max(0.0, next_s - time.monotonic()))
            finally:
                feedback.zero.send()
                follower.hold()
                node.close()
            return {"follow": follower.stats(), "feedback": feedback.stats()}
        finally:
            session.close()
    finally:
        if watchdog is not None:
            watchdog.release()


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of ``python -m master_slave.driver_teleop``."""
    parser = argparse.ArgumentParser(
        prog="python -m master_slave.driver_teleop", description=__doc__.splitlines()[0]
    )
    defaults = FeedbackConfig()
    parser.add_argument("--master", default=defaults.master, help="master driver's namespace")
    parser.add_argument("--slave", default=defaults.slave, help="device whose estimate is fed back")
    parser.add_argument("--scale", type=float, default=defaults.scale, help="force scale, 0..1")
    parser.add_argument(
        "--max-force-n", type=float, default=defaults.max_force_n, help="clip of |F| [N]"
    )
    parser.add_argument(
        "--stale-ms", type=float, default=1e3 * defaults.stale_s, help="estimate age limit [ms]"
    )
    parser.add_argument("--rate-hz", type=float, default=defaults.rate_hz, help="command rate")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    parser.add_argument(
        "--stats-json", default=None, metavar="PATH", help="final stats (- = stdout)"
    )
    parser.add_argument(
        "--no-watchdog", action="store_true", help="no watchdog child (tests of a clean exit)"
    )
    add_zenoh_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run until SIGINT / SIGTERM or ``--duration``; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install()
    try:
        config = FeedbackConfig(
            master=args.master,
            slave=args.slave,
            scale=args.scale,
            max_force_n=args.max_force_n,
            stale_s=args.stale_ms * 1e-3,
            rate_hz=args.rate_hz,
            duration_s=args.duration,
            watchdog=not args.no_watchdog,
        )
        stats = run(config, args, stop)
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    if args.stats_json:
        write_json(args.stats_json, stats)
    feedback, follow = stats["feedback"], stats["follow"]
    log(
        ROLE,
        f"stopped: {follow['forwarded']} poses forwarded, {follow['holds']} holds; "
        f"{feedback['sent']} forces sent, {feedback['zeros_sent']} of them zero",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
