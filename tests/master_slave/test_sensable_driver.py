"""The simulated sawSensablePhantom driver: its device frame, and its ROS 2 node over Zenoh."""

from __future__ import annotations

import math
import queue
import threading
import time

import numpy as np
import pytest

from master_slave.sensable_driver import SensableDriverNode, build_plant
from teleop_force.errors import DataError
from teleop_force.robots.registry import builtin_driver
from teleop_force.ros2 import codec, interfaces
from teleop_force.ros2.node import Node
from teleop_force.simulation.sensable_driver import (
    JOINT_NAMES,
    Mode,
    SimulatedSensableDevice,
    clamp_force,
)

NAME = "sim_arm"


def frames(device: SimulatedSensableDevice, n: int):
    return [device.frame() for _ in range(n)]


# --------------------------------------------------------------------------- the device frame


def test_clamp_force_scales_a_long_force_to_the_limit_and_keeps_a_short_one():
    long = clamp_force(np.array([3.0, 0.0, 4.0]), 2.0)
    assert np.allclose(long, [1.2, 0.0, 1.6], atol=1e-15)
    short = np.array([0.3, -1.0, 0.5])
    assert np.array_equal(clamp_force(short, 2.0), short)


def test_positions_are_the_driver_transform_of_the_raw_angles_and_efforts_the_previous_torque():
    device = SimulatedSensableDevice(build_plant())
    interface = builtin_driver("sensable-phantom")
    device.servo_cf((0.4, 1.1, -0.7))
    previous = None
    for frame in frames(device, 50):
        raw = np.array(frame.q_raw_rad)
        # the driver's lines 418-419, written out: waist = -raw0, elbow = raw2 - raw1
        assert np.allclose(frame.position[:3], [-raw[0], raw[1], raw[2] - raw[1]], atol=1e-12)
        assert np.allclose(frame.position[:3], interface.to_driver(raw)[1], atol=1e-12, rtol=0)
        assert frame.position[3:] == (0.0, 0.0, 0.0) and frame.effort_mnm[3:] == (0.0, 0.0, 0.0)
        expected = (0.0, 0.0, 0.0) if previous is None else previous.tau_nm
        assert np.allclose(frame.effort_mnm[:3], 1000.0 * np.array(expected), rtol=1e-12, atol=0)
        # the model reads them back: q = raw, tau = the previous frame's command
        q, tau = interface.to_model(JOINT_NAMES[:3], frame.position[:3], frame.effort_mnm[:3])
        assert np.allclose(q, raw, atol=1e-12) and np.allclose(tau, expected, atol=1e-15)
        previous = frame
    assert np.any(np.abs(previous.tau_nm) > 0.05)  # the force did make torques


def test_servo_cf_is_clamped_applied_as_jacobian_transpose_and_kept_until_free():
    device = SimulatedSensableDevice(build_plant())
    frames(device, 5)
    device.servo_cf((0.0, 5.0, 0.0))
    arrived_in = device.frame()  # queued commands are processed at the end of a frame
    assert arrived_in.mode is Mode.NONE and arrived_in.force_in_base_n == (0.0, 0.0, 0.0)
    first, *rest = frames(device, 400)  # 0.4 s without a command
    for frame in (first, *rest):
        assert frame.mode is Mode.CF
        assert np.allclose(frame.force_in_base_n, (0.0, 2.0, 0.0), atol=1e-15)
        jac = device.plant.robot.tip_jacobian_in_base(np.array(frame.q_raw_rad))
        assert np.allclose(frame.tau_nm, jac.T @ np.array(frame.force_in_base_n), atol=1e-15)
    assert np.allclose(rest[0].last_force_in_base_n, (0.0, 2.0, 0.0), atol=1e-15)  # HD_LAST_FORCE
    device.free()
    after = frames(device, 3)
    assert after[0].force_in_base_n != (0.0, 0.0, 0.0)  # the frame it arrived in
    assert after[1].force_in_base_n == (0.0, 0.0, 0.0) and after[1].tau_nm == (0.0, 0.0, 0.0)
    assert after[2].last_force_in_base_n == (0.0, 0.0, 0.0)


def test_hold_is_the_drivers_cartesian_pd_on_the_position_held():
    device = SimulatedSensableDevice(build_plant())
    frames(device, 200)
    device.servo_cf((0.0, 1.5, 0.0))  # pushes the tip up
    frames(device, 100)
    device.hold()
    device.frame()  # hold is processed at the end of this one: it holds where that frame read
    target = device.hold_position_m.copy()
    hold = frames(device, 500)
    settings = device.settings
    for frame in hold:
        assert frame.mode is Mode.CP
        assert np.linalg.norm(frame.force_in_base_n) <= settings.max_force_n + 1e-12
    drift_m = np.linalg.norm(np.array(hold[-1].tip_in_base_m) - target)
    assert drift_m < 0.02  # 100 N/m against the unbalanced weight: a sag of millimetres
    # its force is the PD on the error, at rest (velocity ~0): -100 N/m * error
    last = hold[-1]
    error = np.array(last.tip_in_base_m) - target
    assert np.allclose(last.force_in_base_n, -settings.servo_cp_p_gain_n_per_m * error, atol=0.05)


