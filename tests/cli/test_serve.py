"""``teleop-force serve``: the service alone, as a lab starts it against a live device."""

from __future__ import annotations

import time

import numpy as np
import pytest

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import topics
from teleop_force.transport import keys
from teleop_force.transport.pubsub import query_json
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)
from tests.integration.teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop, wait_for
from tests.ros2_traffic import Collector, JointStatePublisher, joint_states_500hz

pytestmark = pytest.mark.zenoh
DEVICE = "lab_slave"
DOMAIN = 7


def test_serve_estimates_on_a_live_device_and_says_when_it_falls_silent(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN))  # the test's own nodes: the lab's domain
    endpoint = listen_endpoint(free_tcp_port())
    log_path = tmp_path / "serve.log"
    process = spawn(
        python_module(
            "teleop_force.cli.main", "serve", "--model", str(DEFAULT_MODEL_PATH),
            "--device", DEVICE, "--ros-domain-id", str(DOMAIN), "--listen", endpoint,
            "--no-multicast", "--no-residual-watch",
        ),
        log_path,
    )  # fmt: skip
    session = open_session(ZenohOptions(connect=(endpoint,), multicast_scouting=False))
    driver = estimates = None
    try:
        wait_for(lambda: "no joint state yet" in log_path.read_text(), STARTUP_TIMEOUT_S,
                 "the silence line")  # fmt: skip
        driver = JointStatePublisher(session, DEVICE, "sensable_phantom")
        estimates = Collector(session, DEVICE, topics.ESTIMATED_CF)
        wait_for(lambda: driver.publisher.zenoh_publisher.matching_status.matching, 30.0,
                 "the service's subscription")  # fmt: skip
        time.sleep(0.2)
        stream = joint_states_500hz(300)
        for js in stream:
            driver.send(js)
        wait_for(lambda: len(estimates) == len(stream), 30.0, "the estimates")
        stats = query_json(session, keys.service_stats(DEVICE), 5.0)
        lines = []

        def lines_in_order() -> bool:
            lines[:] = [x for x in log_path.read_text().splitlines() if "joint state" in x]
            return len(lines) >= 3

        wait_for(lines_in_order, 10.0, "the silence, resume and silence lines")
    finally:
        for entity in (estimates, driver):
            if entity is not None:
                entity.close()
        session.close()
        assert stop(process) == 0, log_path.read_text()
    assert stats["joint_states"]["received"] == len(stream)
    assert "no joint state yet on /lab_slave/measured_js" in lines[0]
    assert "ROS domain 7" in lines[0]
    assert "joint states on /lab_slave/measured_js again" in lines[1]
    assert "no joint state on /lab_slave/measured_js for 1.0 s" in lines[2]
    offline = ForceEstimator(DynamicModel.load(DEFAULT_MODEL_PATH))
    t0 = stream[0].t_ns
    for js, estimate in zip(stream, estimates.messages, strict=True):
        expected = offline.update((js.t_ns - t0) * 1e-9, np.array(js.q_rad), np.array(js.effort_nm))
        assert estimate.source_seq == js.seq
        assert estimate.f_n == tuple(expected.force_tip_in_base_n)


def test_serve_refuses_a_bad_model_with_one_line(tmp_path):
    import subprocess

    result = subprocess.run(
        python_module("teleop_force.cli.main", "serve", "--model", str(tmp_path / "none.json")),
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2
    assert "none.json" in result.stderr and "Traceback" not in result.stderr
