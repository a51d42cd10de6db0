"""Ros2Recorder: the domain's ROS 2 messages drained from a FIFO into a session, crash-safe."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.io.cdr_columns import read_joint_state_arrays
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node
from teleop_force.service.recording_state import RecordingState
from teleop_force.service.ros2_recorder import Ros2Recorder, recorded_key
from teleop_force.transport import messages as m
from tests.io.crash_harness import kill_when_durable

DOMAIN = 0
NAMES = topics.OMNI_MODEL_JOINT_NAMES


def _payload(k: int) -> bytes:
    js = m.JointState(0, 1_700_000_000_000_000_000 + k, (0.1, 0.2, 0.3), (0.0,) * 3, (0.0,) * 3)
    return codec.encode_joint_state(js, NAMES)


def _wait_until(predicate: Any, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


@pytest.mark.zenoh
def test_samples_that_are_no_ros2_messages_are_counted_with_their_key(
    zenoh_session: Any, tmp_path: Path
) -> None:
    seen: list[tuple[str, Exception]] = []
    writer = SessionWriter(tmp_path / "s.mcap", profile="ros2")
    recorder = Ros2Recorder(
        zenoh_session, writer, lambda key, exc: seen.append((key, exc)), domain_id=DOMAIN
    )
    state = RecordingState()
    state.recorder = recorder.start()
    node = Node(zenoh_session, "recorder_unit_test", domain_id=DOMAIN)
    try:
        publisher = node.publisher("/slave/measured_js", interfaces.JOINT_STATE)
        publisher.publish(_payload(0))  # recorded (the session hears itself)
        zenoh_session.put(publisher.key, _payload(1))  # no attachment
        zenoh_session.put(publisher.key, _payload(2), attachment=b"short")  # a bad one
        zenoh_session.put(f"{DOMAIN}/not_a_topic_key", b"x")
        attachment = Attachment(9, 1, publisher.gid).encode()  # a topic whose type changes
        zenoh_session.put(
            "0/slave/measured_js/geometry_msgs::msg::dds_::WrenchStamped_/RIHS01_0",
            b"\x00\x01\x00\x00",
            attachment=attachment,
        )
        zenoh_session.put("1/slave/measured_js/x", b"other domain: not heard")
        _wait_until(lambda: recorder.received == 5)
    finally:
        node.close()
        recorder.close()
    assert state.current_stats() == {
        "path": str(writer.path), "messages": 1, "durable": 1, "received": 5, "backlog": 0,
        "dropped": 0, "malformed": 4,
    }  # fmt: skip
    # by topic where the key names one (as the service counts its input), else by key
    assert sorted(key for key, _ in seen) == sorted([
        "/slave/measured_js", "/slave/measured_js", f"{DOMAIN}/not_a_topic_key",
        "/slave/measured_js",
    ])  # fmt: skip
    assert any("carries" in str(exc) for _, exc in seen)
    assert sum("attachment" in str(exc) for _, exc in seen) == 2
    assert SessionReader(writer.path).message_counts == {"/slave/measured_js": 1}


@pytest.mark.zenoh
def test_an_idle_recorder_still_hands_its_chunks_to_the_os(
    zenoh_session: Any, tmp_path: Path
) -> None:
    writer = SessionWriter(tmp_path / "s.mcap", profile="ros2", flush_interval_s=0.1)
    recorder = Ros2Recorder(zenoh_session, writer, domain_id=DOMAIN).start()
    node = Node(zenoh_session, "recorder_unit_test", domain_id=DOMAIN)
    try:
        node.publisher("/slave/measured_js", interfaces.JOINT_STATE).publish(_payload(0))
        _wait_until(lambda: writer.messages_durable == 1)  # no further message needed
    finally:
        node.close()
        recorder.close()


@pytest.mark.zenoh
def test_a_message_arriving_while_a_drain_writes_keeps_its_source_time(
    zenoh_session: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its log time is clamped into [FIFO found empty, next drain], not after the writing."""
    writing, release = threading.Event(), threading.Event()
    slow_write = SessionWriter.write_ros2_block

    def write_slowly(self: SessionWriter, *args: Any, **kwargs: Any) -> None:
        writing.set()
        release.wait(10.0)
        slow_write(self, *args, **kwargs)

    monkeypatch.setattr(SessionWriter, "write_ros2_block", write_slowly)
    writer = SessionWriter(tmp_path / "s.mcap", profile="ros2")
    recorder = Ros2Recorder(zenoh_session, writer, domain_id=DOMAIN).start()
    node = Node(zenoh_session, "recorder_unit_test", domain_id=DOMAIN)
    try:
        publisher = node.publisher("/slave/measured_js", interfaces.JOINT_STATE)
        publisher.publish(_payload(0), time.time_ns())
        assert writing.wait(10.0)  # the first drain took it and is writing now
        during_ns = time.time_ns()
        publisher.publish(_payload(1), during_ns)
        time.sleep(0.05)
        release.set()
        _wait_until(lambda: recorder.received == 2)
    finally:
        release.set()
        node.close()
        recorder.close()
    raw = list(SessionReader(writer.path).raw_messages())
    assert raw[1].publish_time_ns == during_ns
    assert raw[1].log_time_ns == during_ns


def test_options_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigurationError):
        recorded_key(-1)
    assert recorded_key(3) == "3/**"


CRASH_RECORDER = """
import sys, time
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.service.ros2_recorder import Ros2Recorder
from teleop_force.transport import messages as m
from teleop_force.transport.session import ZenohOptions, open_session
session = open_session(ZenohOptions(mode="peer", listen=("tcp/127.0.0.1:0",),
                                    multicast_scouting=False))
writer = SessionWriter(sys.argv[1], chunk_size_bytes=16384, flush_interval_s=0.05,
                       profile="ros2")
recorder = Ros2Recorder(session, writer, domain_id=0).start()
node = Node(session, "crash_test", domain_id=0)
js = node.publisher("/slave/measured_js", interfaces.JOINT_STATE)
cf = node.publisher("/slave/true_cf", interfaces.WRENCH_STAMPED)
names = topics.OMNI_MODEL_JOINT_NAMES
k = 0
last = -1
while True:
    t = time.time_ns()
    state = m.JointState(k, t, (0.1, 0.2, 0.3), (0.0,) * 3, (0.01,) * 3)
    js.publish(codec.encode_joint_state(state, names), t)
    cf.publish(codec.encode_contact_force(m.ContactForce(k, t, (0.0, 1.0, 0.0)), "base"), t)
    k += 1
    durable = writer.messages_durable
    if durable != last:
        last = durable
        print(durable, flush=True)
    if k % 10 == 0:
        time.sleep(0.001)
"""


def test_sigkill_of_a_recording_process_keeps_what_was_durable(tmp_path: Path) -> None:
    path = tmp_path / "crash.mcap"
    durable, _, stderr = kill_when_durable(CRASH_RECORDER, path, 5000)
    assert durable >= 5000, f"recorder did not get going: {stderr}"
    reader = SessionReader(path)
    assert reader.truncated
    assert sum(1 for _ in reader.raw_messages()) == len(reader) >= durable
    states = [js for _, _, js in reader.messages(["/slave/measured_js"])]
    arrays = read_joint_state_arrays(path, "/slave/measured_js")  # the last chunk: unindexed
    assert arrays.seq.tolist() == [js.seq for js in states]
    assert arrays.seq.tolist()[:3] == [1, 2, 3]  # the attachment's sequence numbers
