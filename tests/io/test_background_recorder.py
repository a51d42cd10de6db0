"""BackgroundRecorder: raw payloads recorded in batches off the receive threads."""

import threading
import time

import pytest

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.service.recorder import BackgroundRecorder
from teleop_force.service.recording_state import RecordingState
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from tests.io.crash_harness import kill_when_durable

T0 = 1_700_000_000_000_000_000
JS, CF, ST = keys.measured_js("s"), keys.measured_cf("s"), keys.status("s")


def joint_state(k):
    return m.JointState(k, T0 + k * 1000, (0.1, 0.2 + 1e-3 * k, 0.3), (0.0,) * 3, (0.01,) * 3)


def wait_until(predicate, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def test_payloads_and_objects_are_all_recorded_in_order(tmp_path):
    path = tmp_path / "r.mcap"
    recorder = BackgroundRecorder(SessionWriter(path))
    for k in range(3000):
        js = joint_state(k)
        recorder.submit(JS, js.encode() if k % 3 else js, T0 + k * 1000)
        if k % 10 == 0:
            cf = m.ContactForce(k, T0, (0.0, 0.1 * k, 0.0))
            recorder.submit(CF, bytearray(cf.encode()) if k % 20 else cf, T0 + k * 1000 + 1)
        if k % 500 == 0:
            recorder.submit(ST, m.Status(k, T0, m.SafetyState.FOLLOWING, "ok").encode(), T0 + k)
    recorder.close()
    stats = recorder.stats()
    assert stats["messages"] == 3000 + 300 + 6
    assert stats["dropped"] == 0 and stats["malformed"] == 0 and stats["backlog"] == 0
    assert stats["durable"] == stats["messages"]
    reader = SessionReader(path)
    assert reader.message_counts == {JS: 3000, CF: 300, ST: 6}
    got = [(ns, x) for _, ns, x in reader.messages([JS])]
    assert [x.seq for _, x in got] == list(range(3000))
    assert all(x == joint_state(x.seq) for _, x in got)


def test_malformed_payloads_are_counted_with_their_key_and_dropped(tmp_path):
    seen = []
    recorder = BackgroundRecorder(
        SessionWriter(tmp_path / "bad.mcap"), lambda key, exc: seen.append((key, exc))
    )
    recorder.submit(JS, joint_state(0).encode(), T0)
    recorder.submit(JS, b"garbage", T0 + 1)
    recorder.submit(JS, m.ContactForce(1, T0, (0.0, 0.0, 0.0)).encode(), T0 + 2)  # wrong class
    recorder.submit(CF, joint_state(1).encode()[:-1], T0 + 3)  # truncated
    recorder.submit(JS, joint_state(2).encode(), T0 + 4)
    recorder.submit(JS, object(), T0 + 5)  # neither payload nor message
    recorder.close()
    assert [key for key, _ in seen] == [JS, JS, CF, JS]
    assert isinstance(seen[0][1], MessageError)
    assert isinstance(seen[1][1], DataError) and "carries JointState" in str(seen[1][1])
    assert recorder.stats()["messages"] == 2 and recorder.stats()["malformed"] == 4
    assert SessionReader(tmp_path / "bad.mcap").message_counts == {JS: 2}


def test_the_backlog_is_bounded_and_drops_are_counted(tmp_path):
    writer = SessionWriter(tmp_path / "slow.mcap")
    release = threading.Event()
    original = writer.write_payloads

    def slow(*args):
        release.wait(10.0)
        return original(*args)

    writer.write_payloads = slow
    recorder = BackgroundRecorder(writer, max_backlog=100, batch_interval_s=0.001)
    payload = joint_state(0).encode()
    for k in range(300):  # queued or in a blocked batch: 100 at most either way
        recorder.submit(JS, payload, T0 + k)
    assert recorder.backlog == 100
    assert recorder.dropped == 200
    release.set()
    recorder.close()
    assert recorder.stats()["messages"] == 100
    assert recorder.stats()["backlog"] == 0
    assert SessionReader(tmp_path / "slow.mcap").message_counts == {JS: 100}


def test_submissions_after_close_are_ignored(tmp_path):
    recorder = BackgroundRecorder(SessionWriter(tmp_path / "c.mcap"))
    recorder.submit(JS, joint_state(0).encode(), T0)
    recorder.close()
    recorder.close()
    recorder.submit(JS, joint_state(1).encode(), T0 + 1)
    assert recorder.stats()["messages"] == 1 and recorder.backlog == 0


def test_an_idle_recorder_still_flushes(tmp_path):
    writer = SessionWriter(tmp_path / "idle.mcap", flush_interval_s=0.05)
    recorder = BackgroundRecorder(writer)
    for k in range(10):
        recorder.submit(JS, joint_state(k).encode(), T0 + k)
    wait_until(lambda: recorder.stats()["durable"] == 10, 5.0)  # no further submit needed
    recorder.close()


def test_write_errors_are_reported_per_message(tmp_path):
    seen = []
    writer = SessionWriter(tmp_path / "e.mcap")
    recorder = BackgroundRecorder(writer, lambda key, exc: seen.append((key, exc)))
    writer.close()  # as if the disk went away: every write now fails
    recorder.submit(JS, joint_state(0).encode(), T0)
    recorder.submit(CF, m.ContactForce(0, T0, (0.0, 0.0, 0.0)).encode(), T0)
    wait_until(lambda: len(seen) == 2)
    assert [key for key, _ in seen] == [JS, CF]
    assert all(isinstance(exc, DataError) for _, exc in seen)
    recorder.close()


def test_an_unexpected_error_in_a_batch_is_reported_and_the_thread_lives_on(tmp_path):
    seen = []
    writer = SessionWriter(tmp_path / "b.mcap")
    recorder = BackgroundRecorder(writer, lambda key, exc: seen.append((key, exc)))
    write_payloads = writer.write_payloads
    calls = []

    def failing_once(*args):
        calls.append(1)
        if len(calls) == 1:
            raise ValueError("a bug in a converter")
        return write_payloads(*args)

    writer.write_payloads = failing_once  # type: ignore[method-assign]
    recorder.submit(JS, joint_state(0).encode(), T0)
    wait_until(lambda: len(seen) == 1)
    assert seen[0][0] == JS and isinstance(seen[0][1], DataError)
    assert "ValueError: a bug in a converter" in str(seen[0][1])
    recorder.submit(JS, joint_state(1).encode(), T0 + 1000)
    wait_until(lambda: recorder.written == 1)
    recorder.close()
    assert [message.seq for _, _, message in SessionReader(tmp_path / "b.mcap").messages()] == [1]


def test_options_are_checked(tmp_path):
    writer = SessionWriter(tmp_path / "o.mcap")
    with pytest.raises(ConfigurationError):
        BackgroundRecorder(writer, max_backlog=0)
    with pytest.raises(ConfigurationError):
        BackgroundRecorder(writer, batch_interval_s=0.0)
    writer.close()


def test_recording_state_reports_the_open_recorder(tmp_path):
    state = RecordingState()
    assert state.current_stats() is None
    state.recorder = BackgroundRecorder(SessionWriter(tmp_path / "s.mcap"))
    state.recorder.submit(JS, joint_state(0).encode(), T0)
    state.recorder.close()
    assert state.current_stats()["messages"] == 1


CRASH_RECORDER = """
import sys, time
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.service.recorder import BackgroundRecorder
writer = SessionWriter(sys.argv[1], chunk_size_bytes=16384, flush_interval_s=0.05)
recorder = BackgroundRecorder(writer)
k = 0
last = -1
while True:
    t = time.time_ns()
    js = m.JointState(k, t, (0.1, 0.2, 0.3), (0.0,) * 3, (0.01,) * 3).encode()
    recorder.submit(keys.measured_js("slave"), js, t)
    recorder.submit(keys.measured_cf("slave"), m.ContactForce(k, t, (0.0, 1.0, 0.0)).encode(), t)
    k += 1
    durable = recorder.stats()["durable"]
    if durable != last:
        last = durable
        print(durable, flush=True)
    if k % 10 == 0:
        time.sleep(0.001)
"""


def test_sigkill_of_a_recording_process_keeps_what_was_durable(tmp_path):
    path = tmp_path / "crash.mcap"
    durable, _, stderr = kill_when_durable(CRASH_RECORDER, path, 5000)
    assert durable >= 5000, f"recorder did not get going: {stderr}"
    reader = SessionReader(path)
    assert reader.truncated
    assert sum(1 for _ in reader) == len(reader) >= durable
