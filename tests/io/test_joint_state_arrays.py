"""read_joint_state_arrays: one topic's joint states as arrays, equal to SessionReader's objects."""

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import IndexType, Writer

from teleop_force.errors import DataError
from teleop_force.io.cdr_columns import JointStateArrays, read_joint_state_arrays
from teleop_force.io.mcap_session import SessionReader, SessionWriter, read_session_as_recording
from teleop_force.transport import keys
from teleop_force.transport import messages as m

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000_000_000_000
JS = keys.measured_js("slave")


def joint_state(i, n=3):
    q = tuple(0.1 * j + 1e-4 * i for j in range(n))
    return m.JointState(i, T0 + i * 1_000_000, q, (0.5 - 1e-3 * i,) * n, (0.01 * i,) * n)


def from_reader(path, topic):
    """The same arrays, built from SessionReader's objects."""
    rows = [(ns, x) for _, ns, x in SessionReader(path).messages([topic])]
    if not rows:
        return None
    return JointStateArrays(
        seq=np.array([x.seq for _, x in rows], dtype=np.uint32),
        t_ns=np.array([x.t_ns for _, x in rows], dtype=np.int64),
        log_time_ns=np.array([ns for ns, _ in rows], dtype=np.int64),
        q_rad=np.array([x.q_rad for _, x in rows], dtype=np.float64),
        qd_rad_s=np.array([x.qd_rad_s for _, x in rows], dtype=np.float64),
        effort_nm=np.array([x.effort_nm for _, x in rows], dtype=np.float64),
    )


