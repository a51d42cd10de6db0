"""A simulated sawSensablePhantom driver: the real driver's ROS 2 interface over the simulated Omni.

Run: ``python -m master_slave.sensable_driver --name arm --connect tcp/127.0.0.1:7447``.

A ROS 2 node ``sensable_phantom`` (namespace ``/``, liveliness tokens as rmw_zenoh declares
them) whose topics are those of sawSensablePhantom's CRTK bridge for a device ``<name>``
(the real one: jhu-saw/sawSensablePhantom ``core/components/code/mtsSensableHD.cpp``, bridged
by jhu-cisst/cisst-ros ``cisst_ros_crtk/src/mts_ros_crtk_bridge_provided.cpp``)::

    published every 2 ms (500 Hz, the bridge's default period), one header stamp each:
    /<name>/measured_js  sensor_msgs/msg/JointState, frame "":
                         name     waist, shoulder, elbow, yaw, pitch, roll
                         position rad: the driver's transform of OpenHaptics' raw angles
                                  (waist = -raw1, shoulder = raw2, elbow = raw3 - raw2: the
                                  inverse of builtin_driver("sensable-phantom")); gimbal 0
                         velocity EMPTY (the driver never sizes it)
                         effort   mN m: HD_LAST_JOINT_TORQUE, the joint torque commanded in
                                  the previous 1 ms frame; gimbal 0
    /<name>/measured_cp  geometry_msgs/msg/PoseStamped, frame "base": the tip position [m]
                         from the model's forward kinematics (the model's base origin, not
                         OpenHaptics'); orientation identity (no gimbal is simulated)
    /<name>/measured_cf  geometry_msgs/msg/WrenchStamped, frame "base": HD_LAST_FORCE, the
                         Cartesian force commanded in the previous frame [N]; torque 0

    subscribed:
    /<name>/servo_cf     geometry_msgs/msg/WrenchStamped: the force [N] (torque ignored); its
                         norm is clamped to 2 N (m_max_force), applied as tau = J(q)^T F and
                         kept, with no timeout, until the next command
    /<name>/servo_cp     geometry_msgs/msg/PoseStamped: the translation [m] (orientation
                         ignored) the driver's Cartesian PD tracks, as hold below
    /<name>/hold         std_msgs/msg/Empty: servo_cp to the position measured then: the
                         driver's Cartesian PD, F = -100 N/m (p - p_hold) - 3 N s/m v, clamped
    /<name>/free         std_msgs/msg/Empty: servo_cf of a zero force

There is no joint-space command (no servo_jp / servo_jf: the driver provides none). The
device loop runs at 1 kHz (``hdSetSchedulerRate(1000)``): every 1 ms frame the plant
(:class:`~teleop_force.simulation.plant.SimulatedOmni`, its spring and friction, no tissue
unless ``--surface-y``) is read, commanded and stepped
(:mod:`teleop_force.simulation.sensable_driver`); every second frame is published. No gravity
compensation is added (the real ``use_gravity_compensation`` does nothing): a free arm settles
where gravity, the plant's spring and friction balance. Malformed commands are counted and
dropped. What is not reproduced: docs/real_robot.md, "The simulated driver".
"""

from __future__ import annotations

import argparse
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np
import zenoh

from master_slave.realtime import LoopConfig, RateLoop
from teleop_force.errors import ConfigurationError, DataError, MessageError, TeleopForceError
from teleop_force.process.lifetime import StopSignal, log, use_realtime_switch_interval, write_json
from teleop_force.ros2 import codec, fast_cdr, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node
from teleop_force.simulation import PlaneContact, PlantConfig, SimulatedOmni
from teleop_force.simulation.sensable_driver import (
    JOINT_NAMES,
    DeviceFrame,
    SensableSettings,
    SimulatedSensableDevice,
)
from teleop_force.transport.session import add_zenoh_arguments, open_session, options_from_args

