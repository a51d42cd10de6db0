"""``teleop-force check-driver``: a driver description against the live driver, before use.

Subscribes for ``--seconds`` to the driver's ``/<device>/measured_js`` (its JointState, in its
own conventions) and ``/<device>/measured_cp`` (its tip pose, m), converts the joint states with
the description (``--driver``), prints what it read in the model's conventions and runs
:func:`teleop_force.robots.driver_check.check_positions`. With ``--probe-force-n F`` it also
commands a small force on ``/<device>/servo_cf`` (F N along x, then y, then z, about a second
in all; a zero force afterwards, always), reads ``/<device>/measured_cf`` with the efforts and
runs :func:`~teleop_force.robots.driver_check.check_efforts`.

Exit status: 0 the checks pass, 1 one fails (the message names the description's entry), 2 bad
usage, a connection error, or a topic that stayed silent (named).
"""

from __future__ import annotations

import argparse
import bisect
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

import numpy as np

from teleop_force.errors import ConfigurationError, DataError, MessageError, TransportError
from teleop_force.ros2 import interfaces, topics
from teleop_force.transport.session import add_zenoh_arguments

if TYPE_CHECKING:  # the CLI builds its flags without rosbags or zenoh
    from teleop_force.robots.driver_check import TipJacobian, TipPosition
    from teleop_force.robots.driver_interface import DriverInterface
    from teleop_force.ros2.attachment import Attachment
    from teleop_force.ros2.codec import RawJointState
    from teleop_force.ros2.node import Node, Publisher

#: The driver's tip pose in its base frame (CRTK ``measured_cp``), position in m.
MEASURED_CP: Final = topics.Topic("measured_cp", interfaces.POSE_STAMPED)
#: The driver's last commanded Cartesian force (sawSensablePhantom: ``HD_LAST_FORCE``), N.
MEASURED_CF: Final = topics.Topic("measured_cf", interfaces.WRENCH_STAMPED)
#: The driver's Cartesian force command (CRTK ``servo_cf``), N, in its base frame.
SERVO_CF: Final = topics.Topic("servo_cf", interfaces.WRENCH_STAMPED)

DEFAULT_SECONDS: Final = 3.0
#: The largest probe force the command sends [N] (the Omni renders up to 3.3 N).
MAX_PROBE_FORCE_N: Final = 1.0
#: How long the probe force is applied in all [s] (one third per axis).
PROBE_DURATION_S: Final = 1.0
#: How often the probe force is re-sent [Hz] (a driver may time out a stale command).
PROBE_RATE_HZ: Final = 100.0
#: At most this many samples go into check_positions (its fits evaluate the kinematics often).
MAX_POSITION_SAMPLES: Final = 300
#: A joint whose angle ranges less than this [rad] leaves its sign and offset barely tested.
SMALL_MOTION_RAD: Final = 0.05
EXIT_OK: Final = 0
EXIT_CHECK_FAILED: Final = 1


@dataclass
class _Stream:
    """One topic's decoded messages: header stamps and arrival times [ns], values."""

    stamps_ns: list[int] = field(default_factory=list)
    received_ns: list[int] = field(default_factory=list)
    values: list[object] = field(default_factory=list)
    malformed: int = 0


