"""The force-estimation service on a real (local) Zenoh session."""

import dataclasses
import math
import time

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.process.memory import MemoryTrimmer
from teleop_force.ros2 import topics
from teleop_force.service.adaptation import AdaptationGate
from teleop_force.service.force_service import ForceService, ServiceConfig
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import query_json
from tests.ros2_traffic import Collector, JointStatePublisher

pytestmark = pytest.mark.zenoh
DEVICE = "svc_test"
JS_TOPIC = topics.topic_name(DEVICE, topics.MEASURED_JS)


@pytest.fixture(scope="module")
def model():
    return DynamicModel.load(DEFAULT_MODEL_PATH)


@pytest.fixture(scope="module")
def cv_model(model):
    """The shipped model with its wavelet network's coupled-CV fallback as the friction."""
    assert isinstance(model.friction, WaveletNetwork)
    return dataclasses.replace(model, friction=model.friction.fallback)


@pytest.fixture
def session(zenoh_session):
    """The service's and the test's loopback peer (tests/conftest.py)."""
    return zenoh_session


def joint_states(n=300, seq0=0, t0_ns=1_700_000_000_000_000_000):
    t = np.arange(n) * 1e-3
    q = np.column_stack(
        [0.2 * np.sin(2 * t), 0.8 + 0.3 * np.sin(3 * t), 0.3 + 0.4 * np.cos(1.5 * t)]
    )
    q = np.round(q / 4e-4) * 4e-4
    tau = np.column_stack(
        [0.02 * np.sin(5 * t), 0.15 + 0.02 * np.cos(t), 0.05 + 0.01 * np.sin(7 * t)]
    )
    return [
        m.JointState(seq0 + k, t0_ns + k * 1_000_000, q[k], np.zeros(3), tau[k]) for k in range(n)
    ]


def wait_until(predicate, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_estimates_equal_the_offline_estimator_and_stats_add_up(session, model):
    service = ForceService(session, model, ServiceConfig(device=DEVICE)).start()
    got = Collector(session, DEVICE, topics.ESTIMATED_CF)
    pub = JointStatePublisher(session, DEVICE)
    try:
        stream = joint_states()
        for js in stream[:100] + stream[102:]:  # two lost
            pub.send(js)
        pub.send_raw(b"garbage", 1000)
        pub.send(stream[0], topics.DRIVER_JOINT_NAMES)  # the driver's relative elbow
        pub.send(m.JointState(0, 0, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)), ())  # 2 joints
        wait_until(lambda: len(got) == 298)
        stats = query_json(session, keys.service_stats(DEVICE))
        served_model = query_json(session, keys.service_model(DEVICE))
    finally:
        got.close()
        pub.close()
        service.close()
    assert stats["joint_states"]["received"] == 298
    assert stats["joint_states"]["lost"] == 2
    assert stats["malformed"]["dropped"] == 3
    assert stats["malformed"]["by_key"] == {JS_TOPIC: 3}
    assert stats["estimates"]["published"] == 298
    assert stats["latency_ms"]["count"] == 298
    assert 0.0 <= stats["on_ground_fraction"] <= 1.0
    assert served_model == model.to_dict()
    # Same floats as the estimator run offline on the same samples.
    offline = ForceEstimator(DynamicModel.load(DEFAULT_MODEL_PATH))
    t0 = stream[0].t_ns
    for js, estimate in zip(stream[:100] + stream[102:], got.messages, strict=True):
        expected = offline.update((js.t_ns - t0) * 1e-9, np.array(js.q_rad), np.array(js.effort_nm))
        assert estimate.source_seq == js.seq
        assert estimate.f_n == tuple(expected.force_tip_in_base_n)
        assert estimate.tau_ext_nm == tuple(expected.tau_external_nm)


def test_a_stream_restart_resets_the_estimator(session, model):
    service = ForceService(session, model, ServiceConfig(device=DEVICE)).start()
    got = Collector(session, DEVICE, topics.ESTIMATED_CF)
    pub = JointStatePublisher(session, DEVICE)
    try:
        first = joint_states(50)
        for js in first:
            pub.send(js)
        # The same samples again, later (a replay): seq goes back -> new stream.
        for js in joint_states(50, t0_ns=1_800_000_000_000_000_000):
            pub.send(js)
        wait_until(lambda: len(got) == 100)
        stats = service.stats()
    finally:
        got.close()
        pub.close()
        service.close()
    assert stats["joint_states"]["restarts"] == 1
    assert stats["joint_states"]["stream_restarts"] == 1
    assert stats["joint_states"]["lost"] == 0
    for a, b in zip(
        got.messages[:50], got.messages[50:], strict=True
    ):  # bit-identical after the reset
        assert a.f_n == b.f_n or all(math.isnan(x) for x in a.f_n + b.f_n)
        assert a.tau_model_filtered_nm == b.tau_model_filtered_nm


