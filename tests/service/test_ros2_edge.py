"""The service's ROS 2 node: rclpy-serialized JointStates in, rclpy-readable estimates out."""

import math
import queue
import time

import numpy as np
import pytest

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport import pubsub
from teleop_force.transport.pubsub import query_json

serialization = pytest.importorskip("rclpy.serialization")
sensor_msgs = pytest.importorskip("sensor_msgs.msg")
geometry_msgs = pytest.importorskip("geometry_msgs.msg")

pytestmark = pytest.mark.zenoh
DEVICE = "ros2_test"
TIMEOUT_S = 30.0  # a loaded 2-core host: the first estimate may take long
T0_NS = 1_764_158_400_000_000_000


def rclpy_joint_state(k, names):
    ros = sensor_msgs.JointState()
    t_ns = T0_NS + k * 1_000_000
    ros.header.stamp.sec, ros.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
    ros.name = list(names)
    t = k * 1e-3
    ros.position = [0.2 * math.sin(2 * t), 0.8 + 0.3 * math.sin(3 * t), 0.3]
    ros.velocity = [0.0, 0.0, 0.0]
    ros.effort = [0.02, 0.15, 0.05]
    return serialization.serialize_message(ros)


def wait_until(predicate, what):
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.005)


@pytest.fixture(scope="module")
def model():
    return DynamicModel.load(DEFAULT_MODEL_PATH)


def test_rclpy_joint_states_are_estimated_on_and_estimates_decode_with_rclpy(zenoh_pair, model):
    service = ForceService(
        zenoh_pair.listener, model, ServiceConfig(device=DEVICE, residual_watch=False)
    ).start()
    client = Node(zenoh_pair.connector, "ros2_test_client", domain_id=graph.domain_id_from_env())
    wrenches: queue.Queue = queue.Queue()
    diagnostics: queue.Queue = queue.Queue()
    try:
        client.subscription(
            topics.topic_name(DEVICE, topics.ESTIMATED_CF),
            interfaces.WRENCH_STAMPED,
            lambda p, a: wrenches.put((p, a)),
        )
        client.subscription(topics.topic_name(DEVICE, topics.ESTIMATE_DIAGNOSTICS),
                            interfaces.ESTIMATE_DIAGNOSTICS,
                            lambda p, a: diagnostics.put((p, a)))  # fmt: skip
        driver = client.publisher(topics.topic_name(DEVICE, topics.MEASURED_JS),
                                  interfaces.JOINT_STATE)  # fmt: skip
        assert pubsub.wait_for_subscribers(driver.zenoh_publisher, TIMEOUT_S)
        service_pub = service._ros2.estimates.zenoh_publisher
        assert pubsub.wait_for_subscribers(service_pub, TIMEOUT_S)
        sent = [driver.publish(rclpy_joint_state(k, topics.OMNI_MODEL_JOINT_NAMES))
                for k in range(20)]  # fmt: skip
        driver.publish(rclpy_joint_state(20, topics.DRIVER_JOINT_NAMES))  # refused: malformed
        got = [wrenches.get(timeout=TIMEOUT_S) for _ in sent]
        diag = [diagnostics.get(timeout=TIMEOUT_S) for _ in sent]
        for (payload, attachment), k in zip(got, range(20), strict=True):
            ros = serialization.deserialize_message(payload, geometry_msgs.WrenchStamped)
            assert ros.header.frame_id == topics.BASE_FRAME
            assert np.isfinite([ros.wrench.force.x, ros.wrench.force.y, ros.wrench.force.z]).all()
            assert attachment.sequence_number == k + 1
        sources = [codec.decode_estimate_diagnostics(p).source_sequence for p, _ in diag]
        assert sources == [a.sequence_number for a in sent]
        stats = query_json(zenoh_pair.connector, f"omni/{DEVICE}/service/stats")
        wait_until(lambda: service.malformed.dropped >= 1, "the driver-named state dropped")
        assert stats["joint_states"]["received"] == 20
        assert stats["joint_states"]["lost"] == 0
        assert stats["estimates"]["published"] == 20
        assert wrenches.empty()
    finally:
        client.close()
        service.close()


