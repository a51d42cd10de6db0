"""SessionWriter.write_payloads: batches of wire payloads, checked and converted per key."""

import math
import time

import numpy as np
import pytest

from teleop_force.errors import DataError, MessageError
from teleop_force.io.mcap_session import SessionReader, SessionWriter
from teleop_force.transport import keys
from teleop_force.transport import messages as m

T0 = 1_700_000_000_000_000_000
JS, CF, ST, EST, SP = (
    keys.measured_js("s"),
    keys.measured_cf("s"),
    keys.status("s"),
    keys.estimated_cf("s"),
    keys.setpoint_js("m"),
)


def mixed(count, n=3):
    """``(key, message, log time)`` of a demo-like stream."""
    out = []
    for k in range(count):
        t = T0 + k * 1_000_000
        q = tuple(0.1 * j + 1e-3 * k for j in range(n))
        out.append((JS, m.JointState(k, t, q, (0.5,) * n, (0.01,) * n), t + 10))
        out.append((CF, m.ContactForce(k, t, (0.0, -0.001 * k, 0.0)), t + 20))
        out.append((SP, m.JointSetpoint(k, t, q), t + 30))
        flags = tuple(j != k % n for j in range(n))
        force = (math.nan, 0.0, 1.0) if k % 5 == 0 else (0.1, 0.2, 0.3)
        estimate = m.ForceEstimateMessage(k, t + 5, k, force, q, flags, q, q, q)
        out.append((EST, estimate, t + 40))
        if k % 10 == 0:
            out.append((ST, m.Status(k, t, m.SafetyState.FOLLOWING, f"step {k} ✓"), t + 50))
    return out


def write_batches(path, items, batch, **kwargs):
    rejected = []
    with SessionWriter(path, chunk_size_bytes=2048, **kwargs) as writer:
        for start in range(0, len(items), batch):
            part = items[start : start + batch]
            got = writer.write_payloads(
                [k for k, _, _ in part],
                [p if isinstance(p, bytes) else p.encode() for _, p, _ in part],
                [t for _, _, t in part],
            )
            rejected += [(start + i, exc) for i, exc in got]
    return rejected


@pytest.mark.parametrize("batch", [1, 7, 1000])
@pytest.mark.parametrize("n", [1, 3, 7])
def test_batches_record_the_same_messages_as_single_writes(tmp_path, batch, n):
    items = mixed(60, n)
    assert write_batches(tmp_path / "b.mcap", items, batch) == []
    with SessionWriter(tmp_path / "s.mcap") as writer:
        for key, message, log_ns in items:
            writer.write(key, message, log_ns)
    got = list(SessionReader(tmp_path / "b.mcap"))
    singles = list(SessionReader(tmp_path / "s.mcap"))
    assert [(t, ns, x.to_json_dict()) for t, ns, x in got] == [
        (t, ns, x.to_json_dict()) for t, ns, x in singles
    ]
    assert len(got) == len(items)
    expected = sorted(items, key=lambda item: item[2])
    for (topic, ns, message), (key, original, log_ns) in zip(got, expected, strict=True):
        assert (topic, ns) == (key, log_ns)
        assert message.to_json_dict() == original.to_json_dict()


def test_malformed_payloads_are_rejected_and_the_rest_written(tmp_path):
    good = [m.JointState(k, T0 + k, (0.1, 0.2, 0.3), (0.0,) * 3, (0.0,) * 3) for k in range(6)]
    bad_version = bytearray(good[1].encode())
    bad_version[2] = 99
    infinite = bytearray(good[2].encode())
    infinite[17:25] = np.float64(np.inf).tobytes()
    payloads = [
        good[0].encode(),
        bytes(bad_version),
        b"garbage",
        bytes(infinite),
        good[3].encode(),
        m.ContactForce(9, T0, (0.0, 0.0, 0.0)).encode(),  # valid, but not the key's class
        good[4].encode(),
        good[5].encode(),
    ]
    path = tmp_path / "bad.mcap"
    with SessionWriter(path) as writer:
        rejected = writer.write_payloads([JS] * len(payloads), payloads, [T0 + i for i in range(8)])
        assert writer.messages_written == 4
    assert [i for i, _ in rejected] == [1, 2, 3, 5]
    assert all(isinstance(exc, MessageError) for i, exc in rejected if i != 5)
    assert isinstance(rejected[-1][1], DataError) and "carries JointState" in str(rejected[-1][1])
    seqs = [message.seq for _, _, message in SessionReader(path)]
    assert seqs == [0, 3, 4, 5]