def test_adaptation_is_refused_without_a_wavelet_network(session, cv_model):
    service = ForceService(session, cv_model, ServiceConfig(device=DEVICE)).start()
    try:
        session.put(keys.service_adapt(DEVICE), "on")
        time.sleep(0.05)
        stats = service.stats()
        with pytest.raises(ConfigurationError, match="coupled-cv"):
            service.set_adaptation(True)
    finally:
        service.close()
    assert stats["adaptation"]["enabled"] is False
    assert stats["adaptation"]["available"] is False


def test_adaptation_runs_on_a_wavelet_network_model(session, cv_model):
    model = cv_model
    network = WaveletNetwork(3, omni_wavelet_specs(), fallback=model.friction)
    wn_model = DynamicModel(
        model.robot, model.n_joints, model.filter_config, model.base, model.base_values,
        model.base_std, network, model.offsets_nm,
    )  # fmt: skip
    service = ForceService(session, wn_model, ServiceConfig(device=DEVICE)).start()
    # these synthetic joint states read as > 0.5 N on the untrained network: open the gate
    service.adaptation_state.gate = AdaptationGate(force_threshold_n=1e6, guard_s=0.0)
    got = Collector(session, DEVICE, topics.ESTIMATED_CF)
    pub = JointStatePublisher(session, DEVICE)
    try:
        before = network.parameters.copy()
        session.put(keys.service_adapt(DEVICE), "on")
        wait_until(lambda: service.adaptation_state.enabled)
        for js in joint_states(200):
            pub.send(js)
        wait_until(lambda: len(got) == 200)
        session.put(keys.service_adapt(DEVICE), "off")
        wait_until(lambda: not service.adaptation_state.enabled)
        stats = service.stats()
    finally:
        got.close()
        pub.close()
        service.close()
    assert stats["adaptation"]["available"] is True
    assert stats["adaptation"]["samples"] == 200
    after = network.parameters
    assert after.size != before.size or not np.array_equal(after, before)  # it learnt something


def test_stats_report_the_process_memory_trimmer(session, model):
    trimmer = MemoryTrimmer(period_s=0.05).start()
    service = ForceService(session, model, ServiceConfig(device=DEVICE), memory=trimmer).start()
    try:
        wait_until(lambda: service.stats()["memory"]["trims"] >= 2)
        memory = service.stats()["memory"]
    finally:
        service.close()
        trimmer.stop()
    assert memory["available"] and memory["period_s"] == 0.05
    assert memory["rss_mb"] > 10.0 and memory["released_mb"] >= 0.0
    assert ForceService(session, model, ServiceConfig(device=DEVICE)).stats()["memory"] is None


def test_stats_keep_their_keys(session, model):
    service = ForceService(session, model, ServiceConfig(device=DEVICE))
    stats = service.stats()
    assert list(stats) == [
        "role", "device", "model", "uptime_s", "joint_states", "estimates", "zenoh_floor",
        "malformed",
        "latency_ms", "processing_ms", "on_ground_fraction", "on_ground_fraction_per_joint",
        "adaptation", "recording", "last_recording", "memory", "controls", "last_estimate",
        "residual_watch",
    ]  # fmt: skip
    assert list(stats["model"]) == ["path", "robot", "friction", "loads"]
    assert list(stats["joint_states"]) == [
        "received", "lost", "restarts", "duplicates", "stream_restarts", "backlog",
        "overflow_dropped", "rate_hz", "mean_rate_hz",
    ]  # fmt: skip
    assert list(stats["estimates"]) == ["published", "singular", "errors", "last_error"]
    assert list(stats["malformed"]) == ["dropped", "by_key", "last", "without_attachment"]
    assert list(stats["adaptation"]) == [
        "enabled", "available", "note", "samples", "skipped_contact", "pending", "dropped",
        "batches", "publications", "errors", "last_error", "batch_ms", "force_threshold_n",
        "guard_s",
    ]  # fmt: skip
    assert list(stats["controls"]) == ["requests", "refused", "last_refusal"]
    assert stats["on_ground_fraction"] is None and stats["last_estimate"] is None
    assert stats["recording"] is None and stats["last_recording"] is None


def test_estimate_seqs_count_on_across_stream_restarts(session, model):
    service = ForceService(session, model, ServiceConfig(device=DEVICE)).start()
    got = Collector(session, DEVICE, topics.ESTIMATED_CF)
    pub = JointStatePublisher(session, DEVICE)
    try:
        for js in joint_states(30) + joint_states(30, t0_ns=1_800_000_000_000_000_000):
            pub.send(js)
        pub.send(joint_states(1, seq0=29, t0_ns=1_800_000_000_029_000_000)[0])  # dup
        wait_until(lambda: len(got) == 60)
        time.sleep(0.05)
        stats = service.stats()
    finally:
        got.close()
        pub.close()
        service.close()
    assert [e.seq for e in got.messages] == list(range(1, 61))  # rmw_zenoh counts from 1
    assert [e.source_seq for e in got.messages] == [*range(30), *range(30)]
    assert (
        stats["joint_states"]["duplicates"] == 1 and stats["joint_states"]["stream_restarts"] == 1
    )
    assert stats["last_estimate"]["source_seq"] == 29 and len(got) == 60
