"""``teleop-force serve --driver sensable-phantom`` against the simulated driver, as processes.

The driver publishes at 500 Hz with no velocities, in its own coordinates and mN m; the
service converts with the built-in driver description and must estimate from that.
"""

from __future__ import annotations

import math
import queue
import time

import pytest
from teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop

from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.ros2.node import Node

pytestmark = pytest.mark.zenoh
DEVICE = "sim_phantom"


def test_the_service_estimates_from_the_simulated_driver(tmp_path, zenoh_rendezvous):
    connect = zenoh_rendezvous.process_args
    log = tmp_path / "processes.log"
    node = Node(zenoh_rendezvous.session, "test_estimates")
    estimates: queue.Queue = queue.Queue()
    node.subscription(
        topics.topic_name(DEVICE, topics.ESTIMATED_CF),
        interfaces.WRENCH_STAMPED,
        lambda payload, attachment: estimates.put(payload),
    )
    servo_cf = node.publisher(f"/{DEVICE}/servo_cf", interfaces.WRENCH_STAMPED)
    processes = []
    try:
        processes.append(
            spawn(python_module("teleop_force.cli.main", "serve", "--driver", "sensable-phantom",
                                "--device", DEVICE, "--no-residual-watch", *connect), log)
        )  # fmt: skip
        processes.append(
            spawn(python_module("master_slave.sensable_driver", "--name", DEVICE, *connect), log)
        )
        first = estimates.get(timeout=STARTUP_TIMEOUT_S)  # both up, the routes too
        # a force that moves the arm: the estimates follow its motion, not only a rest pose
        servo_cf.publish(codec.encode_wrench(time.time_ns(), (0.0, 0.6, 0.0), "base"))
        time.sleep(2.0)
        received = [first]
        while True:
            try:
                received.append(estimates.get_nowait())
            except queue.Empty:
                break
        for process in processes:
            assert process.poll() is None, log.read_text()
    finally:
        for process in reversed(processes):
            stop(process)
        node.close()
    wrenches = [codec.decode_wrench(p) for p in received]
    assert len(wrenches) >= 200, len(wrenches)  # ~500 per second for 2 s on an idle machine
    assert all(w.frame_id == "base" for w in wrenches)
    finite = [w for w in wrenches if all(math.isfinite(f) for f in w.force_n)]
    assert len(finite) >= 0.9 * len(wrenches)  # NaN only near a singular pose
    stamps = [w.t_ns for w in wrenches]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
