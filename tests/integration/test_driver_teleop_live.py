"""Teleoperation through drivers that keep their last command: follow, hold, zero force.

The test plays both drivers as sawSensablePhantom behaves: the master keeps the last
``servo_cf`` it received (no timeout) and ``free`` drops it; the slave follows ``servo_cp``
and ``hold`` stops it. The teleop process must leave the master with no force and the slave
holding, whatever ends it.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any

import numpy as np
import pytest
from teleop_helpers import python_module, spawn, stop, wait_for

from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node

_ESTIMATE_N = (1.0, -2.0, 0.5)
_POSE = interfaces.POSE_STAMPED
_MASTER_POSITION_M = (0.01, -0.02, 0.03)


def _pose_payload(position_m: tuple[float, ...]) -> bytes:
    return codec.encode_pose(time.time_ns(), position_m, topics.BASE_FRAME)


class KeepsLastForce:
    """The master driver's command side: the force it applies is the last servo_cf."""

    def __init__(self, node: Node) -> None:
        self._lock = threading.Lock()
        self.force_n = np.zeros(3)
        self.commands = 0
        self.frees = 0
        node.subscription("/master/servo_cf", interfaces.WRENCH_STAMPED, self._on_servo_cf)
        node.subscription("/master/free", "std_msgs/msg/Empty", self._on_free)
        self.slave_position_m: tuple[float, ...] | None = None
        self.slave_holds = 0
        node.subscription("/slave/servo_cp", _POSE, self._on_servo_cp)
        node.subscription("/slave/hold", "std_msgs/msg/Empty", self._on_hold)

    def _on_servo_cp(self, payload: bytes, attachment: Attachment) -> None:
        position_m = codec.decode_pose(payload).position_m
        with self._lock:
            self.slave_position_m = position_m

    def _on_hold(self, payload: bytes, attachment: Attachment) -> None:
        with self._lock:
            self.slave_holds += 1

    def _on_servo_cf(self, payload: bytes, attachment: Attachment) -> None:
        force = np.array(codec.decode_wrench(payload).force_n)
        with self._lock:
            self.force_n, self.commands = force, self.commands + 1

    def _on_free(self, payload: bytes, attachment: Attachment) -> None:
        with self._lock:
            self.force_n, self.frees = np.zeros(3), self.frees + 1

    def applied(self) -> tuple[np.ndarray, int, int]:
        with self._lock:
            return self.force_n.copy(), self.commands, self.frees


class Estimates:
    """The service's side, estimated_cf, and the master's measured_cp, at 200 Hz."""

    def __init__(self, node: Node) -> None:
        self.publisher = node.publisher(
            topics.topic_name("slave", topics.ESTIMATED_CF), topics.ESTIMATED_CF.ros_type
        )
        self.pose_publisher = node.publisher("/master/measured_cp", _POSE)
        self.pose_running = threading.Event()
        self.running = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            if self.running.is_set():
                payload = codec.encode_wrench(time.time_ns(), _ESTIMATE_N, topics.BASE_FRAME)
                self.publisher.publish(payload)
            if self.pose_running.is_set():
                self.pose_publisher.publish(_pose_payload(_MASTER_POSITION_M))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


@pytest.fixture
def driver(zenoh_rendezvous: Any) -> Any:
    session = zenoh_rendezvous.connect_peer()
    node = Node(session, "test_master_driver")
    driver, estimates = KeepsLastForce(node), Estimates(node)
    try:
        yield driver, estimates
    finally:
        estimates.close()
        node.close()
        session.close()


def _start(zenoh_rendezvous: Any, tmp_path: Any, *extra: str) -> Any:
    argv = python_module(
        "master_slave.driver_teleop", "--master", "master", "--slave", "slave",
        *extra, *zenoh_rendezvous.process_args,
    )  # fmt: skip
    return spawn(argv, tmp_path / "feedback.log")


def _pushing(driver: KeepsLastForce) -> bool:
    force, _, _ = driver.applied()
    return bool(np.allclose(force, -0.5 * np.array(_ESTIMATE_N)))


def _no_force(driver: KeepsLastForce) -> bool:
    force, _, _ = driver.applied()
    return not force.any()


@pytest.mark.parametrize("watchdog", [True, False], ids=["watchdog", "control-no-watchdog"])
def test_sigkill_leaves_the_driver_with_no_force(
    driver: Any, zenoh_rendezvous: Any, tmp_path: Any, watchdog: bool
) -> None:
    """Killed while pushing: the watchdog zeroes the force; without it the force persists."""
    keeper, estimates = driver
    estimates.running.set()
    process = _start(zenoh_rendezvous, tmp_path, *(() if watchdog else ("--no-watchdog",)))
    try:
        wait_for(lambda: _pushing(keeper), 30.0, "the feedback force at the driver")
        process.send_signal(signal.SIGKILL)
        process.wait(10.0)
        if not watchdog:  # the control: the driver itself never drops the force
            time.sleep(1.0)
            assert _pushing(keeper)
            return
        # the estimates still arrive: only the watchdog can have zeroed the force
        wait_for(lambda: _no_force(keeper), 10.0, "zero force after SIGKILL")
        assert keeper.applied()[2] >= 1  # free
        wait_for(lambda: keeper.slave_holds >= 2, 10.0, "the slave's hold after SIGKILL")
        time.sleep(0.3)
        assert _no_force(keeper)  # nothing commands a force any more
    finally:
        stop(process)


def test_stale_estimate_then_clean_exit_command_zero(
    driver: Any, zenoh_rendezvous: Any, tmp_path: Any
) -> None:
    keeper, estimates = driver
    estimates.running.set()
    process = _start(zenoh_rendezvous, tmp_path, "--no-watchdog")
    try:
        wait_for(lambda: _pushing(keeper), 30.0, "the feedback force at the driver")
        estimates.running.clear()  # the service is lost: its last estimate goes stale
        wait_for(lambda: _no_force(keeper), 10.0, "zero force on a stale estimate")
        _, _, frees = keeper.applied()
        assert frees == 0  # a zero command, while the process still runs
        estimates.running.set()
        wait_for(lambda: _pushing(keeper), 10.0, "the force back with fresh estimates")
        assert stop(process, signal.SIGTERM) == 0
        wait_for(lambda: _no_force(keeper), 10.0, "zero force after a clean exit")
        assert keeper.applied()[2] >= 1  # and free
    finally:
        stop(process)


def test_slave_follows_the_master_and_holds_when_it_is_lost(
    driver: Any, zenoh_rendezvous: Any, tmp_path: Any
) -> None:
    keeper, estimates = driver
    process = _start(zenoh_rendezvous, tmp_path, "--no-watchdog")
    try:
        wait_for(lambda: keeper.slave_holds >= 1, 30.0, "hold before any master pose")
        estimates.pose_running.set()
        wait_for(lambda: keeper.slave_position_m == _MASTER_POSITION_M, 10.0, "following")
        holds = keeper.slave_holds
        estimates.pose_running.clear()  # the master is lost
        wait_for(lambda: keeper.slave_holds == holds + 1, 10.0, "hold when the master is lost")
        time.sleep(0.3)
        assert keeper.slave_holds == holds + 1  # once, not every tick
        assert stop(process, signal.SIGTERM) == 0
        wait_for(lambda: keeper.slave_holds == holds + 2, 10.0, "hold on exit")
    finally:
        stop(process)
