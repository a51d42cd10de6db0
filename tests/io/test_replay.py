"""Replay over Zenoh: a session's streams published as ROS 2 messages, old sessions encoded."""

from __future__ import annotations

import queue
import time
from pathlib import Path
from typing import Any

import pytest

from teleop_force.errors import DataError
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.io.replay import ReplayConfig, replay_session
from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.transport import keys
from teleop_force.transport import messages as m

pytestmark = pytest.mark.zenoh
EPOCH_NS = 1_700_000_000_000_000_000
NAMES = topics.OMNI_MODEL_JOINT_NAMES
N = 200


def _joint_state(k: int) -> m.JointState:
    return m.JointState(k + 10, EPOCH_NS + k * 1_000_000, (0.01 * k, 0.2, 0.3), (0.0,) * 3,
                        (0.1, 0.0, -0.1))  # fmt: skip


def _write_old(path: Path) -> None:
    """A session recorded before ROS 2: the project's CDR channels on Zenoh keys."""
    with SessionWriter(path, {"primary_device": "slave"}) as writer:
        for k in range(N):
            log = EPOCH_NS + k * 1_000_000 + 50_000
            writer.write(keys.measured_js("slave"), _joint_state(k), log)
            force = m.ContactForce(k, EPOCH_NS + k * 1_000_000, (0.0, 0.0, 1.0))
            writer.write(keys.measured_cf("slave"), force, log + 1)


def _write_new(path: Path) -> list[bytes]:
    """A ROS 2 session; return the recorded joint-state payloads."""
    payloads = []
    with SessionWriter(path, {"primary_device": "slave"}, profile="ros2") as writer:
        for k in range(N):
            js = _joint_state(k)
            payload = codec.encode_joint_state(js, NAMES)
            payloads.append(payload)
            log = EPOCH_NS + k * 1_000_000 + 50_000
            writer.write_ros2("/slave/measured_js", interfaces.JOINT_STATE, payload, js.seq,
                              js.t_ns, log)  # fmt: skip
    return payloads


def _replay_to_subscriber(zenoh_pair: Any, path: Path, restamp: bool) -> tuple[list, Any]:
    """Replay ``path`` on the listener; return what a ROS 2 subscription on the connector got."""
    got: queue.Queue = queue.Queue()
    node = Node(zenoh_pair.connector, "replay_test", domain_id=graph.domain_id_from_env())
    forces: queue.Queue = queue.Queue()
    try:
        node.subscription(
            "/slave/measured_js", interfaces.JOINT_STATE, lambda p, a: got.put((p, a))
        )
        node.subscription("/slave/true_cf", interfaces.WRENCH_STAMPED, lambda p, a: forces.put(p))
        config = ReplayConfig(path, speed=0.0, restamp=restamp, wait_subscribers_s=10.0)
        result = replay_session(zenoh_pair.listener, config)
        rows = [got.get(timeout=10.0) for _ in range(N)]
        deadline = time.monotonic() + 5.0
        while forces.qsize() < result.published.get("/slave/true_cf", 0):
            assert time.monotonic() < deadline, "true forces not all received"
            time.sleep(0.01)
    finally:
        node.close()
    return rows, result


def test_a_ros2_session_is_replayed_as_recorded(zenoh_pair: Any, tmp_path: Path) -> None:
    path = tmp_path / "new.mcap"
    payloads = _write_new(path)
    rows, result = _replay_to_subscriber(zenoh_pair, path, restamp=False)
    assert result.matched and result.published == {"/slave/measured_js": N}
    assert [payload for payload, _ in rows] == payloads  # the bytes as recorded
    assert [a.sequence_number for _, a in rows] == [k + 10 for k in range(N)]


def test_a_replay_shifts_the_stamps_to_now_and_nothing_else(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "new.mcap"
    _write_new(path)
    before_ns = time.time_ns()
    rows, _ = _replay_to_subscriber(zenoh_pair, path, restamp=True)
    decoded = [codec.decode_joint_state(payload, a.sequence_number)[0] for payload, a in rows]
    shift = decoded[0].t_ns - EPOCH_NS
    assert decoded[0].t_ns >= before_ns
    for k, js in enumerate(decoded):
        assert js.t_ns == EPOCH_NS + k * 1_000_000 + shift  # one constant shift
        assert js.q_rad == _joint_state(k).q_rad and js.seq == k + 10


def test_an_old_session_is_replayed_as_ros2_messages(zenoh_pair: Any, tmp_path: Path) -> None:
    path = tmp_path / "old.mcap"
    _write_old(path)
    rows, result = _replay_to_subscriber(zenoh_pair, path, restamp=False)
    assert result.published == {"/slave/measured_js": N, "/slave/true_cf": N}
    for k, (payload, attachment) in enumerate(rows):
        js, named = codec.decode_joint_state(payload, attachment.sequence_number)
        assert js == _joint_state(k)  # the recorded seq and stamp, encoded with the codec
        assert named.names == NAMES


def test_a_session_without_the_devices_joint_states_is_refused(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "new.mcap"
    _write_new(path)
    with pytest.raises(DataError, match="no joint states"):
        replay_session(zenoh_pair.listener, ReplayConfig(path, device="master"))