def test_a_free_arm_moves_under_gravity_with_no_command():
    plant = build_plant()  # the default plant, its spring included
    device = SimulatedSensableDevice(plant)
    start = device.frame()
    end = frames(device, 300)[-1]
    assert start.mode is end.mode is Mode.NONE and end.tau_nm == (0.0, 0.0, 0.0)
    # nothing holds it (no gravity compensation): it moves from the mid-range start
    assert np.linalg.norm(plant.q_true_rad - np.array(start.q_raw_rad)) > 1e-3


# --------------------------------------------------------------------------- over Zenoh


class RunningDriver:
    """The driver's node in a thread on one session; the frames it published, by stamp."""

    def __init__(self, session) -> None:
        self.published: dict[int, object] = {}
        self.device = SimulatedSensableDevice(build_plant())
        self.node = SensableDriverNode(session, NAME, self.device, on_frame=self._on_frame)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self.node.run, args=(self._stop.is_set,))

    def _on_frame(self, frame, stamp_ns: int) -> None:
        self.published[stamp_ns] = frame

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self.thread.join(10.0)
        self.node.close()


class Listener:
    """The test's node: raw payloads of the driver's topics, with their arrival time."""

    def __init__(self, session) -> None:
        self.node = Node(session, "test_listener")
        self.js: queue.Queue = queue.Queue()
        self.cf: queue.Queue = queue.Queue()
        self.cp: queue.Queue = queue.Queue()
        for kind, ros_type, q in (
            ("measured_js", interfaces.JOINT_STATE, self.js),
            ("measured_cf", interfaces.WRENCH_STAMPED, self.cf),
            ("measured_cp", interfaces.POSE_STAMPED, self.cp),
        ):
            self.node.subscription(
                f"/{NAME}/{kind}", ros_type, lambda p, a, q=q: q.put((time.monotonic(), p))
            )
        self.servo_cf = self.node.publisher(f"/{NAME}/servo_cf", interfaces.WRENCH_STAMPED)
        self.free = self.node.publisher(f"/{NAME}/free", interfaces.EMPTY)
        self.hold = self.node.publisher(f"/{NAME}/hold", interfaces.EMPTY)

    def latest_force(self, timeout_s: float = 10.0) -> np.ndarray:
        """The measured_cf of a message that arrived after this call."""
        drain(self.cf)
        _, payload = self.cf.get(timeout=timeout_s)
        return np.array(codec.decode_wrench(payload).force_n)

    def close(self) -> None:
        self.node.close()


def drain(q: queue.Queue) -> list:
    items = []
    while True:
        try:
            items.append(q.get_nowait())
        except queue.Empty:
            return items


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


@pytest.fixture
def live(zenoh_pair):
    listener = Listener(zenoh_pair.connector)
    try:
        with RunningDriver(zenoh_pair.listener) as driver:
            listener.js.get(timeout=20.0)  # the routes are up
            yield driver, listener
    finally:
        listener.close()


def test_measured_js_is_the_drivers_joint_state_at_500_hz(live):
    driver, listener = live
    interface = builtin_driver("sensable-phantom")
    listener.servo_cf.publish(codec.encode_wrench(time.time_ns(), (0.3, 0.8, -0.5), "base"))
    time.sleep(0.2)
    drain(listener.js)
    t0 = time.monotonic()
    time.sleep(1.0)
    arrived = drain(listener.js)
    in_window = [p for t, p in arrived if t - t0 <= 1.0]
    # 500 per second nominally; a loaded 2-core machine may delay, not multiply, them
    assert 250 <= len(in_window) <= 750, len(in_window)
    by_stamp = {}
    for _, payload in arrived:
        js = codec.decode_raw_joint_state(payload)
        assert js.names == JOINT_NAMES and js.velocity == () and len(js.effort) == 6
        by_stamp[js.t_ns] = js
    stamps = sorted(by_stamp)
    assert np.median(np.diff(stamps)) == 2_000_000  # every second 1 ms frame
    published = driver.published
    frames_by_stamp = sorted(published)
    torques = 0
    for t_ns in stamps:
        js, frame = by_stamp[t_ns], published[t_ns]
        raw = np.array(frame.q_raw_rad)
        assert np.allclose(js.position[:3], interface.to_driver(raw)[1], atol=1e-12, rtol=0)
        assert js.position[3:] == (0.0, 0.0, 0.0)
        # the effort: 1000 x the torque commanded in the previous 1 ms frame (not published)
        assert np.allclose(
            js.effort[:3], 1000.0 * np.array(frame.last_joint_torque_nm), rtol=1e-12, atol=0
        )
        torques += np.any(np.abs(frame.last_joint_torque_nm) > 0.01)
        # and the previous published frame's own command is two frames back, not this one
        i = frames_by_stamp.index(t_ns)
        assert i == 0 or published[frames_by_stamp[i - 1]].t_s < frame.t_s
    assert torques > len(stamps) // 2
    _, pose_payload = listener.cp.get(timeout=5.0)
    pose = codec.decode_pose(pose_payload)
    assert pose.frame_id == "base" and pose.orientation_xyzw == (0.0, 0.0, 0.0, 1.0)
    assert np.allclose(pose.position_m, published[pose.t_ns].tip_in_base_m, atol=0)


