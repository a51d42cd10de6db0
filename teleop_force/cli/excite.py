"""``teleop-force excite``: the training trajectory played through a live driver, and recorded.

Identifying a real arm needs free motion that fills the velocities it will work at, recorded
through the path the service reads: the driver's JointStates, at its rate, in its conventions.
sawSensablePhantom takes no joint command; what it follows is ``servo_cp`` (a tip position its
own translation-only Cartesian PD tracks). So the command:

1. reads the driver's ``/<device>/measured_js`` and ``/<device>/measured_cp`` (exit 2, naming
   the topic, if one stays silent for ``--wait-s``) and takes the offset between the model's
   base origin and the driver's Cartesian origin from one pose (the model's tip of the
   converted angles against measured_cp);
2. builds the training trajectory
   (:func:`~teleop_force.identification.training_trajectory.training_trajectory`) of the
   velocity region asked, inside the model's joint limits less ``--margin-rad``, after a
   minimum-jerk ramp in joint space from where the arm is;
3. records every ROS 2 message of the domain to ``-o`` with
   :class:`~teleop_force.service.ros2_recorder.Ros2Recorder` (the demo's recorder), its
   metadata naming the driver description (so ``identify`` converts the joint states);
4. sends each joint reference through the model's forward kinematics, in the driver's frame,
   as ``servo_cp`` at the description's ``rate_hz``;
5. ends, always (the end, Ctrl-C, SIGTERM, an error, a driver that stops publishing), with a
   zero ``servo_cf`` and then ``hold`` (50 ms apart: the two are on different topics, whose
   order on arrival is not guaranteed, and the last command must be the hold).

Killed outright (SIGKILL), it sends nothing more: the driver keeps servoing to the last
``servo_cp`` (a command it keeps with no timeout), which holds the arm at that point.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, MessageError, TransportError
from teleop_force.ros2 import interfaces, topics
from teleop_force.transport.session import add_zenoh_arguments

if TYPE_CHECKING:  # the CLI builds its flags without rosbags or zenoh
    from teleop_force.robots.driver_interface import DriverInterface
    from teleop_force.ros2.attachment import Attachment
    from teleop_force.ros2.node import Node, Publisher

#: The driver's Cartesian position command (CRTK ``servo_cp``), its base frame, m.
SERVO_CP: Final = topics.Topic("servo_cp", interfaces.POSE_STAMPED)
#: The driver's Cartesian force command (CRTK ``servo_cf``), N.
SERVO_CF: Final = topics.Topic("servo_cf", interfaces.WRENCH_STAMPED)
#: The driver's ``hold`` (``std_msgs/msg/Empty``): servo_cp to where the arm is.
HOLD: Final = topics.Topic("hold", interfaces.EMPTY)
#: The driver's tip pose (CRTK ``measured_cp``), m.
MEASURED_CP: Final = topics.Topic("measured_cp", interfaces.POSE_STAMPED)

DEFAULT_DURATION_S: Final = 120.0
#: Half-widths of the velocity region [rad/s] of q1, q2, q3 (a hand on a master arm).
DEFAULT_VELOCITY_RAD_S: Final = (0.6, 0.8, 0.8)
#: The largest half-width accepted [rad/s]: faster is not a hand's motion, and not safe.
MAX_VELOCITY_RAD_S: Final = 2.0
DEFAULT_MARGIN_RAD: Final = 0.2
DEFAULT_RAMP_S: Final = 3.0
DEFAULT_WAIT_S: Final = 3.0
#: measured_js silent this long during the motion: the driver is gone, hold [s].
STALE_S: Final = 0.5
#: Recorded before the motion starts and after hold [s].
REST_S: Final = 0.5
#: How often a progress line is printed [s].
PROGRESS_S: Final = 10.0
EXIT_INTERRUPTED: Final = 130


@dataclass(frozen=True)
class ExcitationConfig:
    """What to play: the trajectory's length, velocity region, limits margin, ramp and seed.

    Attributes:
        duration_s: The training trajectory's length, after the ramp [s].
        velocity_rad_s: Half-widths of the velocity region of q1, q2, q3 [rad/s]
            (``VelocityRegion((-v1, v1), ...)``).
        margin_rad: Kept from each end of the model's joint ranges [rad].
        ramp_s: The minimum-jerk ramp from the arm's pose to the trajectory's start [s].
        seed: The trajectory's phases.
        rate_hz: servo_cp commands per second (the driver's ``rate_hz``).

    """

    duration_s: float = DEFAULT_DURATION_S
    velocity_rad_s: tuple[float, float, float] = DEFAULT_VELOCITY_RAD_S
    margin_rad: float = DEFAULT_MARGIN_RAD
    ramp_s: float = DEFAULT_RAMP_S
    seed: int = 0
    rate_hz: float = 500.0

    def __post_init__(self) -> None:
        """Check every value is finite and in range; raise ConfigurationError."""
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise ConfigurationError(f"--duration must be > 0, got {self.duration_s}")
        velocity = tuple(float(v) for v in self.velocity_rad_s)
        if len(velocity) != 3 or not all(
            math.isfinite(v) and 0 < v <= MAX_VELOCITY_RAD_S for v in velocity
        ):
            raise ConfigurationError(
                f"--velocity-rad-s needs 3 values in (0, {MAX_VELOCITY_RAD_S:g}] rad/s, got "
                f"{list(self.velocity_rad_s)}"
            )
        object.__setattr__(self, "velocity_rad_s", velocity)
        if not (math.isfinite(self.margin_rad) and self.margin_rad >= 0):
            raise ConfigurationError(f"--margin-rad must be >= 0, got {self.margin_rad}")
        if not (math.isfinite(self.ramp_s) and self.ramp_s > 0):
            raise ConfigurationError(f"--ramp-s must be > 0, got {self.ramp_s}")
        if self.seed < 0:
            raise ConfigurationError(f"--seed must be >= 0, got {self.seed}")
        if not (math.isfinite(self.rate_hz) and 1.0 <= self.rate_hz <= 2000.0):
            raise ConfigurationError(
                f"the command rate must be in [1, 2000] Hz, got {self.rate_hz}"
            )

    def to_json(self) -> dict[str, Any]:
        """Return the configuration as the recording's metadata holds it."""
        return {
            "duration_s": self.duration_s,
            "velocity_rad_s": list(self.velocity_rad_s),
            "margin_rad": self.margin_rad,
            "ramp_s": self.ramp_s,
            "seed": self.seed,
            "rate_hz": self.rate_hz,
        }


@dataclass(frozen=True)
class ExcitationPlan:
    """Joint references [rad] (model coordinates), one per command at ``rate_hz``.

    The first ``ramp_samples`` are the ramp from the arm's pose, the rest the trajectory.
    """

    q_rad: np.ndarray
    rate_hz: float
    ramp_samples: int

    def __post_init__(self) -> None:
        """Check the shapes and that every reference is finite."""
        if self.q_rad.ndim != 2 or self.q_rad.shape[1] != 3 or self.q_rad.shape[0] < 2:
            raise ConfigurationError(f"q_rad must be (N >= 2, 3), got {self.q_rad.shape}")
        if not np.all(np.isfinite(self.q_rad)):
            raise ConfigurationError("the joint references are not finite")
        if not 0 < self.ramp_samples < self.q_rad.shape[0]:
            raise ConfigurationError(f"ramp_samples must be in (0, N), got {self.ramp_samples}")

    @property
    def duration_s(self) -> float:
        """How long the plan takes at ``rate_hz`` [s]."""
        return self.q_rad.shape[0] / self.rate_hz

    def tip_in_base_m(self) -> np.ndarray:
        """Return the model's tip of every reference: ``(N, 3)`` [m, model base frame]."""
        from teleop_force.robots.omni import tip_position_formula

        return np.asarray(tip_position_formula(self.q_rad.T)).T


def plan_excitation(config: ExcitationConfig, q_start_rad: np.ndarray) -> ExcitationPlan:
    """Return the ramp from ``q_start_rad`` then the training trajectory of ``config``.

    Raises:
        ConfigurationError: the region cannot be filled inside the limits less the margin.

    """
    from teleop_force.identification.training_trajectory import (
        VelocityRegion,
        training_trajectory,
    )
    from teleop_force.robots.omni import Q_MAX_RAD, Q_MIN_RAD

    v1, v2, v3 = config.velocity_rad_s
    region = VelocityRegion((-v1, v1), (-v2, v2), (-v3, v3))
    trajectory = training_trajectory(
        region,
        config.duration_s,
        config.rate_hz,
        q_min_rad=Q_MIN_RAD,
        q_max_rad=Q_MAX_RAD,
        margin_rad=config.margin_rad,
        seed=config.seed,
    )
    q_start = np.asarray(q_start_rad, dtype=float).reshape(3)
    n_ramp = max(2, round(config.ramp_s * config.rate_hz))
    tau = np.arange(n_ramp)[:, None] / n_ramp
    blend = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)  # minimum jerk, 0 -> 1
    ramp = q_start + blend * (trajectory.q_rad[0] - q_start)
    return ExcitationPlan(np.vstack((ramp, trajectory.q_rad)), config.rate_hz, n_ramp)


