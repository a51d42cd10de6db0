"""The service's own recording: every ROS 2 message of the domain, its own estimates included."""

from __future__ import annotations

import queue
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.mcap_session import SessionReader
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport import messages as m
from web.control import ServiceClient

pytestmark = pytest.mark.zenoh
DEVICE = "rec_test"
_NAMES = topics.OMNI_MODEL_JOINT_NAMES


@pytest.fixture(scope="module")
def model() -> DynamicModel:
    return DynamicModel.load(DEFAULT_MODEL_PATH)


def _joint_states(n: int, t0_ns: int = 1_700_000_000_000_000_000) -> list[m.JointState]:
    t = np.arange(n) * 1e-3
    q = np.column_stack([0.2 * np.sin(2 * t), 0.8 + 0.3 * np.sin(3 * t), 0.3 + 0.1 * t])
    tau = np.column_stack([0.02 * np.sin(5 * t), 0.15 + 0.0 * t, 0.05 + 0.01 * np.sin(7 * t)])
    return [m.JointState(0, t0_ns + k * 1_000_000, q[k], np.zeros(3), tau[k]) for k in range(n)]


def _wait_until(predicate: Any, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


class _Client:
    """A ROS 2 node publishing joint states and hearing the estimates, on the client's session."""

    def __init__(self, session: Any) -> None:
        self.node = Node(session, "recording_test_client", domain_id=graph.domain_id_from_env())
        self.js = self.node.publisher(topics.topic_name(DEVICE, topics.MEASURED_JS),
                                      interfaces.JOINT_STATE)  # fmt: skip
        self.wrenches: queue.Queue = queue.Queue()
        self.node.subscription(topics.topic_name(DEVICE, topics.ESTIMATED_CF),
                               interfaces.WRENCH_STAMPED,
                               lambda p, a: self.wrenches.put((p, a)))  # fmt: skip
        self.sent: list[Any] = []

    def publish(self, states: list[m.JointState]) -> None:
        for js in states:
            self.sent.append(self.js.publish(codec.encode_joint_state(js, _NAMES)))

    def received(self, n: int) -> list[tuple[bytes, Any]]:
        return [self.wrenches.get(timeout=10.0) for _ in range(n)]


def test_the_service_records_the_ros2_messages_and_its_own_estimates(
    zenoh_pair: Any, model: DynamicModel, tmp_path: Path
) -> None:
    record = tmp_path / "svc.mcap"
    config = ServiceConfig(device=DEVICE, record_path=record, residual_watch=False)
    service = ForceService(zenoh_pair.listener, model, config, model_path=DEFAULT_MODEL_PATH)
    service.start()
    client = _Client(zenoh_pair.connector)
    try:
        _wait_until(lambda: client.js.zenoh_publisher.matching_status.matching)
        time.sleep(0.1)
        client.publish(_joint_states(300))
        heard = client.received(300)
        _wait_until(lambda: service.stats()["recording"]["messages"] >= 900)
    finally:
        client.node.close()
        service.close()
    last = service.stats()["last_recording"]
    assert last["path"] == str(record) and last["messages"] == 900 and last["malformed"] == 0
    with open(record, "rb") as f:
        assert make_reader(f).get_header().profile == "ros2"
    reader = SessionReader(record)
    assert reader.metadata["primary_device"] == DEVICE
    assert reader.metadata["model"] == str(DEFAULT_MODEL_PATH)
    assert reader.metadata["recorder"] == "teleop_force.service.force_service"
    assert reader.metadata["estimator"] == model.filter_config.estimator  # a replay runs it
    assert reader.message_counts == {
        f"/{DEVICE}/measured_js": 300,
        f"/{DEVICE}/estimated_cf": 300,  # published by the service, heard by its own session
        f"/{DEVICE}/estimate_diagnostics": 300,
    }
    raw_wrenches = [r.data for r in reader.raw_messages([f"/{DEVICE}/estimated_cf"])]
    assert raw_wrenches == [payload for payload, _ in heard]  # the bytes as published
    estimates = [e for _, _, e in reader.messages([f"/{DEVICE}/estimated_cf"])]
    assert [e.seq for e in estimates] == [a.sequence_number for _, a in heard]
    # each joined with its diagnostics: computed from the joint state of that sequence number
    assert [e.source_seq for e in estimates] == [a.sequence_number for a in client.sent]
    assert [e.f_n for e in estimates] == [codec.decode_wrench(p).force_n for p, _ in heard]
    states = [js for _, _, js in reader.messages([f"/{DEVICE}/measured_js"])]
    assert [js.seq for js in states] == [a.sequence_number for a in client.sent]
    with AnyReader([record]) as bag:  # rosbags decodes the project's types from the schemas
        (connection,) = [c for c in bag.connections if c.topic.endswith("estimate_diagnostics")]
        assert connection.msgtype == interfaces.ESTIMATE_DIAGNOSTICS
        reports = [bag.deserialize(raw, connection.msgtype)
                   for _, _, raw in bag.messages([connection])]  # fmt: skip
    assert [int(r.source_sequence) for r in reports] == [e.source_seq for e in estimates]
    assert [list(r.external_torque_nm) for r in reports] == [list(e.tau_ext_nm) for e in estimates]


def test_a_recording_starts_and_stops_on_request(
    zenoh_pair: Any, model: DynamicModel, tmp_path: Path
) -> None:
    config = ServiceConfig(device=DEVICE, residual_watch=False, record_dirs=(tmp_path,))
    service = ForceService(zenoh_pair.listener, model, config).start()
    control = ServiceClient(zenoh_pair.connector, DEVICE, timeout_s=5.0)
    client = _Client(zenoh_pair.connector)
    target = tmp_path / "run.mcap"
    try:
        _wait_until(lambda: control.fetch_stats(timeout_s=1.0).ok, 20.0)
        _wait_until(lambda: client.js.zenoh_publisher.matching_status.matching)
        time.sleep(0.1)
        client.publish(_joint_states(50))  # before the recording: not in it
        client.received(50)
        reply = control.set_recording(True, target)
        assert reply.ok and reply.data == {"ok": True, "path": str(target.resolve())}, reply.text
        again = control.set_recording(True, tmp_path / "second.mcap")
        assert not again.ok and "already recording" in again.text
        client.publish(_joint_states(100, t0_ns=1_800_000_000_000_000_000))
        client.received(100)
        _wait_until(lambda: service.stats()["recording"]["messages"] >= 300)
        stop = control.set_recording(False)
        assert stop.ok, stop.text
        assert stop.data["messages"] == 300 and stop.data["malformed"] == 0
        not_recording = control.set_recording(False)
        assert not not_recording.ok and "not recording" in not_recording.text
    finally:
        client.node.close()
        service.close()
    counts = SessionReader(target).message_counts
    assert counts[f"/{DEVICE}/measured_js"] == 100
    assert counts[f"/{DEVICE}/estimated_cf"] == counts[f"/{DEVICE}/estimate_diagnostics"] == 100