class DriverReader:
    """Subscriptions to the driver's topics; every message is kept with its arrival time."""

    def __init__(self, node: Node, device: str, *, forces: bool) -> None:
        """Subscribe to measured_js and measured_cp (and measured_cf if ``forces``)."""
        self._lock = threading.Lock()
        self.streams: dict[str, _Stream] = {}
        wanted = [topics.MEASURED_JS, MEASURED_CP] + ([MEASURED_CF] if forces else [])
        for topic in wanted:
            self.streams[topic.kind] = _Stream()
            node.subscription(
                topics.topic_name(device, topic), topic.ros_type, self._callback(topic.kind)
            )

    def _callback(self, kind: str) -> Callable[[bytes, Attachment], None]:
        decode = {
            topics.MEASURED_JS.kind: _decode_js,
            MEASURED_CP.kind: _decode_cp,
            MEASURED_CF.kind: _decode_cf,
        }[kind]

        def on_message(payload: bytes, attachment: Attachment) -> None:
            now = time.time_ns()
            stream = self.streams[kind]
            try:
                stamp, value = decode(payload)
            except MessageError:
                with self._lock:
                    stream.malformed += 1
                return
            with self._lock:
                stream.stamps_ns.append(stamp)
                stream.received_ns.append(now)
                stream.values.append(value)

        return on_message

    def snapshot(self, kind: str) -> _Stream:
        """Return a copy of what came on ``kind`` so far."""
        with self._lock:
            s = self.streams[kind]
            return _Stream(list(s.stamps_ns), list(s.received_ns), list(s.values), s.malformed)

    def count(self, kind: str) -> int:
        """How many messages came on ``kind``."""
        with self._lock:
            return len(self.streams[kind].values)


def _decode_js(payload: bytes) -> tuple[int, RawJointState]:
    from teleop_force.ros2 import codec

    js = codec.decode_raw_joint_state(payload)
    return js.t_ns, js


def _decode_cp(payload: bytes) -> tuple[int, np.ndarray]:
    from teleop_force.ros2 import codec

    pose = codec.decode_pose(payload)
    return pose.t_ns, np.asarray(pose.position_m, dtype=float)


def _decode_cf(payload: bytes) -> tuple[int, np.ndarray]:
    from teleop_force.ros2 import codec

    wrench = codec.decode_wrench(payload)
    return wrench.t_ns, np.asarray(wrench.force_n, dtype=float)


def _common_clock(*streams: _Stream) -> list[np.ndarray]:
    """Each stream's times [s]: the header stamps if every stream has increasing non-zero ones.

    Otherwise (a driver that does not stamp) the arrival times, for all alike.
    """

    def stamped(s: _Stream) -> bool:
        t = np.asarray(s.stamps_ns, dtype=np.int64)
        return t.size > 0 and bool(np.all(t > 0)) and bool(np.all(np.diff(t) >= 0))

    use_stamps = all(stamped(s) for s in streams)
    return [
        np.asarray(s.stamps_ns if use_stamps else s.received_ns, dtype=np.int64) * 1e-9
        for s in streams
    ]


@dataclass(frozen=True)
class JointReadings:
    """measured_js in the model's coordinates, with what the driver's messages held."""

    names: tuple[str, ...]
    positions: np.ndarray  # samples x names, the driver's
    efforts: np.ndarray | None  # samples x names, the driver's; None: not published
    q_rad: np.ndarray  # samples x model joints
    tau_nm: np.ndarray | None
    rate_hz: float
    velocity: bool
    skipped: int  # messages with other names or array lengths


def joint_readings(interface: DriverInterface, stream: _Stream) -> JointReadings:
    """Convert the JointStates of ``stream`` (those with the first message's names)."""
    from teleop_force.ros2.codec import RawJointState

    first = stream.values[0]
    assert isinstance(first, RawJointState)
    names = first.names
    n = len(names)
    rows, effort_rows, velocity = [], [], True
    skipped = 0
    for value in stream.values:
        assert isinstance(value, RawJointState)
        if value.names != names or len(value.position) != n:
            skipped += 1
            continue
        rows.append(value.position)
        effort_rows.append(value.effort if len(value.effort) == n else None)
        velocity = velocity and len(value.velocity) == n
    positions = np.asarray(rows, dtype=float)
    efforts = None
    if all(e is not None for e in effort_rows):
        efforts = np.asarray(effort_rows, dtype=float)
    q, tau = interface.to_model(names, positions, efforts)
    t = np.asarray(stream.received_ns, dtype=np.int64) * 1e-9
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0
    return JointReadings(names, positions, efforts, q, tau, float(rate), velocity, skipped)


def _same_names(stream: _Stream, names: tuple[str, ...]) -> np.ndarray:
    from teleop_force.ros2.codec import RawJointState

    return np.array(
        [isinstance(v, RawJointState) and v.names == names and len(v.position) == len(names)
         for v in stream.values],
        dtype=bool,
    )  # fmt: skip


