"""The ROS 2 clients of docs/ros2.md, each run as a user would, against the service.

The service estimates on rclpy-serialized JointStates published with rmw_zenoh's attachment;
each client (nothing of this project imported) connects over 127.0.0.1 and prints forces.
"""

from __future__ import annotations

import math
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")

pytestmark = pytest.mark.zenoh
DOC = Path(__file__).resolve().parents[2] / "docs" / "ros2.md"
FORCE_LINE = re.compile(r"F = \([+-]\d+\.\d\d, [+-]\d+\.\d\d, [+-]\d+\.\d\d\) N")


def doc_python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.DOTALL)


def joint_state(k: int) -> bytes:
    ros = sensor_msgs.JointState()
    ros.header.stamp.sec, ros.header.stamp.nanosec = divmod(time.time_ns(), 1_000_000_000)
    ros.name = list(topics.OMNI_MODEL_JOINT_NAMES)
    ros.position = [0.2 * math.sin(2e-3 * k), 0.8, 0.3]
    ros.velocity = [0.0, 0.0, 0.0]
    ros.effort = [0.02, 0.15, 0.05]
    return serialization.serialize_message(ros)


@pytest.mark.parametrize("block", [0, 1], ids=["zenoh+rosbags", "zenoh+rclpy"])
def test_the_ros2_clients_of_the_docs_print_estimates(block: int) -> None:
    code = doc_python_blocks()[block]
    assert "teleop_force" not in code
    endpoint = listen_endpoint(free_tcp_port())
    session = open_session(ZenohOptions(mode="peer", listen=(endpoint,), multicast_scouting=False))
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(session, model, ServiceConfig(residual_watch=False)).start()
    driver = Node(session, "test_driver", domain_id=0).publisher(
        topics.topic_name("slave", topics.MEASURED_JS), interfaces.JOINT_STATE
    )
    client = subprocess.Popen(
        [sys.executable, "-c", code.replace("tcp/127.0.0.1:7447", endpoint)
         .replace("time.sleep(10.0)", "time.sleep(6.0)")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 6.0
        k = 0
        while time.monotonic() < deadline and client.poll() is None:
            driver.publish(joint_state(k))
            k += 1
            time.sleep(0.002)
        out, err = client.communicate(timeout=60)
    finally:
        service.close()
        session.close()
    assert client.returncode == 0, err
    lines = [line for line in out.splitlines() if FORCE_LINE.search(line)]
    assert len(lines) > 10, out[-2000:]
