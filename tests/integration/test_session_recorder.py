"""The session recorder process's subscriptions: FIFO channels drained into an MCAP session."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.service.session_recorder import SessionRecorder, final_line
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import (
    declare_data_publisher,
    declare_queue_subscriber,
    wait_for_subscribers,
)

_COUNT = 600


def _publish_and_record(zenoh_pair: Any, path: Path, stamp_offset_ns: int) -> SessionRecorder:
    writer = SessionWriter(path, {"primary_device": "slave", "source": "live"})
    recorder = SessionRecorder(zenoh_pair.listener, writer, "slave").start()
    publisher = declare_data_publisher(zenoh_pair.connector, keys.measured_js("slave"))
    try:
        assert wait_for_subscribers(publisher, 5.0)
        for seq in range(_COUNT):
            stamp = time.time_ns() + stamp_offset_ns
            publisher.put(m.pack_joint_state(seq, stamp, (0.1, 0.2, 0.3), (0, 0, 0), (0, 0, 0)))
            if seq % 100 == 0:
                time.sleep(0.03)  # several drains, not one
        publisher.put(b"not a message")
        deadline = time.monotonic() + 5.0
        while recorder.received < _COUNT + 1 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        publisher.undeclare()
        recorder.close()
    return recorder


def test_every_message_recorded_with_log_time_from_its_stamp(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "session.mcap"
    before_ns = time.time_ns()
    recorder = _publish_and_record(zenoh_pair, path, 0)
    after_ns = time.time_ns()
    stats = recorder.stats()
    assert stats["received"] == _COUNT + 1
    assert stats["recorder"]["messages"] == _COUNT
    assert stats["malformed"]["dropped"] == 1
    assert final_line(stats) == (
        f"stopped: {_COUNT} messages written to {path} ({_COUNT + 1} received, 0 dropped, "
        "1 malformed)"
    )
    rows = list(SessionReader(path).messages([keys.measured_js("slave")]))
    assert [message.seq for _, _, message in rows] == list(range(_COUNT))
    log_times = [log_ns for _, log_ns, _ in rows]
    assert log_times == sorted(log_times)
    for _, log_ns, message in rows:
        # received after it was stamped, within the drain interval it arrived in
        assert message.t_ns <= log_ns <= message.t_ns + 500_000_000
        assert before_ns <= log_ns <= after_ns
    exact = sum(log_ns == message.t_ns for _, log_ns, message in rows)
    assert exact >= 0.5 * _COUNT  # most arrive within the interval they were stamped in


def test_stamp_from_another_clock_clamped_into_the_drain_interval(
    zenoh_pair: Any, tmp_path: Path
) -> None:
    path = tmp_path / "session.mcap"
    before_ns = time.time_ns()
    _publish_and_record(zenoh_pair, path, -3600 * 10**9)  # an hour behind
    after_ns = time.time_ns()
    rows = list(SessionReader(path).messages([keys.measured_js("slave")]))
    assert len(rows) == _COUNT
    for _, log_ns, message in rows:
        assert log_ns > message.t_ns
        assert before_ns <= log_ns <= after_ns
    log_times = [log_ns for _, log_ns, _ in rows]
    assert log_times == sorted(log_times)


def test_queue_subscriber_refuses_an_empty_fifo(zenoh_pair: Any) -> None:
    with pytest.raises(ConfigurationError, match="queue capacity"):
        declare_queue_subscriber(zenoh_pair.listener, keys.measured_js("slave"), 0)
