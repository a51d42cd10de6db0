"""Fuzzed payloads over real Zenoh: the service and the slave count and drop them, and go on.

The service runs on a loopback session; the test publishes mutated CDR messages of every
topic on its ``/<device>/measured_js`` from a second session (a ROS 2 node), some without
rmw_zenoh's attachment, predicts which ones are malformed, and checks the service's counters
against that. ``TELEOP_FUZZ_EXAMPLES=N`` sets the number of payloads (default 400).
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from master_slave.slave import SetpointInbox
from teleop_force.errors import MessageError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import codec, streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE, ForceService, ServiceConfig
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import query_json
from tests.ros2_traffic import Collector, JointStatePublisher

from .strategies import mutate_bytes
from .targets import count, fuzzed_ros2_payloads, ros2_seeds

DEVICE = "fuzz_slave"
N_PAYLOADS = int(os.environ.get("TELEOP_FUZZ_EXAMPLES") or 400)
NAMES = topics.OMNI_MODEL_JOINT_NAMES
#: Every this many payloads, one is sent without rmw_zenoh's attachment.
NO_ATTACHMENT_EVERY = 37


def own_joint_state_is_valid(payload: bytes) -> bool:
    try:
        js, named = codec.decode_joint_state(payload, 0)
        streams.check_joint_names(named.names, NAMES)
    except MessageError:
        return False
    values = np.abs(np.array(js.q_rad + js.qd_rad_s + js.effort_nm))
    return js.n_joints == 3 and bool(np.all(values <= MAX_ABS_JOINT_VALUE))


def wait_until(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


@pytest.mark.zenoh
def test_service_counts_and_drops_fuzzed_payloads_and_keeps_estimating(zenoh_pair):
    own = topics.topic_name(DEVICE, topics.MEASURED_JS)
    payloads = fuzzed_ros2_payloads(N_PAYLOADS, seed=0)
    bare = {k for k in range(N_PAYLOADS) if k % NO_ATTACHMENT_EVERY == 5}
    expected_valid = sum(
        own_joint_state_is_valid(p) for k, p in enumerate(payloads) if k not in bare
    )
    service_session, session = zenoh_pair.listener, zenoh_pair.connector
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    service = ForceService(service_session, model, ServiceConfig(device=DEVICE)).start()
    pub = JointStatePublisher(session, DEVICE)
    got = Collector(session, DEVICE, topics.ESTIMATED_CF)
    try:
        wait_until(lambda: pub.publisher.zenoh_publisher.matching_status.matching, 20.0,
                   "the service to subscribe")  # fmt: skip
        time.sleep(0.2)
        for k, payload in enumerate(payloads):
            if k in bare:
                pub.publisher.zenoh_publisher.put(payload)  # no attachment
            else:
                pub.send_raw(payload, k + 1)

        def stats():
            return query_json(session, keys.service_stats(DEVICE), 5.0)

        def settled():
            st_ = stats()
            seen = st_["joint_states"]["received"] + st_["malformed"]["by_key"].get(own, 0)
            return seen + service._ros2.malformed_attachments == N_PAYLOADS

        wait_until(settled, 60.0, "the service to process every payload")
        time.sleep(0.3)
        after_fuzz = stats()
        # It still estimates on good joint states (a new stream).
        n_before = len(got)
        for k in range(200):
            q = (0.1, 0.8 + 1e-3 * k, 0.3)
            good = m.JointState(k, 1_800_000_000_000_000_000 + k * 1_000_000, q, (0.0,) * 3,
                                (0.0, 0.1, 0.05))  # fmt: skip
            pub.send(good)
        wait_until(lambda: len(got) >= n_before + 200, 30.0, "estimates after the fuzzing")
    finally:
        got.close()
        pub.close()
        service.close()
    malformed = after_fuzz["malformed"]["by_key"]
    assert malformed.get(own, 0) == N_PAYLOADS - len(bare) - expected_valid
    assert after_fuzz["joint_states"]["received"] == expected_valid
    js, est = after_fuzz["joint_states"], after_fuzz["estimates"]
    assert est["published"] + est["errors"] + js["duplicates"] == js["received"]
    count("service: fuzzed payloads over Zenoh", "malformed, counted",
          N_PAYLOADS - expected_valid)  # fmt: skip
    count("service: fuzzed payloads over Zenoh", "valid", expected_valid)


_SETPOINT_SEEDS = ros2_seeds()
_GID = bytes(range(16))


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
    for k, payload in enumerate(batch):
        try:
            setpoint, named = codec.decode_joint_setpoint(payload, 0)
            ok = setpoint.n_joints == 3 and named.names in ((), NAMES)
        except MessageError:
            ok = False
        valid += ok
        inbox.on_sample(payload, Attachment(k + 1, time.time_ns(), _GID))  # never raises
    stats = inbox.stats()
    assert stats["valid"] == valid
    assert stats["malformed"] == len(batch) - valid
    q, _arrival, n = inbox.latest()
    assert n == valid and (q is None) == (valid == 0)
    count("slave: fuzzed setpoints (SetpointInbox)", "valid", valid)
    count("slave: fuzzed setpoints (SetpointInbox)", "malformed, counted", len(batch) - valid)
