"""Copying recorded messages between sessions chunk by chunk (``SessionWriter.copy_from``).

The bulk copy must write exactly what the message-by-message copy writes (the re-estimation's
reference path): the same messages per topic, in the same order, with the same log times,
publish times and sequence numbers, for ROS 2 sessions and (by falling back) JSON ones.
"""

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from teleop_force.errors import DataError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.mcap_session import SessionReader, SessionWriter, export_session_json
from teleop_force.io.ros2_columns import EstimateRows, estimate_blocks
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.service import reestimation
from teleop_force.transport import messages as m

EPOCH_NS = 1_700_000_000_000_000_000
JS, MJS, SP, CF, ST, EST = (
    "/slave/measured_js", "/master/measured_js", "/master/setpoint_js", "/slave/true_cf",
    "/slave/status", "/slave/estimated_cf",
)  # fmt: skip
TOPICS = sorted((JS, MJS, SP, CF, ST))
NAMES = topics.OMNI_MODEL_JOINT_NAMES


def _write_source(path: Path, n: int = 1500, *, shuffled_cf: bool = False) -> None:
    """A ROS 2 session of small chunks, with statuses of varying size, sequence wrapping."""
    meta = {"primary_device": "slave", "master_device": "master", "source": "live"}
    rng = np.random.default_rng(3)
    with SessionWriter(path, meta, chunk_size_bytes=4096, profile="ros2") as writer:

        def put(topic, ros_type, payload, seq, stamp, log):
            writer.write_ros2(topic, ros_type, payload, seq, stamp, log)

        for k in range(n):
            log = EPOCH_NS + k * 1_000_000
            stamp = EPOCH_NS + k * 999_000
            publish = -1 if k % 97 == 0 else stamp + 7  # no source time: the log time
            q = tuple(rng.normal(size=3).tolist())
            effort = (2e6, 0.0, 0.0) if k % 211 == 5 else tuple(rng.normal(size=3).tolist())
            master = codec.encode_joint_state(m.JointState(0, stamp, q, q, (0.0,) * 3), NAMES)
            put(MJS, interfaces.JOINT_STATE, master, k + 1, publish, log)
            setpoint = codec.encode_joint_setpoint(m.JointSetpoint(0, stamp, q), NAMES)
            put(SP, interfaces.JOINT_STATE, setpoint, k + 1, publish, log)
            js = codec.encode_joint_state(m.JointState(0, stamp, q, q, effort), NAMES)
            put(JS, interfaces.JOINT_STATE, js, 2**32 - 700 + k, publish, log + 1)
            cf_log = log + 2 - (1_500_000 if shuffled_cf and k % 10 == 3 else 0)
            force = m.ContactForce(0, stamp, (1.0, 2.0, float(k)))
            put(CF, interfaces.WRENCH_STAMPED, codec.encode_contact_force(force, "base"), k + 1,
                publish, cf_log)  # fmt: skip
            if k % 30 == 0:
                status = m.Status(0, stamp, m.SafetyState.FOLLOWING, "x" * (k % 7))
                put(ST, interfaces.STATUS, codec.encode_status(status), k // 30 + 1, publish,
                    log + 3)  # fmt: skip
            if k % 100 == 0:
                old = m.ForceEstimateMessage(
                    0, stamp, k, (0.0, 0.0, 0.0), (0.0,) * 3, (True,) * 3, (1.0,) * 3,
                    (0.0,) * 3, (0.0,) * 3,
                )  # fmt: skip
                wrench, diagnostics = codec.encode_estimate(old, NAMES, "base")
                put(EST, interfaces.WRENCH_STAMPED, wrench, k + 1, publish, log + 4)
                put("/slave/estimate_diagnostics", interfaces.ESTIMATE_DIAGNOSTICS, diagnostics,
                    k + 1, publish, log + 4)  # fmt: skip


def _records(path: Path) -> dict[str, list[tuple[int, int, int, bytes]]]:
    """Every message record per topic, in log-time order (ties: file order)."""
    out: dict[str, list[tuple[int, int, int, int, bytes]]] = defaultdict(list)
    with open(path, "rb") as f:
        for n, (_, channel, message) in enumerate(
            make_reader(f).iter_messages(log_time_order=False)
        ):
            out[channel.topic].append(
                (message.log_time, n, message.publish_time, message.sequence, message.data)
            )
    return {
        topic: [(log, pub, seq, data) for log, _, pub, seq, data in sorted(rows)]
        for topic, rows in out.items()
    }


def _plausible(path: Path) -> np.ndarray:
    efforts = [js.effort_nm[0] for _, _, js in SessionReader(path).messages([JS])]
    return np.abs(np.asarray(efforts)) < 1e6


def _copy_both(source: Path, tmp_path: Path) -> tuple[Path, Path, tuple, tuple]:
    keep = _plausible(source)
    old, new = tmp_path / "old.mcap", tmp_path / "new.mcap"
    reader = SessionReader(source)
    with SessionWriter(old) as writer:
        old_result = reestimation._copy_replayed(reader, writer, TOPICS, JS, keep)
    with SessionWriter(new) as writer:
        new_result = reestimation._copy(reader, writer, TOPICS, JS, keep)
    return old, new, old_result, new_result


