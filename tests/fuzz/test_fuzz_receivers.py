"""Fuzzed payloads over real Zenoh: the service and the slave count and drop them, and go on.

The service (recording every ROS 2 sample of the domain) runs on a loopback session; the test
publishes mutated messages of every type on its joint-state key, and fuzzed samples with and
without valid attachments on rmw_zenoh keys, from a second session, predicts which ones are
malformed, and checks the service's counters and its recording against that.
``TELEOP_FUZZ_EXAMPLES=N`` sets the number of payloads per key (default 400).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from master_slave.slave import SetpointInbox
from teleop_force.errors import MessageError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.mcap_session import SessionReader
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import graph
from teleop_force.ros2 import topics as ros_topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE, ForceService, ServiceConfig
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import declare_data_publisher, query_json

from .strategies import mutate_bytes
from .targets import count, fuzzed_payloads, message_examples

DEVICE = "fuzz-slave"
N_PAYLOADS = int(os.environ.get("TELEOP_FUZZ_EXAMPLES") or 400)


def own_joint_state_is_valid(payload: bytes) -> bool:
    try:
        js = m.JointState.decode(payload)
    except MessageError:
        return False
    values = np.abs(np.array(js.q_rad + js.qd_rad_s + js.effort_nm))
    return js.n_joints == 3 and bool(np.all(values <= MAX_ABS_JOINT_VALUE))


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def _ros2_samples(n: int, gid: bytes) -> dict[str, list[tuple[bytes, bytes | None]]]:
    """Fuzzed (payload, attachment) samples on rmw_zenoh keys of the domain, and a non-topic key."""
    domain = graph.domain_id_from_env()
    rng = np.random.default_rng(7)
    keys_ = [
        ros_topics.data_key("fuzz_slave", ros_topics.TRUE_CF, domain),
        ros_topics.data_key("fuzz_master", ros_topics.SETPOINT_JS, domain),
        ros_topics.data_key("fuzz_slave", ros_topics.STATUS, domain),
        f"{domain}/not_a_topic_key",
    ]
    out: dict[str, list[tuple[bytes, bytes | None]]] = {}
    for i, key in enumerate(keys_):
        payloads = fuzzed_payloads(n, seed=10 + i)
        rows: list[tuple[bytes, bytes | None]] = []
        for k, payload in enumerate(payloads):
            choice = k % 5
            if choice == 0:
                attachment = None
            elif choice == 1:
                attachment = rng.bytes(int(rng.integers(0, 40)))
            else:
                attachment = Attachment(k + 1, time.time_ns(), gid).encode()
            rows.append((payload, attachment))
        out[key] = rows
    return out


def _recorded(key: str, attachment: bytes | None) -> bool:
    """Whether the recorder writes a sample: a topic key and a valid attachment."""
    try:
        graph.parse_topic_key(key)
        if attachment is None:
            return False
        Attachment.decode(attachment)
    except MessageError:
        return False
    return True


@pytest.mark.zenoh
def test_service_counts_and_drops_fuzzed_payloads_and_keeps_estimating(zenoh_pair):
    own = keys.measured_js(DEVICE)
    payloads = fuzzed_payloads(N_PAYLOADS, seed=0)
    expected_valid = sum(map(own_joint_state_is_valid, payloads))
    samples = _ros2_samples(N_PAYLOADS, b"\x07" * 16)
    expected_recorded = {
        key: sum(_recorded(key, a) for _, a in rows) for key, rows in samples.items()
    }
    folder = Path(tempfile.mkdtemp(prefix="fuzz-service-"))
    record = folder / "fuzz.mcap"
    service_session, session = zenoh_pair.listener, zenoh_pair.connector
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(
        service_session, model, ServiceConfig(device=DEVICE, record_path=record)
    ).start()
    publisher = declare_data_publisher(session, own)
    ros_publishers = {key: declare_data_publisher(session, key) for key in samples}
    got: list[m.ForceEstimateMessage] = []
    sub = session.declare_subscriber(
        keys.estimated_cf(DEVICE),
        lambda s: got.append(m.ForceEstimateMessage.decode(s.payload.to_bytes())),
    )
    try:
        for pub in (publisher, *ros_publishers.values()):
            wait_until(lambda p=pub: p.matching_status.matching, 20.0, "the service to subscribe")
        time.sleep(0.2)
        for k in range(N_PAYLOADS):
            publisher.put(payloads[k])
            for key, pub in ros_publishers.items():
                payload, attachment = samples[key][k]
                pub.put(payload, attachment=attachment)

        def stats():
            return query_json(session, keys.service_stats(DEVICE), 5.0)

        def settled():
            st_ = stats()
            own_seen = st_["joint_states"]["received"] + st_["malformed"]["by_key"].get(own, 0)
            return (
                own_seen == N_PAYLOADS and st_["recording"]["received"] == len(samples) * N_PAYLOADS
            )

        wait_until(settled, 60.0, "the service to process every payload")
        time.sleep(0.3)
        after_fuzz = stats()
        # It still estimates on good joint states (a new stream).
        n_before = len(got)
        for k in range(200):
            q = (0.1, 0.8 + 1e-3 * k, 0.3)
            good = m.JointState(k, 1_800_000_000_000_000_000 + k * 1_000_000, q, (0.0,) * 3,
                                (0.0, 0.1, 0.05))  # fmt: skip
            publisher.put(good.encode())
        wait_until(lambda: len(got) >= n_before + 200, 30.0, "estimates after the fuzzing")
    finally:
        sub.undeclare()
        for pub in (publisher, *ros_publishers.values()):
            pub.undeclare()
        service.close()
    malformed = after_fuzz["malformed"]["by_key"]
    assert malformed.get(own, 0) == N_PAYLOADS - expected_valid
    assert after_fuzz["joint_states"]["received"] == expected_valid
    js, est = after_fuzz["joint_states"], after_fuzz["estimates"]
    assert est["published"] + est["errors"] + js["duplicates"] == js["received"]
    for key, written in expected_recorded.items():
        assert malformed.get(key, 0) == N_PAYLOADS - written, key
    counts = SessionReader(record).message_counts
    for key, written in expected_recorded.items():
        if written and key.split("/")[1] != "not_a_topic_key":
            topic, _ = graph.parse_topic_key(key)
            assert counts[topic] == written, key  # the bytes as received, whatever they are
    assert sum(counts.values()) == sum(expected_recorded.values())
    refused = sum(N_PAYLOADS - w for w in expected_recorded.values())
    count("service: fuzzed payloads over Zenoh", "malformed, counted",
          refused + N_PAYLOADS - expected_valid)  # fmt: skip
    count("service: fuzzed payloads over Zenoh", "valid",
          sum(expected_recorded.values()) + expected_valid)  # fmt: skip


class FakeSample:
    """What the slave's setpoint callback reads from a Zenoh sample."""

    class _Payload:
        def __init__(self, data: bytes) -> None:
            self.data = data

        def to_bytes(self) -> bytes:
            return self.data

    def __init__(self, data: bytes) -> None:
        self.payload = self._Payload(data)


_SETPOINT_SEEDS = [x.encode() for x in message_examples()]


@settings(max_examples=N_PAYLOADS, deadline=None)
@given(
    st.lists(
        st.one_of(
            st.binary(max_size=80), st.sampled_from(_SETPOINT_SEEDS).flatmap(mutate_bytes),
            st.sampled_from(_SETPOINT_SEEDS),
        ),
        min_size=1,
        max_size=20,
    )
)  # fmt: skip
def test_slave_counts_and_drops_fuzzed_setpoints(batch):
    inbox = SetpointInbox()
    valid = 0
    for payload in batch:
        try:
            ok = m.JointSetpoint.decode(payload).n_joints == 3
        except MessageError:
            ok = False
        valid += ok
        inbox.on_sample(FakeSample(payload))  # never raises
    stats = inbox.stats()
    assert stats["valid"] == valid
    assert stats["malformed"] == len(batch) - valid
    q, _arrival, n = inbox.latest()
    assert n == valid and (q is None) == (valid == 0)
    count("slave: fuzzed setpoints (SetpointInbox)", "valid", valid)
    count("slave: fuzzed setpoints (SetpointInbox)", "malformed, counted", len(batch) - valid)