def test_servo_cf_of_5_n_is_clamped_to_2_n_kept_without_commands_and_zeroed_by_free(live):
    driver, listener = live
    listener.servo_cf.publish(codec.encode_wrench(time.time_ns(), (0.0, 3.0, 4.0), "base"))
    wait_until(lambda: driver.device.commands["servo_cf"] == 1, 10.0, "the command")
    # measured_cf shows it from the frame after the command was processed, 2 ms later
    wait_until(lambda: listener.latest_force().any(), 10.0, "the force on measured_cf")
    force = listener.latest_force()
    assert np.allclose(force, (0.0, 1.2, 1.6), atol=1e-12)  # norm 5 -> 2, same direction
    time.sleep(0.5)  # no command for 250 messages: no timeout
    assert np.allclose(listener.latest_force(), (0.0, 1.2, 1.6), atol=1e-12)
    listener.free.publish(codec.encode_empty())
    wait_until(lambda: driver.device.commands["free"] == 1, 10.0, "free")
    wait_until(lambda: not listener.latest_force().any(), 10.0, "zero force after free")
    listener.hold.publish(codec.encode_empty())
    wait_until(lambda: driver.device.mode is Mode.CP, 10.0, "hold")
    listener.servo_cf.publish(b"\x00\x01\x00\x00")  # not a WrenchStamped: counted, dropped
    wait_until(lambda: driver.node.malformed == 1, 10.0, "the malformed command")
    assert driver.device.mode is Mode.CP


def test_servo_cp_tracks_the_position_given_with_the_drivers_pd():
    device = SimulatedSensableDevice(build_plant())
    frames(device, 200)
    device.hold()
    device.frame()
    held_m = device.hold_position_m.copy()
    rest_held = np.array(frames(device, 1500)[-1].tip_in_base_m)  # the PD's rest, with its sag
    step_m = np.array([0.0, 0.01, 0.0])  # 1 cm up
    device.servo_cp(tuple(held_m + step_m))
    device.frame()
    np.testing.assert_array_equal(device.hold_position_m, held_m + step_m)
    tracked = frames(device, 1500)
    assert all(f.mode is Mode.CP for f in tracked)
    moved_m = np.array(tracked[-1].tip_in_base_m) - rest_held
    # it moves toward the target, until the joints' static friction holds it against the PD
    assert moved_m[1] > 0.3 * step_m[1] and np.all(np.abs(moved_m[[0, 2]]) < moved_m[1])
    last = tracked[-1]
    error_m = np.array(last.tip_in_base_m) - (held_m + step_m)
    gain = device.settings.servo_cp_p_gain_n_per_m  # at rest, the force is the P term alone
    np.testing.assert_allclose(last.force_in_base_n, -gain * error_m, atol=0.02)
    with pytest.raises(DataError):
        device.servo_cp((0.0, math.nan, 0.0))


def test_the_driver_declares_its_node_publishers_and_subscriptions_in_the_ros2_graph(live):
    from teleop_force.ros2 import graph

    driver, listener = live
    domain = driver.node.node.domain_id
    replies = listener.node.session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=5.0)
    entities = [graph.parse_token(str(r.ok.key_expr)) for r in replies if r.ok is not None]
    ours = {
        (e.kind, None if e.topic is None else (e.topic.name, e.topic.ros_type))
        for e in entities
        if e.node_name == "sensable_phantom"
    }
    kinds = graph.EntityKind
    assert ours == {
        (kinds.NODE, None),
        (kinds.PUBLISHER, (f"/{NAME}/measured_js", interfaces.JOINT_STATE)),
        (kinds.PUBLISHER, (f"/{NAME}/measured_cp", interfaces.POSE_STAMPED)),
        (kinds.PUBLISHER, (f"/{NAME}/measured_cf", interfaces.WRENCH_STAMPED)),
        (kinds.SUBSCRIPTION, (f"/{NAME}/servo_cf", interfaces.WRENCH_STAMPED)),
        (kinds.SUBSCRIPTION, (f"/{NAME}/servo_cp", interfaces.POSE_STAMPED)),
        (kinds.SUBSCRIPTION, (f"/{NAME}/hold", interfaces.EMPTY)),
        (kinds.SUBSCRIPTION, (f"/{NAME}/free", interfaces.EMPTY)),
    }