@dataclass(frozen=True)
class DriverFrame:
    """The driver's Cartesian frame in the model's base: ``p_model = R p_driver + origin``.

    Attributes:
        rotation: ``R``, the description's ``base_rotation`` (3 x 3).
        origin_in_model_m: The driver's origin in the model's base frame [m].

    """

    rotation: np.ndarray
    origin_in_model_m: np.ndarray

    def __post_init__(self) -> None:
        """Check the shapes and finiteness."""
        if self.rotation.shape != (3, 3) or self.origin_in_model_m.shape != (3,):
            raise ConfigurationError("DriverFrame: rotation must be 3 x 3, origin (3,)")
        if not (np.all(np.isfinite(self.rotation)) and np.all(np.isfinite(self.origin_in_model_m))):
            raise DataError("the driver's frame is not finite (measured_cp or measured_js NaN?)")

    def to_driver(self, p_model_m: np.ndarray) -> np.ndarray:
        """Return model-base positions ``(N, 3)`` [m] in the driver's frame."""
        return (np.asarray(p_model_m, dtype=float) - self.origin_in_model_m) @ self.rotation


def driver_frame(
    interface: DriverInterface, q_rad: np.ndarray, measured_cp_m: np.ndarray
) -> DriverFrame:
    """Return the driver's frame from one pose: the model's tip of ``q_rad`` and measured_cp."""
    from teleop_force.robots.omni import tip_position_formula

    rotation = interface.rotation
    tip = np.asarray(tip_position_formula(np.asarray(q_rad, dtype=float)), dtype=float)
    return DriverFrame(rotation, tip - rotation @ np.asarray(measured_cp_m, dtype=float))