ROLE = "sensable_driver"
#: The node's name (the real bridge's node name was not read; this one is ours).
NODE_NAME: Final = "sensable_phantom"
#: The device loop (hdSetSchedulerRate(1000)) and the bridge's period (2 ms).
DEVICE_RATE_HZ: Final = 1000.0
FRAMES_PER_MESSAGE: Final = 2
BASE_FRAME: Final = "base"

FrameCallback = Callable[[DeviceFrame, int], None]


class SensableDriverNode:
    """The driver's ROS 2 node on ``session`` over ``device``; :meth:`run` runs its loop.

    ``on_frame(frame, stamp_ns)`` (tests) sees every frame that is published, before it is.
    """

    def __init__(
        self,
        session: zenoh.Session,
        name: str,
        device: SimulatedSensableDevice,
        *,
        on_frame: FrameCallback | None = None,
        freeze_gc: bool = False,
    ) -> None:
        """Declare the node, its three publishers and three subscriptions.

        ``freeze_gc``: freeze the heap when the loop starts (a process; process-wide).
        """
        self.name = topics.validate_device(name)
        self.device = device
        self._on_frame = on_frame
        self.malformed = 0
        self.last_malformed = ""
        self.published = 0
        self._lock = threading.Lock()
        codec.warm_up()  # rosbags compiles on first use: not in the loop
        self._joint_state = fast_cdr.JointStateLayout(JOINT_NAMES, velocities=False)
        self._wrench = fast_cdr.WrenchLayout(BASE_FRAME)
        self.node = Node(session, NODE_NAME)
        try:
            self._js = self.node.publisher(self._topic("measured_js"), interfaces.JOINT_STATE)
            self._cp = self.node.publisher(self._topic("measured_cp"), interfaces.POSE_STAMPED)
            self._cf = self.node.publisher(self._topic("measured_cf"), interfaces.WRENCH_STAMPED)
            self.node.subscription(
                self._topic("servo_cf"), interfaces.WRENCH_STAMPED, self._on_servo_cf
            )
            self.node.subscription(
                self._topic("servo_cp"), interfaces.POSE_STAMPED, self._on_servo_cp
            )
            self.node.subscription(self._topic("hold"), interfaces.EMPTY, self._on_hold)
            self.node.subscription(self._topic("free"), interfaces.EMPTY, self._on_free)
        except BaseException:
            self.node.close()
            raise
        self.loop = RateLoop(LoopConfig(rate_hz=DEVICE_RATE_HZ, freeze_gc=freeze_gc))

    def _topic(self, kind: str) -> str:
        return f"/{self.name}/{kind}"

    # -- commands (Zenoh's callback threads) ---------------------------------------------------

    def _count_malformed(self, what: str, exc: Exception) -> None:
        with self._lock:
            self.malformed += 1
            self.last_malformed = f"{what}: {exc}"

    def _on_servo_cf(self, payload: bytes, attachment: Attachment) -> None:
        try:
            wrench = codec.decode_wrench(payload)
            self.device.servo_cf(wrench.force_n)
        except (MessageError, DataError) as exc:
            self._count_malformed("servo_cf", exc)

    def _on_servo_cp(self, payload: bytes, attachment: Attachment) -> None:
        try:
            self.device.servo_cp(codec.decode_pose(payload).position_m)
        except (MessageError, DataError) as exc:
            self._count_malformed("servo_cp", exc)

    def _on_hold(self, payload: bytes, attachment: Attachment) -> None:
        try:
            codec.decode_empty(payload)
        except MessageError as exc:
            self._count_malformed("hold", exc)
            return
        self.device.hold()

    def _on_free(self, payload: bytes, attachment: Attachment) -> None:
        try:
            codec.decode_empty(payload)
        except MessageError as exc:
            self._count_malformed("free", exc)
            return
        self.device.free()

    # -- the loop ------------------------------------------------------------------------------

    def publish(self, frame: DeviceFrame, stamp_ns: int) -> None:
        """Publish one frame's measured_js, measured_cp and measured_cf (one stamp)."""
        if self._on_frame is not None:
            self._on_frame(frame, stamp_ns)
        self._js.publish(self._joint_state.pack(stamp_ns, frame.position, (), frame.effort_mnm))
        self._cp.publish(codec.encode_pose(stamp_ns, frame.tip_in_base_m, BASE_FRAME))
        self._cf.publish(self._wrench.pack(stamp_ns, frame.last_force_in_base_n))
        self.published += 1

    def run(self, stop: Callable[[], bool], duration_s: float | None = None) -> None:
        """Run frames at 1 kHz, publishing every second, until ``stop()`` or ``duration_s``."""
        loop, device = self.loop, self.device
        n_frames = None if duration_s is None else round(duration_s * DEVICE_RATE_HZ)
        loop.start()
        while not stop():
            k = loop.wait()
            if n_frames is not None and k >= n_frames:
                break
            frame = device.frame()
            if k % FRAMES_PER_MESSAGE == 0:
                self.publish(frame, loop.stamp_ns)

    def stats(self) -> dict[str, Any]:
        """Frames, messages, commands and malformed commands."""
        with self._lock:
            malformed = {"dropped": self.malformed, "last": self.last_malformed}
        return {
            "loop": self.loop.stats(),
            "published": self.published,
            "commands": dict(self.device.commands),
            "mode": self.device.mode.value,
            "malformed": malformed,
        }

    def close(self) -> None:
        """Undeclare every entity and the node's token."""
        self.node.close()


