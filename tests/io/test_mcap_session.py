import dataclasses
import json
import math
import signal
import threading

import numpy as np
import pytest
from mcap.reader import make_reader

from teleop_force.errors import DataError
from teleop_force.io.mcap_session import SessionReader, SessionWriter, read_session_as_recording
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from tests.io import cdr_reference
from tests.io.crash_harness import kill_when_durable

T0 = 1_700_000_000_000_000_000


def joint_state(i, n=3, t0=T0):
    q = tuple(0.1 * j + 1e-4 * i for j in range(n))
    return m.JointState(i, t0 + i * 1_000_000, q, (0.5,) * n, tuple(0.01 * j for j in range(n)))


def force_estimate(i):
    return m.ForceEstimateMessage(
        i,
        T0 + i * 1_000_000 + 300_000,
        i,
        (math.nan, -1.0, 0.0) if i % 7 == 0 else (0.1, -1.0, 0.2),
        (0.1, 0.2, 0.3),
        (True, i % 2 == 0, True),
        (1.0, 0.5, 0.25),
        (0.0, 0.1, 0.2),
        (0.0, 0.1, 0.1),
    )


def write_demo(path, n=400, **kwargs):
    written = []
    with SessionWriter(path, {"robot": "omni", "primary_device": "slave"}, **kwargs) as w:
        for i in range(n):
            items = [
                (keys.measured_js("slave"), joint_state(i)),
                (keys.estimated_cf("slave"), force_estimate(i)),
            ]
            if i % 4 == 0:
                cf = m.ContactForce(i, T0 + i * 1_000_000, (0.0, -0.001 * i, 0.0))
                items.append((keys.measured_cf("slave"), cf))
            if i % 100 == 0:
                st = m.Status(i, T0 + i * 1_000_000, m.SafetyState.FOLLOWING, f"step {i}")
                items.append((keys.status("slave"), st))
                items.append((keys.setpoint_js("slave"), m.JointSetpoint(i, T0, (0.1, 0.2, 0.3))))
            for topic, message in items:
                log_ns = message.t_ns + 50_000
                w.write(topic, message, log_ns)
                written.append((topic, log_ns, message))
    return written


def same(a, b):
    return a.to_json_dict() == b.to_json_dict()


def reference_values(message):
    """What the spec-written CDR decoder should find for ``message``."""
    values = {"seq": message.seq, "t_ns": message.t_ns}
    if isinstance(message, m.Status):
        return {**values, "state": int(message.state), "reason": message.reason}
    for name in (f.name for f in dataclasses.fields(message)):
        if name not in values:
            field = getattr(message, name)
            values[name] = list(field) if isinstance(field, tuple) else field
    return cdr_reference.normalised(values)


def in_log_time_order(written):
    """What a reader yields: by log time; equal log times of one key in write order."""
    return sorted(written, key=lambda item: item[1])


def assert_same_items(got, written):
    """Same messages: log-time order overall, write order within each key."""
    expected = in_log_time_order(written)
    assert [ns for _, ns, _ in got] == [ns for _, ns, _ in expected]
    for topic in {t for t, _, _ in written}:
        mine = [(ns, x) for t, ns, x in got if t == topic]
        theirs = [(ns, x) for t, ns, x in expected if t == topic]
        assert len(mine) == len(theirs)
        for (ns_a, a), (ns_b, b) in zip(mine, theirs, strict=True):
            assert ns_a == ns_b and type(a) is type(b) and same(a, b)


@pytest.mark.parametrize("encoding", ["cdr", "json"])
def test_round_trip_in_time_order(tmp_path, encoding):
    path = tmp_path / "s.mcap"
    written = write_demo(path, chunk_size_bytes=4096, message_encoding=encoding)
    reader = SessionReader(path)
    assert not reader.truncated
    assert reader.metadata["robot"] == "omni"
    assert reader.metadata["format"] == "teleop-force-session"
    assert reader.metadata["format_version"] == {"cdr": "2", "json": "1"}[encoding]
    assert (
        reader.topics[keys.measured_js("slave")]
        == {
            "cdr": "teleop_force/msg/JointState",
            "json": "teleop_force.JointState",
        }[encoding]
    )
    assert reader.devices() == ["slave"]
    assert len(reader) == len(written)
    assert_same_items(list(reader), written)


def test_out_of_order_log_times_across_chunks_are_sorted(tmp_path):
    path = tmp_path / "s.mcap"
    rng = np.random.default_rng(1)
    log_times = T0 + rng.permutation(3000) * 1000
    with SessionWriter(path, chunk_size_bytes=2048) as w:
        for i, log_ns in enumerate(log_times):
            w.write(keys.measured_js("a"), joint_state(i), int(log_ns))
    stamps = [ns for _, ns, _ in SessionReader(path)]
    assert stamps == sorted(int(x) for x in log_times)