def test_a_device_id_that_is_no_ros_name_is_refused():
    from teleop_force.errors import ConfigurationError

    with pytest.raises(ConfigurationError, match="ROS 2 name"):
        ServiceConfig(device="svc-test")
    assert ServiceConfig(device="svc_test").device == "svc_test"


def test_residual_watch_reports_are_published_as_service_diagnostics(zenoh_pair):
    from teleop_force.service.ros2_edge import Ros2Edge
    from teleop_force.transport import messages as m

    edge = Ros2Edge(zenoh_pair.listener, DEVICE, 3, lambda msg, a, t: None, lambda k, e: None)
    client = Node(zenoh_pair.connector, "ros2_test_client", domain_id=graph.domain_id_from_env())
    got: queue.Queue = queue.Queue()
    try:
        client.subscription(topics.topic_name(DEVICE, topics.SERVICE_DIAGNOSTICS),
                            interfaces.SERVICE_DIAGNOSTICS, lambda p, a: got.put(p))  # fmt: skip
        assert pubsub.wait_for_subscribers(edge.service_diagnostics.zenoh_publisher, TIMEOUT_S)
        report = m.ServiceDiagnostics(
            seq=3, t_ns=T0_NS, device=DEVICE, state="watching", stream_s=61.0,
            baseline_complete=True, rms_torque_nm=(0.02, 0.03, 0.02),
            checks=(m.DiagnosticCheck(2, 128, "t", 0.2, 0.01, 0),), finding=None, command="",
        )  # fmt: skip
        edge.publish_service_diagnostics(report.encode())
        back = codec.decode_service_diagnostics(got.get(timeout=TIMEOUT_S), seq=3)
        assert back.to_json_dict() == report.to_json_dict()
    finally:
        client.close()
        edge.close()


def test_a_drivers_joint_states_are_converted_on_reading_and_estimated_on(zenoh_pair, model):
    """sawSensablePhantom's measured_js (its names, relative elbow, mN m, no velocity, 500 Hz):
    the estimates equal the estimator's on the same samples in the model's coordinates."""
    from teleop_force.estimation.estimator import ForceEstimator
    from teleop_force.robots.registry import builtin_driver
    from tests.robots.test_driver_interface import saw_measured_js
    from tests.ros2_traffic import Collector, put

    device = "omni_right"  # the driver's namespace
    config = ServiceConfig(
        device=device, residual_watch=False, driver=builtin_driver("sensable-phantom")
    )
    service = ForceService(zenoh_pair.listener, model, config).start()
    client = Node(zenoh_pair.connector, "sensable_phantom")
    estimates = Collector(zenoh_pair.connector, device, topics.ESTIMATED_CF)
    n = 100
    t = np.arange(n) * 2e-3
    q = np.column_stack([0.2 * np.sin(2 * t), 0.8 + 0.3 * np.sin(3 * t), 0.3 + 0.1 * t])
    tau_nm = np.column_stack([0.02 + 0 * t, 0.15 + 0.01 * np.cos(t), 0.05 + 0 * t])
    try:
        driver = client.publisher(topics.topic_name(device, topics.MEASURED_JS),
                                  interfaces.JOINT_STATE)  # fmt: skip
        assert pubsub.wait_for_subscribers(driver.zenoh_publisher, TIMEOUT_S)
        for k in range(n):
            names, position, effort = saw_measured_js(
                q[k],
                np.zeros(3),
                tau_nm[k] * 1e3,
                np.zeros(3),  # OpenHaptics: mN m
            )
            ros = sensor_msgs.JointState()
            ros.header.stamp.sec, ros.header.stamp.nanosec = divmod(T0_NS + k * 2_000_000, 10**9)
            ros.name, ros.position, ros.effort = list(names), list(position), list(effort)
            put(driver, serialization.serialize_message(ros), k + 1)  # no velocity, as it sends
        wait_until(lambda: len(estimates) == n, "the estimates")
    finally:
        estimates.close()
        client.close()
        service.close()
    offline = ForceEstimator(model)
    for k, estimate in enumerate(estimates.messages):
        expected = offline.update(k * 2e-3, q[k], tau_nm[k])
        np.testing.assert_allclose(estimate.f_n, expected.force_tip_in_base_n, rtol=0, atol=1e-9)
