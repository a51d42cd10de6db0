"""The service publishes its residual watch's diagnostics over Zenoh, off the 1 kHz path.

Two loopback peers (tests/conftest.py): the service on one, a client on the other that
streams ROS 2 JointStates on ``/<device>/measured_js``, subscribes to
``/<device>/service/diagnostics`` (teleop_force_msgs/ServiceDiagnostics) and queries the
statistics, as the dashboard does.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from ros2_traffic import Collector, JointStatePublisher

from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import topics
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.service.residual_watch import Finding
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import query_json

pytestmark = pytest.mark.zenoh
DEVICE = "watch_test"
T0_NS = 1_700_000_000_000_000_000


def _wait_until(predicate, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_the_service_publishes_diagnostics_and_a_finding_with_its_command(zenoh_pair) -> None:
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(
        zenoh_pair.listener, model, ServiceConfig(device=DEVICE), model_path=DEFAULT_MODEL_PATH
    ).start()
    client = zenoh_pair.connector
    diagnostics = Collector(client, DEVICE, topics.SERVICE_DIAGNOSTICS)
    got: list[m.ServiceDiagnostics] = diagnostics.messages
    estimates = Collector(client, DEVICE, topics.ESTIMATED_CF, node_name="test_estimates")
    driver = JointStatePublisher(client, DEVICE)
    try:
        _wait_until(lambda: driver.publisher.zenoh_publisher.matching_status.matching)
        t = np.arange(2000) * 1e-3
        for k in range(t.size):
            q = (0.1 * np.sin(t[k]), 0.9 + 0.2 * np.sin(2 * t[k]), 0.4)
            js = m.JointState(k, T0_NS + k * 1_000_000, tuple(map(float, q)), (0.0,) * 3,
                              (0.0, 0.1, 0.0))  # fmt: skip
            driver.send(js)
        _wait_until(lambda: len(estimates) == t.size)
        _wait_until(lambda: any(d.stream_s > 1.5 for d in got))
        first = got[-1]
        stats = query_json(client, keys.service_stats(DEVICE))
        # a finding (planted in the watch: a real one needs a minute of stream) is published
        # with the command to run next
        assert service.residual_watch is not None
        service.residual_watch.findings[1] = Finding(1, "tau2", 0.1, 0.015, 1e-12, 70.0, 66.0)
        count = len(got)
        _wait_until(lambda: len(got) > count + 1)
        last = got[-1]
    finally:
        for closing in (estimates, diagnostics, driver):
            closing.close()
        service.close()
    assert not diagnostics.malformed and not estimates.malformed
    assert [e.source_seq for e in estimates.messages] == list(range(t.size))
    assert first.device == DEVICE and first.state == "baseline"
    assert first.finding is None and first.command == ""
    assert stats["residual_watch"]["samples"] == t.size
    assert stats["residual_watch"]["errors"] == 0, stats["residual_watch"]["last_error"]
    assert last.state == "dependence"
    assert last.finding is not None and (last.finding.joint, last.finding.variable) == (2, "tau2")
    assert last.command == f"teleop-force residual RECORDING --model {DEFAULT_MODEL_PATH}"


def test_the_watch_can_be_switched_off(zenoh_session) -> None:
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(zenoh_session, model, ServiceConfig(device=DEVICE, residual_watch=False))
    try:
        assert service.residual_watch is None
        assert service.stats()["residual_watch"] is None
    finally:
        service.close()