def test_topic_filter(tmp_path):
    path = tmp_path / "s.mcap"
    write_demo(path, n=100)
    topics = {t for t, _, _ in SessionReader(path).messages([keys.status("slave")])}
    assert topics == {keys.status("slave")}


def test_readable_by_the_official_mcap_reader_as_foxglove_cdr(tmp_path):
    path = tmp_path / "s.mcap"
    written = write_demo(path, n=50)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == len(written)
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        got = []
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            # Decoded from the schema text in the file, by the spec-written decoder.
            values, _ = cdr_reference.decode(schema.data.decode(), message.data)
            assert message.sequence == values["seq"]
            assert message.publish_time == values["t_ns"]
            got.append((channel.topic, message.log_time, values))
    assert len(got) == len(written)
    by_topic = {}
    for topic, ns, message in in_log_time_order(written):
        by_topic.setdefault(topic, []).append((ns, message))
    for topic, expected in by_topic.items():
        mine = [(ns, values) for t, ns, values in got if t == topic]
        for (ns_a, values), (ns_b, message) in zip(mine, expected, strict=True):
            assert ns_a == ns_b
            assert cdr_reference.normalised(values) == reference_values(message)


def test_json_sessions_are_readable_by_the_official_mcap_reader(tmp_path):
    path = tmp_path / "s.mcap"
    write_demo(path, n=50, message_encoding="json")
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count > 0
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        for schema in summary.schemas.values():
            assert json.loads(schema.data)["type"] == "object"
        count = 0
        for _schema, channel, message in reader.iter_messages():
            body = json.loads(message.data)
            assert "seq" in body and "t_ns" in body
            assert keys.parse(channel.topic).device == "slave"
            count += 1
        assert count == summary.statistics.message_count


def test_session_as_recording(tmp_path):
    path = tmp_path / "s.mcap"
    write_demo(path, n=200)
    rec = read_session_as_recording(path)
    assert rec.n_samples == 200 and rec.n_joints == 3 and rec.has_force
    np.testing.assert_allclose(rec.t_s, np.arange(200) * 1e-3, atol=1e-12)
    np.testing.assert_allclose(rec.q_rad[:, 0], 1e-4 * np.arange(200))
    np.testing.assert_allclose(rec.tau_nm[5], (0.0, 0.01, 0.02))
    # Force recorded every 4th sample, linearly interpolated in between, held after the last.
    np.testing.assert_allclose(rec.f_tip_in_base_n[:197, 1], -0.001 * np.arange(197), atol=1e-12)
    np.testing.assert_allclose(rec.f_tip_in_base_n[197:, 1], -0.196)
    assert rec.source == path


def test_session_as_recording_device_choice(tmp_path):
    path = tmp_path / "two.mcap"
    with SessionWriter(path) as w:
        for i in range(10):
            w.write(keys.measured_js("master"), joint_state(i), T0 + i)
            w.write(keys.measured_js("slave"), joint_state(i, n=2), T0 + i)
    with pytest.raises(DataError, match="several devices"):
        read_session_as_recording(path)
    assert read_session_as_recording(path, device="slave").n_joints == 2
    assert read_session_as_recording(path, device="master").n_joints == 3
    with pytest.raises(DataError, match="no joint states for device"):
        read_session_as_recording(path, device="other")


def test_session_without_joint_states(tmp_path):
    path = tmp_path / "none.mcap"
    with SessionWriter(path) as w:
        w.write(keys.status("x"), m.Status(0, 0, m.SafetyState.STARTING), T0)
    with pytest.raises(DataError, match="no joint states"):
        read_session_as_recording(path)


def test_duplicate_and_reordered_joint_states(tmp_path):
    path = tmp_path / "dup.mcap"
    with SessionWriter(path) as w:
        for i in (0, 2, 1, 1, 3):
            w.write(keys.measured_js("a"), joint_state(i), T0 + 10 * i)
    rec = read_session_as_recording(path)
    np.testing.assert_allclose(rec.t_s, [0.0, 1e-3, 2e-3, 3e-3])
    assert not rec.has_force


def test_changing_joint_count_is_reported(tmp_path):
    path = tmp_path / "n.mcap"
    with SessionWriter(path) as w:
        w.write(keys.measured_js("a"), joint_state(0, n=3), T0)
        w.write(keys.measured_js("a"), joint_state(1, n=2), T0 + 1)
    with pytest.raises(DataError, match="joint count changes"):
        read_session_as_recording(path)


def test_channel_type_is_fixed(tmp_path):
    with SessionWriter(tmp_path / "x.mcap") as w:
        w.write("omni/a/measured_js", joint_state(0), T0)
        with pytest.raises(DataError, match="carries JointState"):
            w.write("omni/a/measured_js", m.JointSetpoint(0, 0, (1.0,)), T0)


