"""Two simulated drivers, the service and the teleop process: follow, feed back, die safely.

Everything as a lab runs it: a master and a slave ``sensable_phantom`` node (the simulated
driver, which keeps the last ``servo_cf`` as the real one does), ``teleop-force serve
--driver sensable-phantom`` on the slave, and ``master_slave.driver_teleop`` between them. The
teleop process is then killed with SIGKILL: the master driver must end with no force applied.
"""

from __future__ import annotations

import queue
import signal
import threading
import time

import numpy as np
import pytest
from teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop, wait_for

from teleop_force.robots import omni
from teleop_force.ros2 import codec, interfaces
from teleop_force.ros2.node import Node

pytestmark = pytest.mark.zenoh


class Latest:
    """The latest message of a topic, decoded."""

    def __init__(self, node: Node, topic: str, ros_type: str, decode) -> None:
        self._lock = threading.Lock()
        self.value = None
        self.count = 0
        node.subscription(topic, ros_type, self._on_sample)
        self._decode = decode

    def _on_sample(self, payload: bytes, attachment) -> None:
        value = self._decode(payload)
        with self._lock:
            self.value, self.count = value, self.count + 1

    def get(self):
        with self._lock:
            return self.value


def test_teleop_through_two_simulated_drivers_and_sigkill(tmp_path, zenoh_rendezvous):
    connect = zenoh_rendezvous.process_args
    log = tmp_path / "processes.log"
    node = Node(zenoh_rendezvous.session, "test_observer")
    master_cf = Latest(node, "/master/measured_cf", interfaces.WRENCH_STAMPED,
                       lambda p: np.array(codec.decode_wrench(p).force_n))  # fmt: skip
    master_cp = Latest(node, "/master/measured_cp", interfaces.POSE_STAMPED,
                       lambda p: np.array(codec.decode_pose(p).position_m))  # fmt: skip
    slave_cp = Latest(node, "/slave/measured_cp", interfaces.POSE_STAMPED,
                      lambda p: np.array(codec.decode_pose(p).position_m))  # fmt: skip
    estimates: queue.Queue = queue.Queue()
    node.subscription("/slave/estimated_cf", interfaces.WRENCH_STAMPED,
                      lambda p, a: estimates.put(p))  # fmt: skip
    drivers, teleop = [], None
    try:
        drivers.append(spawn(python_module("master_slave.sensable_driver", "--name", "master",
                                           "--seed", "3", *connect), log))  # fmt: skip
        # the slave starts elsewhere: 0.3 rad of waist away, several centimetres at the tip
        q0 = 0.5 * (np.asarray(omni.Q_MIN_RAD) + np.asarray(omni.Q_MAX_RAD)) + (0.3, 0.0, 0.0)
        drivers.append(spawn(python_module("master_slave.sensable_driver", "--name", "slave",
                                           "--q0-rad", *map(str, q0), *connect), log))  # fmt: skip
        drivers.append(
            spawn(python_module("teleop_force.cli.main", "serve", "--driver", "sensable-phantom",
                                "--device", "slave", "--no-residual-watch", *connect), log)
        )  # fmt: skip
        estimates.get(timeout=STARTUP_TIMEOUT_S)
        wait_for(lambda: master_cp.get() is not None and slave_cp.get() is not None,
                 STARTUP_TIMEOUT_S, "the drivers' poses")  # fmt: skip
        assert np.linalg.norm(master_cp.get() - slave_cp.get()) > 0.03  # apart before teleop
        # full scale: the free-space estimate's few tenths of a newton reach the master
        teleop = spawn(python_module("master_slave.driver_teleop", "--master", "master",
                                     "--slave", "slave", "--scale", "1.0", *connect),
                       log)  # fmt: skip

        def follows() -> bool:
            a, b = master_cp.get(), slave_cp.get()
            return a is not None and b is not None and np.linalg.norm(a - b) < 0.02

        wait_for(follows, STARTUP_TIMEOUT_S, "the slave following the master")
        wait_for(lambda: master_cf.get() is not None and master_cf.get().any(), 30.0,
                 "a feedback force at the master")  # fmt: skip
        teleop.send_signal(signal.SIGKILL)
        teleop.wait(10.0)
        # the estimates go on: only the watchdog can have zeroed the master's force
        wait_for(lambda: not master_cf.get().any(), 10.0, "no force at the master")
        count = master_cf.count
        time.sleep(0.5)
        assert master_cf.count > count  # the driver still publishes ...
        assert not master_cf.get().any()  # ... and applies no force
        assert estimates.qsize() > 0
        for process in drivers:
            assert process.poll() is None, log.read_text()
    finally:
        if teleop is not None:
            stop(teleop)
        for process in reversed(drivers):
            stop(process)
        node.close()