class DriverMonitor:
    """The driver's latest measured_js and measured_cp, kept as received, decoded on demand."""

    def __init__(self, node: Node, device: str, interface: DriverInterface) -> None:
        """Subscribe to ``/<device>/measured_js`` and ``/<device>/measured_cp``."""
        self.device = device
        self.interface = interface
        self._lock = threading.Lock()
        self._latest: dict[str, bytes] = {}
        self._arrived_s: dict[str, float] = {}
        self.counts = {topics.MEASURED_JS.kind: 0, MEASURED_CP.kind: 0}
        for topic in (topics.MEASURED_JS, MEASURED_CP):
            node.subscription(
                topics.topic_name(device, topic), topic.ros_type, self._callback(topic.kind)
            )

    def _callback(self, kind: str) -> Callable[[bytes, Attachment], None]:
        def on_message(payload: bytes, attachment: Attachment) -> None:
            with self._lock:
                self._latest[kind] = payload
                self._arrived_s[kind] = time.monotonic()
                self.counts[kind] += 1

        return on_message

    def topic(self, kind: str) -> str:
        """Return the topic name of ``kind``."""
        return f"/{self.device}/{kind}"

    def wait(self, timeout_s: float, where: str, stop: Callable[[], bool]) -> None:
        """Wait until both topics have delivered; raise TransportError naming a silent one."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not stop():
            with self._lock:
                if all(self.counts.values()):
                    return
            time.sleep(0.02)
        with self._lock:
            silent = [kind for kind, count in self.counts.items() if count == 0]
        if silent:
            raise TransportError(
                f"no message on {self.topic(silent[0])} in {timeout_s:g} s (is the driver "
                f"running and publishing it, on {where}?); nothing was commanded"
            )

    def silent_s(self) -> float:
        """How long since the last measured_js [s] (infinite before the first)."""
        with self._lock:
            arrived = self._arrived_s.get(topics.MEASURED_JS.kind)
        return math.inf if arrived is None else time.monotonic() - arrived

    def joint_angles_rad(self) -> np.ndarray:
        """Return the latest measured_js in the model's coordinates [rad].

        Raises:
            DataError: it does not parse, or lacks a joint the description reads (named).

        """
        from teleop_force.ros2 import codec

        payload = self._payload(topics.MEASURED_JS.kind)
        try:
            js = codec.decode_raw_joint_state(payload)
        except MessageError as exc:
            raise DataError(f"{self.topic('measured_js')}: {exc}") from None
        q, _ = self.interface.to_model(js.names, js.position)
        if not np.all(np.isfinite(q)):
            raise DataError(f"{self.topic('measured_js')}: positions are not finite")
        return np.asarray(q, dtype=float)

    def tip_m(self) -> np.ndarray:
        """Return the latest measured_cp's position [m, the driver's frame]."""
        from teleop_force.ros2 import codec

        try:
            pose = codec.decode_pose(self._payload(MEASURED_CP.kind))
        except MessageError as exc:
            raise DataError(f"{self.topic('measured_cp')}: {exc}") from None
        return np.asarray(pose.position_m, dtype=float)

    def _payload(self, kind: str) -> bytes:
        with self._lock:
            payload = self._latest.get(kind)
        if payload is None:
            raise TransportError(f"no message on {self.topic(kind)} yet")
        return payload


@dataclass(frozen=True)
class ExcitationResult:
    """What was played: commands sent, whether it was cut short, tracking, the loop's stats.

    Attributes:
        commands_sent: servo_cp commands published.
        planned: Commands the plan held.
        interrupted: Stopped by Ctrl-C / SIGTERM before the end.
        tracking_rms_m: RMS of measured_cp against the latest servo_cp, sampled every 10th
            command of the trajectory (NaN before any) [m].
        loop: The command loop's statistics (ticks, overruns...).

    """

    commands_sent: int
    planned: int
    interrupted: bool
    tracking_rms_m: float
    loop: dict[str, Any]

    def __post_init__(self) -> None:
        """Check the counts."""
        if not 0 <= self.commands_sent <= self.planned:
            raise ConfigurationError("commands_sent must be in [0, planned]")


def play(
    plan: ExcitationPlan,
    frame: DriverFrame,
    servo_cp: Publisher,
    monitor: DriverMonitor,
    stop: Callable[[], bool],
    log: Callable[[str], None],
    frame_id: str,
) -> ExcitationResult:
    """Send the plan as servo_cp at its rate until its end or ``stop()``.

    Raises:
        TransportError: measured_js went silent for :data:`STALE_S` (the driver is gone).

    """
    from master_slave.realtime import LoopConfig, RateLoop
    from teleop_force.ros2 import codec

    tips = frame.to_driver(plan.tip_in_base_m())
    loop = RateLoop(LoopConfig(rate_hz=plan.rate_hz))
    every = max(1, round(PROGRESS_S * plan.rate_hz))
    errors: list[float] = []
    sent, interrupted = 0, False
    loop.start()
    for k in range(tips.shape[0]):
        loop.wait()
        if stop():
            interrupted = True
            break
        if (silent := monitor.silent_s()) > STALE_S:
            raise TransportError(
                f"{monitor.topic('measured_js')} silent for {silent:.2f} s during the motion "
                "(driver gone?)"
            )
        servo_cp.publish(codec.encode_pose(loop.stamp_ns, tips[k], frame_id))
        sent += 1
        if k >= plan.ramp_samples and k % 10 == 0:
            errors.append(float(np.linalg.norm(monitor.tip_m() - tips[k - 1])))
        if k and k % every == 0:
            log(f"excite: {k / plan.rate_hz:.0f} of {plan.duration_s:.0f} s")
    rms = float(np.sqrt(np.mean(np.square(errors)))) if errors else math.nan
    return ExcitationResult(sent, tips.shape[0], interrupted, rms, loop.stats())


def stop_motion(servo_cf: Publisher, hold: Publisher) -> None:
    """Send a zero servo_cf, then (50 ms later, so it is the last command) hold, twice."""
    from teleop_force.ros2 import codec

    servo_cf.publish(codec.encode_wrench(time.time_ns(), (0.0, 0.0, 0.0), topics.BASE_FRAME))
    for _ in range(2):
        time.sleep(0.05)
        hold.publish(codec.encode_empty())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add excite's flags to ``parser``."""
    from teleop_force.cli.check_driver import add_device_arguments

    add_device_arguments(parser)
    parser.add_argument(
        "--duration", type=float, default=DEFAULT_DURATION_S, metavar="S",
        help=f"length of the training trajectory after the ramp (default {DEFAULT_DURATION_S:g})",
    )  # fmt: skip
    parser.add_argument(
        "--velocity-rad-s", type=float, nargs=3, default=list(DEFAULT_VELOCITY_RAD_S),
        metavar=("QD1", "QD2", "QD3"),
        help="half-widths of the joint velocity region to fill, rad/s (default "
        + " ".join(f"{v:g}" for v in DEFAULT_VELOCITY_RAD_S) + ")",
    )  # fmt: skip
    parser.add_argument(
        "--margin-rad", type=float, default=DEFAULT_MARGIN_RAD, metavar="RAD",
        help=f"kept from each end of the model's joint ranges (default {DEFAULT_MARGIN_RAD:g})",
    )  # fmt: skip
    parser.add_argument(
        "--ramp-s", type=float, default=DEFAULT_RAMP_S, metavar="S",
        help=f"ramp from the arm's pose to the trajectory's start (default {DEFAULT_RAMP_S:g})",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="the trajectory's phases (default 0)")
    parser.add_argument(
        "--wait-s", type=float, default=DEFAULT_WAIT_S, metavar="S",
        help=f"how long to wait for the driver's topics before giving up (default "
        f"{DEFAULT_WAIT_S:g})",
    )  # fmt: skip
    parser.add_argument(
        "-o", "--output", required=True, metavar="SESSION.mcap",
        help="the recording to write (.mcap; an existing file is not overwritten)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    add_zenoh_arguments(parser)


def _log(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    """Excite and record; return 0, or 130 when interrupted; raise TeleopForceError for 2."""
    from teleop_force.process.lifetime import StopSignal

    return excite(args, StopSignal().install().is_set)


def excite(args: argparse.Namespace, stop: Callable[[], bool]) -> int:
    """Run the command (module docstring) until its end or ``stop()``; return the exit status."""
    from teleop_force.cli.check_driver import endpoints_text
    from teleop_force.io.driver_session import driver_metadata
    from teleop_force.io.mcap_session import SessionWriter
    from teleop_force.robots.registry import resolve_driver
    from teleop_force.ros2.node import Node
    from teleop_force.service.controls import create_exclusively
    from teleop_force.service.ros2_recorder import PROFILE, Ros2Recorder
    from teleop_force.transport.session import open_session, options_from_args

    device = topics.validate_device(args.device)
    interface = resolve_driver(args.driver)
    if interface.n_joints != 3:
        raise ConfigurationError(
            f"driver {interface.name}: {interface.n_joints} model joints; excite knows the "
            "Omni's kinematics only (3 joints)"
        )
    v1, v2, v3 = (float(v) for v in args.velocity_rad_s)
    config = ExcitationConfig(
        duration_s=args.duration,
        velocity_rad_s=(v1, v2, v3),
        margin_rad=args.margin_rad,
        ramp_s=args.ramp_s,
        seed=args.seed,
        rate_hz=interface.rate_hz,
    )
    plan_excitation(config, np.zeros(3))  # a region the limits cannot hold: exit 2 now
    wait_s = float(args.wait_s)
    if not (math.isfinite(wait_s) and wait_s > 0):
        raise ConfigurationError(f"--wait-s must be > 0, got {args.wait_s}")
    output = Path(args.output)
    if output.suffix.lower() != ".mcap":
        raise ConfigurationError(f"-o {output}: the recording must be a .mcap file")
    if output.exists():
        raise DataError("exists: a recording is not overwritten (choose another -o)", path=output)
    session = open_session(options_from_args(args))
    try:
        node = Node(session, "teleop_force_excite", domain_id=args.ros_domain_id)
        try:
            monitor = DriverMonitor(node, device, interface)
            servo_cp = node.publisher(topics.topic_name(device, SERVO_CP), SERVO_CP.ros_type)
            servo_cf = node.publisher(topics.topic_name(device, SERVO_CF), SERVO_CF.ros_type)
            hold = node.publisher(topics.topic_name(device, HOLD), HOLD.ros_type)
            where = f"ROS domain {node.domain_id}, through {endpoints_text(args)}"
            monitor.wait(wait_s, where, stop)
            if stop():
                return EXIT_INTERRUPTED
            output.parent.mkdir(parents=True, exist_ok=True)
            create_exclusively(output)
            metadata = {
                "primary_device": device,
                "source": "excite",
                "recorder": "teleop-force excite",
                "model": "",
                "excitation": json.dumps(config.to_json()),
                **driver_metadata(interface),
            }
            writer = SessionWriter(output, metadata, profile=PROFILE)
            recorder = Ros2Recorder(session, writer, domain_id=node.domain_id).start()
            try:
                result = _excite_recorded(
                    config, interface, monitor, (servo_cp, servo_cf, hold), stop
                )
            finally:
                recorder.close()
        finally:
            node.close()
    finally:
        session.close()
    _report(args, output, result, monitor, recorder.stats())
    return EXIT_INTERRUPTED if result.interrupted else 0


def _excite_recorded(
    config: ExcitationConfig,
    interface: DriverInterface,
    monitor: DriverMonitor,
    publishers: tuple[Publisher, Publisher, Publisher],
    stop: Callable[[], bool],
) -> ExcitationResult:
    """Rest, plan from the arm's pose, play, and always end with zero force and hold."""
    servo_cp, servo_cf, hold = publishers
    try:
        time.sleep(REST_S)  # recorded at rest: the start of the session
        q_start = monitor.joint_angles_rad()
        frame = driver_frame(interface, q_start, monitor.tip_m())
        plan = plan_excitation(config, q_start)
        _log(
            f"excite: /{monitor.device}: {plan.ramp_samples / plan.rate_hz:g} s ramp, then "
            f"{config.duration_s:g} s of the training trajectory as servo_cp at "
            f"{plan.rate_hz:g} Hz (Ctrl-C: hold)"
        )
        result = play(plan, frame, servo_cp, monitor, stop, _log, interface.base_frame)
    finally:
        stop_motion(servo_cf, hold)
        _log(f"excite: zero servo_cf and hold sent to /{monitor.device}")
    time.sleep(REST_S)  # the hold, recorded
    return result


def _report(
    args: argparse.Namespace,
    output: Path,
    result: ExcitationResult,
    monitor: DriverMonitor,
    recorded: dict[str, Any],
) -> None:
    summary = {
        "recording": str(output),
        "device": monitor.device,
        "driver": monitor.interface.name,
        "commands_sent": result.commands_sent,
        "commands_planned": result.planned,
        "interrupted": result.interrupted,
        "joint_states_received": monitor.counts[topics.MEASURED_JS.kind],
        "messages_recorded": recorded["messages"],
        "tracking_rms_m": None if math.isnan(result.tracking_rms_m) else result.tracking_rms_m,
        "loop": result.loop,
    }
    _log(
        f"excite: {result.commands_sent} of {result.planned} servo_cp sent"
        + (" (interrupted)" if result.interrupted else "")
        + f", tip tracking {result.tracking_rms_m * 1e3:.1f} mm RMS; "
        f"{recorded['messages']} messages recorded to {output}"
    )
    _log(f"next: teleop-force identify {output} -o MODEL.json")
    if args.json:
        print(json.dumps(summary))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m teleop_force.cli.excite``: as ``teleop-force excite``."""
    from teleop_force.cli.main import main as cli_main

    return cli_main(["excite", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