def test_concurrent_writers_lose_nothing(tmp_path):
    path = tmp_path / "threads.mcap"
    with SessionWriter(path, chunk_size_bytes=4096) as w:

        def run(device):
            for i in range(1000):
                w.write(keys.measured_js(device), joint_state(i), T0 + i)

        threads = [threading.Thread(target=run, args=(d,)) for d in ("a", "b", "c")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert SessionReader(path).message_counts == {
        keys.measured_js(d): 1000 for d in ("a", "b", "c")
    }


def test_truncated_at_every_point_is_readable_up_to_the_last_chunk(tmp_path):
    path = tmp_path / "full.mcap"
    write_demo(path, n=300, chunk_size_bytes=2048)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    previous = 0
    for size in range(8, len(data), max(1, len(data) // 97)):
        cut.write_bytes(data[:size])
        reader = SessionReader(cut)
        assert reader.truncated
        count = sum(1 for _ in reader)
        assert count == len(reader) >= previous
        previous = count
    assert previous > 0.9 * len(SessionReader(path))


CRASH_WRITER = """
import sys, time
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.io.mcap_session import SessionWriter
w = SessionWriter(sys.argv[1], {"robot": "omni"}, chunk_size_bytes=16384, flush_interval_s=0.05)
last = -1
i = 0
while True:
    t = time.time_ns()
    js = m.JointState(i, t, (0.1, 0.2, 0.3), (0.0,) * 3, (0.01,) * 3)
    w.write(keys.measured_js("slave"), js, t)
    w.write(keys.estimated_cf("slave"),
            m.ForceEstimateMessage(i, t, i, (0.0, -1.0, 0.0), (0.1,) * 3, (True,) * 3, (1.0,) * 3,
                            (0.0,) * 3, (0.0,) * 3), t)
    i += 1
    if w.messages_durable != last:
        last = w.messages_durable
        print(last, flush=True)
    if i % 50 == 0:
        time.sleep(0.001)
"""


def test_sigkill_mid_recording_leaves_a_readable_file(tmp_path):
    path = tmp_path / "crash.mcap"
    durable, returncode, stderr = kill_when_durable(CRASH_WRITER, path, 6000)
    assert durable >= 6000, f"writer did not get going: {stderr}"
    assert returncode == -signal.SIGKILL
    reader = SessionReader(path)
    assert reader.truncated
    count = sum(1 for _ in reader)
    assert count >= 0.99 * durable
    # Each key has its own chunks: the joint states alone are about half of what was durable.
    rec = read_session_as_recording(path)
    assert rec.n_samples == reader.message_counts[keys.measured_js("slave")]
    assert rec.n_samples >= 0.4 * durable


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b"", "not an MCAP file"),
        (b"t,q1,tau1\n0,1,2\n", "not an MCAP file"),
        (b"\x89MCAP0\r", "not an MCAP file"),
    ],
)
def test_bad_files_raise_data_error_naming_the_file(tmp_path, content, problem):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(DataError, match=problem) as info:
        SessionReader(path)
    assert str(path) in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(DataError, match="cannot read"):
        SessionReader(tmp_path / "nope.mcap")
    with pytest.raises(DataError, match="directory"):
        SessionReader(tmp_path)


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_corrupted_chunk_is_reported(tmp_path, compression):
    path = tmp_path / "c.mcap"
    write_demo(path, n=200, compression=compression)
    data = bytearray(path.read_bytes())
    middle = len(data) // 3
    for i in range(middle, middle + 64):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))
    with pytest.raises(DataError) as info:
        for _ in SessionReader(path):
            pass
    assert str(path) in str(info.value)


def test_foreign_json_channels_are_returned_as_json(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "foreign.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        sid = writer.register_schema("other.Thing", "jsonschema", b'{"type":"object"}')
        cid = writer.register_channel("other/topic", "json", sid)
        writer.add_message(cid, log_time=5, data=b'{"a": 1}', publish_time=5)
        writer.finish()
    assert list(SessionReader(path)) == [("other/topic", 5, {"a": 1})]


def test_writer_options_are_checked(tmp_path):
    from teleop_force.errors import ConfigurationError

    with pytest.raises(ConfigurationError):
        SessionWriter(tmp_path / "a.mcap", compression="brotli")
    with pytest.raises(ConfigurationError):
        SessionWriter(tmp_path / "a.mcap", chunk_size_bytes=10)
    with pytest.raises(DataError, match="cannot create"):
        SessionWriter(tmp_path / "no" / "such" / "dir.mcap")
    w = SessionWriter(tmp_path / "b.mcap")
    w.close()
    w.close()
    with pytest.raises(DataError, match="closed"):
        w.write(keys.measured_js("a"), joint_state(0))