def build_plant(
    seed: int = 0, surface_y_m: float | None = None, q0_rad: Sequence[float] | None = None
) -> SimulatedOmni:
    """Return the simulated Omni (1 kHz ticks) at ``q0_rad``, default mid-range.

    A tissue plane at ``surface_y_m`` if given.
    """
    contact = None if surface_y_m is None else PlaneContact.horizontal(surface_y_m)
    q0 = None if q0_rad is None else np.asarray(q0_rad, dtype=float)
    config = PlantConfig(control_period_s=1.0 / DEVICE_RATE_HZ)
    return SimulatedOmni(config, seed=seed, contact=contact, q0_rad=q0)


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m master_slave.sensable_driver``."""
    parser = argparse.ArgumentParser(
        prog="python -m master_slave.sensable_driver", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--name", default="arm", help="device name, /<name>/... (default arm)")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    parser.add_argument("--seed", type=int, default=0, help="seed of the actuator noise")
    parser.add_argument(
        "--surface-y", type=float, default=None, metavar="M",
        help="a tissue plane at this height [m] (default: free space)",
    )  # fmt: skip
    parser.add_argument(
        "--q0-rad", type=float, nargs=3, default=None, metavar=("Q1", "Q2", "Q3"),
        help="the arm's starting angles in the model's coordinates (default: mid-range)",
    )  # fmt: skip
    parser.add_argument(
        "--max-force", type=float, default=2.0, metavar="N",
        help="m_max_force: the force norm limit [N] (default 2, the driver's)",
    )  # fmt: skip
    parser.add_argument(
        "--stats-json", default=None, metavar="PATH", help="final stats (- = stdout)"
    )
    add_zenoh_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulated driver until SIGINT / SIGTERM or ``--duration``; return the status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    use_realtime_switch_interval()
    try:
        if args.duration is not None and not args.duration > 0:
            raise ConfigurationError(f"--duration must be > 0, got {args.duration}")
        device = SimulatedSensableDevice(
            build_plant(args.seed, args.surface_y, args.q0_rad),
            SensableSettings(max_force_n=args.max_force),
        )
        session = open_session(options_from_args(args))
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        driver = SensableDriverNode(session, args.name, device, freeze_gc=True)
        try:
            log(ROLE, f"/{args.name}: simulated sawSensablePhantom, 1 kHz device, 500 Hz topics")
            driver.run(stop.is_set, args.duration)
        finally:
            driver.close()
        stats = driver.stats()
    except TeleopForceError as exc:
        log(ROLE, f"error: {exc}")
        return 2
    finally:
        session.close()
    if args.stats_json:
        write_json(args.stats_json, stats)
    log(ROLE, f"stopped after {stats['loop']['ticks']} frames, {stats['published']} messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
