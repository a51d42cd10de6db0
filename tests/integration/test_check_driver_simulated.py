"""``teleop-force check-driver`` against the simulated sawSensablePhantom driver (a process).

The simulated driver was written from the driver's source, the check from the description:
the built-in description passing against it, positions and efforts, ties the two together.
"""

from __future__ import annotations

import math
import threading
import time

import pytest
from teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop, wait_for

from teleop_force.cli.main import main
from teleop_force.ros2 import codec, interfaces
from teleop_force.ros2.node import Node

pytestmark = pytest.mark.zenoh
DEVICE = "sim_arm"


def _check(rendezvous, *extra: str) -> int:
    return main(
        ["check-driver", "--device", DEVICE, "--ros-domain-id", "0", "--connect",
         rendezvous.endpoint, "--no-multicast", *extra]
    )  # fmt: skip


def test_the_builtin_description_passes_against_the_simulated_driver(
    tmp_path, zenoh_rendezvous, capsys, monkeypatch
):
    monkeypatch.setenv("ROS_DOMAIN_ID", "0")
    log = tmp_path / "driver.log"
    node = Node(zenoh_rendezvous.session, "test_mover", domain_id=0)
    poses = []
    node.subscription(f"/{DEVICE}/measured_cp", interfaces.POSE_STAMPED,
                      lambda p, a: poses.append(1))  # fmt: skip
    servo_cf = node.publisher(f"/{DEVICE}/servo_cf", interfaces.WRENCH_STAMPED)
    driver = spawn(python_module("master_slave.sensable_driver", "--name", DEVICE,
                                 *zenoh_rendezvous.process_args), log)  # fmt: skip
    stop_moving = threading.Event()

    def move() -> None:  # a hand moving the stylus around while the check reads
        start = time.monotonic()
        while not stop_moving.wait(0.01):
            t = time.monotonic() - start
            force = (0.8 * math.sin(2.1 * t), 0.8 * math.cos(1.3 * t), 0.6 * math.sin(0.9 * t))
            servo_cf.publish(codec.encode_wrench(time.time_ns(), force, "base"))

    mover = threading.Thread(target=move, daemon=True)
    try:
        wait_for(lambda: len(poses) > 0, STARTUP_TIMEOUT_S, "the simulated driver")
        mover.start()
        positions = _check(zenoh_rendezvous, "--seconds", "3")
        positions_out = capsys.readouterr().out
        stop_moving.set()
        mover.join(2.0)
        servo_cf.publish(codec.encode_wrench(time.time_ns(), (0.0, 0.0, 0.0), "base"))
        time.sleep(0.3)
        probe = _check(zenoh_rendezvous, "--seconds", "1", "--probe-force-n", "0.5")
        probe_out = capsys.readouterr().out
        assert driver.poll() is None, log.read_text()
    finally:
        stop_moving.set()
        stop(driver)
        node.close()
    assert positions == 0, positions_out
    assert "positions: pass" in positions_out
    assert probe == 0, probe_out
    assert "efforts: pass" in probe_out