def test_bulk_copy_writes_what_the_message_copy_writes(tmp_path) -> None:
    source = tmp_path / "s.mcap"
    _write_source(source)
    old, new, old_result, new_result = _copy_both(source, tmp_path)
    assert new_result == old_result
    read, _, _, written = new_result
    assert read[JS] == 1500 and written < sum(read.values())  # malformed ones dropped
    want, got = _records(old), _records(new)
    assert set(got) == set(TOPICS)
    assert got == want
    assert len(got[JS]) == int(_plausible(source).sum())
    assert EST not in got


def test_bulk_copy_keeps_the_order_of_messages_logged_out_of_order(tmp_path) -> None:
    source = tmp_path / "s.mcap"
    _write_source(source, n=400, shuffled_cf=True)
    old, new, old_result, new_result = _copy_both(source, tmp_path)
    assert new_result == old_result
    got = _records(new)
    assert got == _records(old)
    logs = [row[0] for row in got[CF]]
    assert logs == sorted(logs)


def test_json_sessions_are_copied_message_by_message(tmp_path) -> None:
    cdr_source = tmp_path / "cdr.mcap"
    _write_source(cdr_source, n=300)
    source = tmp_path / "json.mcap"
    export_session_json(cdr_source, source)
    old, new, old_result, new_result = _copy_both(source, tmp_path)
    assert new_result == old_result
    assert _records(new) == _records(old)
    # the same bytes and sequence numbers (the JSON layout keeps no source time)
    dropped_publish = [[(log, seq, data) for log, _, seq, data in _records(path)[CF]]
                       for path in (new, cdr_source)]  # fmt: skip
    assert dropped_publish[0] == dropped_publish[1]


def test_a_keep_mask_of_another_length_is_refused(tmp_path) -> None:
    source = tmp_path / "s.mcap"
    _write_source(source, n=50)
    with SessionWriter(tmp_path / "out.mcap") as writer, pytest.raises(DataError, match="keep"):
        writer.copy_from(source, TOPICS, keep={JS: np.ones(49, dtype=bool)})


def test_reestimation_output_equals_the_message_copy_output(tmp_path, monkeypatch) -> None:
    source = tmp_path / "s.mcap"
    _write_source(source, n=800)
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    new = reestimation.reestimate_session(source, tmp_path / "new.mcap", model)
    monkeypatch.setattr(reestimation, "_copy", reestimation._copy_replayed)
    old = reestimation.reestimate_session(source, tmp_path / "old.mcap", model)
    assert new.replayed == old.replayed and new.written == old.written
    assert new.recorded_span_s == old.recorded_span_s
    assert _records(new.target) == _records(old.target)
    assert SessionReader(new.target).message_counts == SessionReader(old.target).message_counts


def test_opening_a_reader_counts_messages_from_the_indexes(tmp_path) -> None:
    source = tmp_path / "s.mcap"
    _write_source(source, n=300)
    reader = SessionReader(source)
    iterated: dict[str, int] = defaultdict(int)
    for raw in reader.raw_messages():
        iterated[raw.topic] += 1
    assert reader.message_counts == dict(iterated)
    assert reader.message_counts[JS] == 300
    assert not reader.truncated


@pytest.mark.parametrize("n", [3, 9])
def test_estimate_blocks_are_the_codecs_messages(n) -> None:
    rng = np.random.default_rng(n)
    k = 40
    force = rng.normal(size=(k, 3))
    force[5] = np.nan  # singular: no force
    sources = (np.arange(k) * 7 + 2**32 - 50) % 2**32  # wrapping
    rows = EstimateRows(
        EPOCH_NS + np.arange(k, dtype=np.int64) * 999_999_937, sources,
        force, rng.normal(size=(k, n)), rng.uniform(size=(k, n)), rng.uniform(size=(k, n)) > 0.5,
        rng.normal(size=(k, n)), rng.normal(size=(k, n)),
    )  # fmt: skip
    names = topics.model_joint_names(n)
    zeros = (0.0,) * n
    template = m.ForceEstimateMessage(0, 0, 0, (0.0,) * 3, zeros, (False,) * n, zeros, zeros,
                                      zeros)  # fmt: skip
    wrenches, reports = estimate_blocks(*codec.encode_estimate(template, names, "base"), rows)
    for r in range(k):
        estimate = m.ForceEstimateMessage(
            0, int(rows.t_ns[r]), int(rows.source_sequence[r]), tuple(force[r]),
            tuple(rows.tau_ext_nm[r]), tuple(rows.on_trained_ground[r].tolist()),
            tuple(rows.coverage_weight[r]), tuple(rows.tau_motor_filtered_nm[r]),
            tuple(rows.tau_model_filtered_nm[r]),
        )  # fmt: skip
        wrench, diagnostics = codec.encode_estimate(estimate, names, "base")
        assert wrenches[r].tobytes() == wrench
        assert reports[r].tobytes() == diagnostics