def test_the_first_valid_payload_fixes_a_keys_class(tmp_path):
    js = m.JointState(1, T0, (0.1,), (0.0,), (0.0,)).encode()
    cf = m.ContactForce(2, T0, (0.0, 0.0, 0.0)).encode()
    path = tmp_path / "first.mcap"
    with SessionWriter(path) as writer:
        rejected = writer.write_payloads([CF] * 4, [b"x", cf, js, cf], [T0, T0 + 1, T0 + 2, T0 + 3])
        later = writer.write_payloads([CF], [js], [T0 + 4])
    assert [i for i, _ in rejected] == [0, 2]
    assert [i for i, _ in later] == [0]
    assert SessionReader(path).message_counts == {CF: 2}


def test_joint_count_changes_within_a_key_keep_their_order(tmp_path):
    payloads = [
        m.JointState(k, T0 + k, (0.1,) * (3 if k % 2 else 2), (0.0,) * (3 if k % 2 else 2),
                     (0.0,) * (3 if k % 2 else 2)).encode()
        for k in range(6)
    ]  # fmt: skip
    path = tmp_path / "n.mcap"
    with SessionWriter(path) as writer:
        assert writer.write_payloads([JS] * 6, payloads, [T0 + k for k in range(6)]) == []
    assert [x.seq for _, _, x in SessionReader(path)] == list(range(6))


def test_bad_log_times_are_rejected(tmp_path):
    js = [m.JointState(k, T0, (0.1,), (0.0,), (0.0,)).encode() for k in range(3)]
    with SessionWriter(tmp_path / "t.mcap") as writer:
        rejected = writer.write_payloads([JS] * 3, js, [T0, -5, 2**64])
        assert [i for i, _ in rejected] == [1, 2]
        assert all("log time" in str(exc) for _, exc in rejected)
        with pytest.raises(DataError, match="differ in length"):
            writer.write_payloads([JS], [], [T0])
    with pytest.raises(DataError, match="closed"):
        writer.write_payloads([JS], js[:1], [T0])


def test_json_writers_take_payloads_too(tmp_path):
    items = mixed(20)
    assert write_batches(tmp_path / "j.mcap", items, 9, message_encoding="json") == []
    reader = SessionReader(tmp_path / "j.mcap")
    assert reader.metadata["message_encoding"] == "json"
    assert len(reader) == len(items)


def test_a_negative_source_stamp_publishes_at_the_log_time(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "p.mcap"
    payload = m.JointState(1, -1, (0.1,), (0.0,), (0.0,)).encode()
    with SessionWriter(path) as writer:
        writer.write_payloads([JS, JS], [payload, payload], [T0, T0 + 1])
    with open(path, "rb") as f:
        stamps = [(x.publish_time, x.sequence) for _, _, x in make_reader(f).iter_messages()]
    assert stamps == [(T0, 1), (T0 + 1, 1)]


def test_durable_counts_and_idle_flushes(tmp_path):
    payload = m.JointState(1, T0, (0.1,), (0.0,), (0.0,)).encode()
    with SessionWriter(tmp_path / "d.mcap", flush_interval_s=0.05) as writer:
        writer.write_payloads([JS] * 10, [payload] * 10, [T0] * 10)
        assert writer.messages_written == 10 and writer.messages_durable == 0
        writer.flush_if_due()  # too early
        assert writer.messages_durable == 0
        time.sleep(0.06)
        writer.flush_if_due()
        assert writer.messages_durable == 10