def assert_equal_arrays(a, b):
    for name in ("seq", "t_ns", "log_time_ns", "q_rad", "qd_rad_s", "effort_nm"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def write_session(path, n_steps=500, log_order=None, **kwargs):
    """Joint states of two devices, forces and statuses; log times optionally permuted."""
    with SessionWriter(path, {"primary_device": "slave"}, **kwargs) as writer:
        for k in range(n_steps):
            log_ns = T0 + int(log_order[k] if log_order is not None else k) * 1000
            writer.write(JS, joint_state(k), log_ns)
            writer.write(keys.measured_js("master"), joint_state(k, n=2), log_ns + 1)
            writer.write(keys.measured_cf("slave"), m.ContactForce(k, T0, (0.0, 1.0, 2.0)), log_ns)
            if k % 50 == 0:
                writer.write(keys.status("slave"), m.Status(k, T0, m.SafetyState.HOLDING), log_ns)


@pytest.mark.parametrize("encoding", ["cdr", "json"])
@pytest.mark.parametrize("chunk_size_bytes", [1024, 1 << 20])
def test_equal_to_the_session_reader(tmp_path, encoding, chunk_size_bytes):
    path = tmp_path / "s.mcap"
    write_session(path, chunk_size_bytes=chunk_size_bytes, message_encoding=encoding)
    arrays = read_joint_state_arrays(path, JS)
    assert arrays.n_samples == 500 and arrays.n_joints == 3
    assert_equal_arrays(arrays, from_reader(path, JS))
    master = read_joint_state_arrays(path, keys.measured_js("master"))
    assert master.n_joints == 2
    assert_equal_arrays(master, from_reader(path, keys.measured_js("master")))


def test_out_of_order_log_times_are_sorted_like_the_reader(tmp_path):
    path = tmp_path / "s.mcap"
    order = np.random.default_rng(3).permutation(500) // 2  # pairs of equal log times
    write_session(path, log_order=order, chunk_size_bytes=2048)
    arrays = read_joint_state_arrays(path, JS)
    assert np.all(np.diff(arrays.log_time_ns) >= 0)
    assert_equal_arrays(arrays, from_reader(path, JS))


def test_batches_of_payloads(tmp_path):
    path = tmp_path / "b.mcap"
    payloads = [joint_state(k).encode() for k in range(3000)]
    with SessionWriter(path, chunk_size_bytes=4096) as writer:
        for start in range(0, 3000, 700):
            part = payloads[start : start + 700]
            logs = [T0 + (start + i) * 1000 for i in range(len(part))]
            writer.write_payloads([JS] * len(part), part, logs)
    arrays = read_joint_state_arrays(path, JS)
    assert arrays.seq.tolist() == list(range(3000))
    assert_equal_arrays(arrays, from_reader(path, JS))


@pytest.mark.parametrize("encoding", ["cdr", "json"])
def test_truncated_files_read_like_the_reader(tmp_path, encoding):
    path = tmp_path / "full.mcap"
    write_session(path, n_steps=300, chunk_size_bytes=2048, message_encoding=encoding)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    seen = 0
    for size in range(8, len(data), max(1, len(data) // 61)):
        cut.write_bytes(data[:size])
        expected = from_reader(cut, JS)
        if expected is None:
            with pytest.raises(DataError, match="no joint states"):
                read_joint_state_arrays(cut, JS)
            continue
        got = read_joint_state_arrays(cut, JS)
        assert_equal_arrays(got, expected)
        assert got.n_samples >= seen
        seen = got.n_samples
    assert seen > 250


def legacy_session(path, *, chunked=True, indexed=True):
    """A session as recorded before the CDR encoding, with the mcap library's own writer."""
    with open(path, "wb") as f:
        writer = Writer(
            f,
            chunk_size=2048,
            use_chunking=chunked,
            index_types=IndexType.ALL if indexed else IndexType.NONE,
        )
        writer.start()
        writer.add_metadata("teleop_force.session", {"format": "teleop-force-session"})
        schemas = {
            cls: writer.register_schema(
                cls.SCHEMA_NAME, "jsonschema", json.dumps(cls.json_schema()).encode()
            )
            for cls in (m.JointState, m.ContactForce)
        }
        js = writer.register_channel(JS, "json", schemas[m.JointState])
        cf = writer.register_channel(keys.measured_cf("slave"), "json", schemas[m.ContactForce])
        for k in range(400):
            message = joint_state(k)
            data = json.dumps(message.to_json_dict()).encode()
            writer.add_message(js, T0 + k, data, message.t_ns, message.seq)
            force = m.ContactForce(k, T0, (0.0, 0.1, 0.2))
            writer.add_message(cf, T0 + k, json.dumps(force.to_json_dict()).encode(), T0, k)
        writer.finish()


@pytest.mark.parametrize(
    ("chunked", "indexed"), [(True, True), (True, False), (False, True)]
)  # fmt: skip
def test_legacy_json_sessions(tmp_path, chunked, indexed):
    path = tmp_path / "legacy.mcap"
    legacy_session(path, chunked=chunked, indexed=indexed)
    arrays = read_joint_state_arrays(path, JS)
    assert arrays.seq.tolist() == list(range(400))
    assert_equal_arrays(arrays, from_reader(path, JS))


def test_the_shipped_palpation_recording():
    path = REPO / "recordings" / "palpation_demo.mcap"
    if not path.exists():
        pytest.skip("recordings/palpation_demo.mcap is not in this checkout")
    for topic in (JS, keys.measured_js("master")):
        arrays = read_joint_state_arrays(path, topic)
        assert arrays.n_samples > 1000
        assert_equal_arrays(arrays, from_reader(path, topic))


def test_errors_name_the_file(tmp_path):
    path = tmp_path / "s.mcap"
    write_session(path, n_steps=20)
    with pytest.raises(DataError, match="does not hold JointState") as info:
        read_joint_state_arrays(path, keys.measured_cf("slave"))
    assert str(path) in str(info.value)
    with pytest.raises(DataError, match="no joint states on omni/nobody/measured_js"):
        read_joint_state_arrays(path, keys.measured_js("nobody"))
    with pytest.raises(DataError, match="cannot read"):
        read_joint_state_arrays(tmp_path / "missing.mcap", JS)
    (tmp_path / "text.mcap").write_text("t,q\n")
    with pytest.raises(DataError, match="not an MCAP file"):
        read_joint_state_arrays(tmp_path / "text.mcap", JS)


def test_a_changing_joint_count_is_reported_like_read_session_as_recording(tmp_path):
    path = tmp_path / "n.mcap"
    with SessionWriter(path) as writer:
        writer.write(JS, joint_state(0, n=3), T0)
        writer.write(JS, joint_state(1, n=2), T0 + 1)
    with pytest.raises(DataError, match="joint count changes from 3 to 2 at seq 1"):
        read_joint_state_arrays(path, JS)
    with pytest.raises(DataError, match="joint count changes from 3 to 2 at seq 1"):
        read_session_as_recording(path)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_corrupt_chunks_raise_data_error(tmp_path, compression):
    path = tmp_path / "c.mcap"
    write_session(path, n_steps=200, compression=compression)
    data = bytearray(path.read_bytes())
    middle = len(data) // 3
    for i in range(middle, middle + 64):
        data[i] ^= 0x5A
    path.write_bytes(bytes(data))
    with pytest.raises(DataError) as info:
        read_joint_state_arrays(path, JS)
    assert str(path) in str(info.value)


def test_arrays_are_checked():
    with pytest.raises(DataError, match="seq"):
        JointStateArrays(
            seq=np.zeros(2, np.int64),
            t_ns=np.zeros(2, np.int64),
            log_time_ns=np.zeros(2, np.int64),
            q_rad=np.zeros((2, 3)),
            qd_rad_s=np.zeros((2, 3)),
            effort_nm=np.zeros((2, 3)),
        )
    with pytest.raises(DataError, match="effort_nm"):
        JointStateArrays(
            seq=np.zeros(2, np.uint32),
            t_ns=np.zeros(2, np.int64),
            log_time_ns=np.zeros(2, np.int64),
            q_rad=np.zeros((2, 3)),
            qd_rad_s=np.zeros((2, 3)),
            effort_nm=np.zeros((2, 2)),
        )