def paired_positions(
    js: _Stream, cp: _Stream, readings: JointReadings
) -> tuple[np.ndarray, np.ndarray]:
    """Driver positions interpolated at each measured_cp's time, with those poses' positions.

    Only measured_cp messages within the span of the joint states are used; at most
    :data:`MAX_POSITION_SAMPLES`, evenly spread.
    """
    t_js, t_cp = _common_clock(js, cp)
    t_js = t_js[_same_names(js, readings.names)]
    cp_m = np.asarray(cp.values, dtype=float).reshape(-1, 3)
    inside = (t_cp >= t_js[0]) & (t_cp <= t_js[-1])
    if not np.any(inside):
        raise DataError(
            "measured_cp and measured_js do not overlap in time (their stamps disagree)"
        )
    t_cp, cp_m = t_cp[inside], cp_m[inside]
    order = np.argsort(t_js, kind="stable")
    x = np.column_stack(
        [np.interp(t_cp, t_js[order], readings.positions[order, j])
         for j in range(readings.positions.shape[1])]
    )  # fmt: skip
    keep = np.unique(
        np.linspace(0, len(t_cp) - 1, min(len(t_cp), MAX_POSITION_SAMPLES)).astype(int)
    )
    return x[keep], cp_m[keep]


def paired_efforts(
    js: _Stream, cf: _Stream, readings: JointReadings
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the joint states taken while the commanded force was steady and non-zero.

    A joint state is used when the measured_cf messages just before and just after it (by
    time) carry the same force: no step of the command falls between them. Returns the
    driver's positions, efforts and that force (N).
    """
    assert readings.efforts is not None
    t_js, t_cf = _common_clock(js, cf)
    t_js = t_js[_same_names(js, readings.names)]
    forces = np.asarray(cf.values, dtype=float).reshape(-1, 3)
    order = np.argsort(t_cf, kind="stable")
    times, forces = [float(t) for t in t_cf[order]], forces[order]
    rows, force_rows = [], []
    for k, t in enumerate(t_js):
        before = bisect.bisect_right(times, t) - 1
        after = bisect.bisect_left(times, t)
        if before < 0 or after >= len(times):
            continue
        f = forces[before]
        if np.array_equal(f, forces[after]) and np.any(f != 0.0):
            rows.append(k)
            force_rows.append(f)
    if not rows:
        raise DataError(
            "measured_cf never showed the probe force while measured_js came (does the driver "
            "accept servo_cf?)"
        )
    idx = np.asarray(rows)
    return readings.positions[idx], readings.efforts[idx], np.asarray(force_rows)


def probe_force(publisher: Publisher, force_n: float, duration_s: float = PROBE_DURATION_S) -> None:
    """Command ``force_n`` N along x, y, then z (one third of ``duration_s`` each), then zero.

    The zero force is sent whatever happens (also on an error or Ctrl-C), twice.
    """
    from teleop_force.ros2 import codec

    frame = topics.BASE_FRAME
    try:
        period = 1.0 / PROBE_RATE_HZ
        for axis in range(3):
            force = np.zeros(3)
            force[axis] = force_n
            end = time.monotonic() + duration_s / 3
            while time.monotonic() < end:
                publisher.publish(codec.encode_wrench(time.time_ns(), tuple(force), frame))
                time.sleep(period)
    finally:
        for _ in range(2):
            publisher.publish(codec.encode_wrench(time.time_ns(), (0.0, 0.0, 0.0), frame))
            time.sleep(0.05)


def _print(line: str) -> None:
    print(line, flush=True)


def _report_readings(interface: DriverInterface, readings: JointReadings) -> None:
    model_names = topics.model_joint_names(interface.n_joints)
    _print(
        f"measured_js: {len(readings.q_rad)} joint states at {readings.rate_hz:.1f} Hz "
        f"(the description says {interface.rate_hz:g}), names {list(readings.names)}, "
        f"velocity {'present' if readings.velocity else 'absent'} (the description says "
        f"{'present' if interface.publishes_velocity else 'absent'}), effort "
        f"{'present' if readings.tau_nm is not None else 'absent'}"
    )
    if readings.skipped:
        _print(f"measured_js: {readings.skipped} messages with other names or lengths skipped")
    for j, entry in enumerate(interface.positions):
        q = readings.q_rad[:, j]
        tau = (
            ""
            if readings.tau_nm is None
            else f", tau {readings.tau_nm[-1, j]:+.5f} N m "
            f"(max |tau| {np.max(np.abs(readings.tau_nm[:, j])):.5f})"
        )
        _print(
            f"  {model_names[j]} (driver joint {entry.joint!r}): q {q[-1]:+.4f} rad "
            f"(range {q.min():+.4f} .. {q.max():+.4f}){tau}"
        )


def _tip_functions(interface: DriverInterface) -> tuple[TipPosition, TipJacobian]:
    from teleop_force.robots.omni import tip_jacobian_formula, tip_position_formula

    if interface.n_joints != 3:
        raise ConfigurationError(
            f"driver {interface.name}: {interface.n_joints} model joints; check-driver knows "
            "the Omni's kinematics only (3 joints)"
        )
    return tip_position_formula, tip_jacobian_formula


def _wait_for(reader: DriverReader, kind: str, device: str, seconds: float, where: str) -> None:
    if reader.count(kind) == 0:
        raise TransportError(
            f"no message on /{device}/{kind} in {seconds:g} s (is the driver publishing it, "
            f"on {where}?)"
        )


def add_device_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--driver``, ``--device`` and ``--ros-domain-id``: which live driver, where."""
    parser.add_argument(
        "--driver", default="sensable-phantom", metavar="NAME|FILE",
        help="the driver description: a built-in (sensable-phantom) or a description file "
        "(default sensable-phantom)",
    )  # fmt: skip
    parser.add_argument(
        "--device", required=True, help="the driver's device name: its topics are /<device>/..."
    )
    parser.add_argument(
        "--ros-domain-id", type=int, default=None, metavar="D",
        help="ROS 2 domain of the driver's topics (default: $ROS_DOMAIN_ID, else 0)",
    )  # fmt: skip


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add check-driver's flags to ``parser``."""
    add_device_arguments(parser)
    parser.add_argument(
        "--seconds", type=float, default=DEFAULT_SECONDS, metavar="S",
        help=f"how long to read the driver's topics (default {DEFAULT_SECONDS:g}); move the "
        "arm through its workspace meanwhile",
    )  # fmt: skip
    parser.add_argument(
        "--probe-force-n", type=float, default=None, metavar="F",
        help=f"also command F N (at most {MAX_PROBE_FORCE_N:g}) on servo_cf along x, y, z for "
        f"about {PROBE_DURATION_S:g} s, then zero, and check the efforts (default: no force)",
    )  # fmt: skip
    add_zenoh_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """Run the checks; return 0 (pass) or 1 (a check failed); raise TeleopForceError for 2."""
    from teleop_force.ros2.node import Node
    from teleop_force.service.force_service import load_driver
    from teleop_force.transport.session import open_session, options_from_args

    seconds = float(args.seconds)
    if not (np.isfinite(seconds) and seconds > 0):
        raise ConfigurationError(f"--seconds must be > 0, got {args.seconds}")
    force_n = args.probe_force_n
    if force_n is not None and not (np.isfinite(force_n) and 0 < force_n <= MAX_PROBE_FORCE_N):
        raise ConfigurationError(
            f"--probe-force-n must be > 0 and at most {MAX_PROBE_FORCE_N:g} N, got {force_n}"
        )
    device = topics.validate_device(args.device)
    interface = load_driver(args.driver)
    tip_position, tip_jacobian = _tip_functions(interface)
    session = open_session(options_from_args(args))
    try:
        node = Node(session, "teleop_force_check_driver", domain_id=args.ros_domain_id)
        try:
            where = f"ROS domain {node.domain_id}, through {endpoints_text(args)}"
            reader = DriverReader(node, device, forces=force_n is not None)
            servo = None  # declared now: matched with the driver's subscriber by the probe
            if force_n is not None:
                servo = node.publisher(topics.topic_name(device, SERVO_CF), SERVO_CF.ros_type)
            time.sleep(seconds)
            for topic in (topics.MEASURED_JS, MEASURED_CP):
                _wait_for(reader, topic.kind, device, seconds, where)
            if servo is not None:
                last = reader.snapshot(topics.MEASURED_JS.kind).values[-1]
                if not getattr(last, "effort", ()):
                    raise DataError(
                        f"/{device}/measured_js carries no efforts: the efforts cannot be "
                        "checked (no force was commanded)"
                    )
                _print(f"servo_cf: {force_n:g} N along x, y, then z, then zero")
                probe_force(servo, float(force_n))
                _wait_for(reader, MEASURED_CF.kind, device, seconds + PROBE_DURATION_S, where)
            js = reader.snapshot(topics.MEASURED_JS.kind)
            cp = reader.snapshot(MEASURED_CP.kind)
            cf = reader.snapshot(MEASURED_CF.kind) if force_n is not None else None
        finally:
            node.close()
    finally:
        session.close()
    return _check(interface, tip_position, tip_jacobian, js, cp, cf)


def _check(
    interface: DriverInterface,
    tip_position: TipPosition,
    tip_jacobian: TipJacobian,
    js: _Stream,
    cp: _Stream,
    cf: _Stream | None,
) -> int:
    from teleop_force.robots.driver_check import check_efforts, check_positions

    readings = joint_readings(interface, js)
    _report_readings(interface, readings)
    _print(f"measured_cp: {len(cp.values)} poses")
    for topic, stream in (("measured_js", js), ("measured_cp", cp), ("measured_cf", cf)):
        if stream is not None and stream.malformed:
            _print(f"{topic}: {stream.malformed} malformed messages dropped")
    for j in np.flatnonzero(np.ptp(readings.q_rad, axis=0) < SMALL_MOTION_RAD):
        _print(
            f"note: q{j + 1} moved less than {SMALL_MOTION_RAD:g} rad: its sign and offset are "
            "barely tested (move the arm during the check)"
        )
    ok = True
    positions, cp_m = paired_positions(js, cp, readings)
    result = check_positions(interface, tip_position, readings.names, positions, cp_m)
    offset = "" if result.base_offset_m is None else (
        ", origins differ by " + " ".join(f"{v:+.4f}" for v in result.base_offset_m) + " m"
    )  # fmt: skip
    _print(
        f"positions: {'pass' if result.ok else 'FAIL'}: the model's tip is "
        f"{result.residual * 1e3:.2f} mm RMS from measured_cp over {len(positions)} poses{offset}"
    )
    for finding in result.findings:
        _print(f"  {finding}")
    ok = ok and result.ok
    if cf is not None:
        if readings.efforts is None:
            raise DataError("measured_js carries no efforts: the efforts cannot be checked")
        x, e, f = paired_efforts(js, cf, readings)
        effort_result = check_efforts(interface, tip_jacobian, readings.names, x, e, f)
        _print(
            f"efforts: {'pass' if effort_result.ok else 'FAIL'}: torques vs J^T measured_cf "
            f"over {len(x)} joint states, RMS difference {effort_result.residual:.3g} N m"
        )
        for finding in effort_result.findings:
            _print(f"  {finding}")
        if not (result.ok or effort_result.ok):
            _print("  (the efforts check uses the description's q: fix the positions first)")
        ok = ok and effort_result.ok
    return EXIT_OK if ok else EXIT_CHECK_FAILED


def endpoints_text(args: argparse.Namespace) -> str:
    """Return the ``--connect`` endpoints for a message (or "this machine's Zenoh peers")."""
    connect = list(getattr(args, "connect", None) or [])
    return ", ".join(connect) if connect else "this machine's Zenoh peers"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m teleop_force.cli.check_driver``: as ``teleop-force check-driver``."""
    from teleop_force.cli.main import main as cli_main

    return cli_main(["check-driver", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
