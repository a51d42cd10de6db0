"""export_session_json: any session rewritten in the JSON layout of the recordings before CDR."""

import itertools
import json
from pathlib import Path

import pytest
from mcap.reader import make_reader

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.io.cdr_columns import read_joint_state_arrays
from teleop_force.io.mcap_session import (
    SessionReader,
    SessionWriter,
    export_session_json,
    read_session_as_recording,
)
from teleop_force.transport import keys
from teleop_force.transport import messages as m

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000_000_000_000
JS = keys.measured_js("slave")


def write_cdr(path, steps=300):
    with SessionWriter(
        path, {"robot": "omni", "primary_device": "slave"}, chunk_size_bytes=2048
    ) as w:
        for k in range(steps):
            t = T0 + k * 1_000_000
            w.write(JS, m.JointState(k, t, (0.1 * k, 0.2, 0.3), (1.0,) * 3, (0.5,) * 3), t + 1)
            w.write(keys.measured_cf("slave"), m.ContactForce(k, t, (0.0, -0.01 * k, 0.0)), t + 2)
            estimate = m.ForceEstimateMessage(
                k, t, k, (float("nan"), 1.0, 2.0), (0.1,) * 3, (True, False, True),
                (1.0,) * 3, (0.0,) * 3, (0.0,) * 3,
            )  # fmt: skip
            w.write(keys.estimated_cf("slave"), estimate, t + 3)
            if k % 100 == 0:
                w.write(keys.status("slave"), m.Status(k, t, m.SafetyState.HOLDING, "why ✓"), t)


def as_json_items(path):
    return [(t, ns, x.to_json_dict()) for t, ns, x in SessionReader(path)]


def test_export_keeps_every_message_and_the_metadata(tmp_path):
    source, target = tmp_path / "cdr.mcap", tmp_path / "json.mcap"
    write_cdr(source)
    result = export_session_json(source, target)
    assert (result.messages, result.skipped) == (903, 0)
    assert (result.source, result.target) == (source, target)
    assert as_json_items(target) == as_json_items(source)
    reader = SessionReader(target)
    assert reader.metadata["format_version"] == "1"
    assert reader.metadata["message_encoding"] == "json"
    assert reader.metadata["robot"] == "omni"
    assert reader.metadata["exported_from"] == str(source)
    assert reader.topics[JS] == "teleop_force.JointState"
    with open(target, "rb") as f:
        summary = make_reader(f).get_summary()
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    assert {c.message_encoding for c in summary.channels.values()} == {"json"}
    # What is read from the JSON copy is what is read from the CDR original.
    assert read_session_as_recording(target).n_samples == 300
    a, b = read_joint_state_arrays(source, JS), read_joint_state_arrays(target, JS)
    assert (a.q_rad == b.q_rad).all() and (a.log_time_ns == b.log_time_ns).all()


def test_a_json_export_of_a_truncated_recording(tmp_path):
    source = tmp_path / "cdr.mcap"
    write_cdr(source)
    data = source.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    result = export_session_json(cut, tmp_path / "json.mcap")
    assert 0 < result.messages == len(SessionReader(cut))
    assert as_json_items(tmp_path / "json.mcap") == as_json_items(cut)


def test_foreign_channels_are_skipped(tmp_path):
    from mcap.writer import Writer

    source = tmp_path / "foreign.mcap"
    with open(source, "wb") as f:
        writer = Writer(f)
        writer.start()
        sid = writer.register_schema("other.Thing", "jsonschema", b'{"type":"object"}')
        cid = writer.register_channel("other/topic", "json", sid)
        writer.add_message(cid, log_time=5, data=b'{"a": 1}', publish_time=5)
        schema = writer.register_schema(
            m.Status.SCHEMA_NAME, "jsonschema", json.dumps(m.Status.json_schema()).encode()
        )
        status = writer.register_channel(keys.status("x"), "json", schema)
        body = m.Status(1, 6, m.SafetyState.STOPPED, "e-stop").to_json_dict()
        writer.add_message(status, log_time=6, data=json.dumps(body).encode(), publish_time=6)
        writer.finish()
    result = export_session_json(source, tmp_path / "out.mcap")
    assert (result.messages, result.skipped) == (1, 1)
    assert [t for t, _, _ in SessionReader(tmp_path / "out.mcap")] == [keys.status("x")]


def test_export_refuses_to_overwrite_its_source(tmp_path):
    source = tmp_path / "cdr.mcap"
    write_cdr(source, steps=5)
    with pytest.raises(ConfigurationError, match="source itself"):
        export_session_json(source, source)
    with pytest.raises(DataError, match="cannot read"):
        export_session_json(tmp_path / "missing.mcap", tmp_path / "x.mcap")


def by_topic(items):
    out = {}
    for topic, ns, body in items:
        out.setdefault(topic, []).append((ns, body))
    return out


def test_the_shipped_json_recording_round_trips_through_cdr(tmp_path):
    legacy = REPO / "recordings" / "palpation_demo.mcap"
    if not legacy.exists():
        pytest.skip("recordings/palpation_demo.mcap is not in this checkout")
    reader = SessionReader(legacy)
    original = []
    for topic in reader.topics:  # the first 500 messages of every key
        original += itertools.islice(reader.messages([topic]), 500)
    original.sort(key=lambda item: item[1])
    cdr_copy = tmp_path / "cdr.mcap"
    with SessionWriter(cdr_copy, reader.metadata) as writer:
        for topic, log_ns, message in original:
            writer.write(topic, message, log_ns)
    export_session_json(cdr_copy, tmp_path / "json.mcap")
    expected = by_topic((t, ns, x.to_json_dict()) for t, ns, x in original)
    assert len(expected) == 6
    assert by_topic(as_json_items(cdr_copy)) == expected
    assert by_topic(as_json_items(tmp_path / "json.mcap")) == expected
