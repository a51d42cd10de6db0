"""Copying recorded messages between sessions chunk by chunk (``SessionWriter.copy_from``).

The bulk copy must write exactly what the message-by-message copy writes (the re-estimation's
reference path): the same messages per topic, in the same order, with the same log times,
publish times and sequence numbers, for CDR sessions and (by falling back) JSON ones.
"""

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from teleop_force.errors import DataError
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.io.mcap_session import SessionReader, SessionWriter, export_session_json
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service import reestimation
from teleop_force.transport import keys
from teleop_force.transport import messages as m

EPOCH_NS = 1_700_000_000_000_000_000
JS, MJS, SP, CF, ST, EST = (
    keys.measured_js("slave"), keys.measured_js("master"), keys.setpoint_js("master"),
    keys.measured_cf("slave"), keys.status("slave"), keys.estimated_cf("slave"),
)  # fmt: skip
TOPICS = sorted((JS, MJS, SP, CF, ST))


def _write_source(path: Path, n: int = 1500, *, shuffled_cf: bool = False) -> None:
    """A CDR session of small chunks, with negative stamps, statuses of varying size."""
    meta = {"primary_device": "slave", "master_device": "master", "source": "live"}
    rng = np.random.default_rng(3)
    with SessionWriter(path, meta, chunk_size_bytes=4096) as writer:
        for k in range(n):
            log = EPOCH_NS + k * 1_000_000
            stamp = -1 if k % 97 == 0 else EPOCH_NS + k * 999_000
            q = tuple(rng.normal(size=3).tolist())
            effort = (2e6, 0.0, 0.0) if k % 211 == 5 else tuple(rng.normal(size=3).tolist())
            writer.write(MJS, m.JointState(k, stamp, q, q, (0.0,) * 3), log)
            writer.write(SP, m.JointSetpoint(k, stamp, q), log)
            writer.write(JS, m.JointState(k % 1000, stamp, q, q, effort), log + 1)
            cf_log = log + 2 - (1_500_000 if shuffled_cf and k % 10 == 3 else 0)
            writer.write(CF, m.ContactForce(k, stamp, (1.0, 2.0, float(k))), cf_log)
            if k % 30 == 0:
                reason = "x" * (k % 7)
                state = m.SafetyState.FOLLOWING
                writer.write(ST, m.Status(k // 30, stamp, state, reason), log + 3)
            if k % 100 == 0:
                old = m.ForceEstimateMessage(
                    k, stamp, k, (0.0, 0.0, 0.0), (0.0,) * 3, (True,) * 3, (1.0,) * 3,
                    (0.0,) * 3, (0.0,) * 3,
                )  # fmt: skip
                writer.write(EST, old, log + 4)


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
    assert _records(new)[CF] == _records(cdr_source)[CF]


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
    for topic, _, _ in reader:
        iterated[topic] += 1
    assert reader.message_counts == dict(iterated)
    assert reader.message_counts[JS] == 300
    assert not reader.truncated


@pytest.mark.parametrize("n", [3, 9])
def test_estimate_payloads_are_the_packed_messages(n) -> None:
    from teleop_force.estimation.batch import BatchEstimates

    rng = np.random.default_rng(n)
    k = 40
    force = rng.normal(size=(k, 3))
    force[5] = np.nan  # singular: no force
    est = BatchEstimates(
        np.arange(k, dtype=float), force, rng.normal(size=(k, n)), rng.normal(size=(k, n)),
        rng.normal(size=(k, n)), rng.uniform(size=(k, n)), rng.uniform(size=(k, n)) > 0.5,
        np.zeros(k, dtype=bool),
    )  # fmt: skip
    rows = np.array([0, 3, 5, 7, 39])
    sources = np.array([7, 2**32 - 1, 0, 12, 13], dtype=np.uint32)
    stamps = np.array([EPOCH_NS + i for i in range(rows.size)], dtype=np.int64)
    got = reestimation._estimate_payloads(est, rows, sources, stamps)
    want = []
    for count, r in enumerate(rows.tolist()):
        values = np.concatenate(
            (est.force_tip_in_base_n[r], est.tau_external_nm[r], est.coverage_weight[r],
             est.tau_motor_filtered_nm[r], est.tau_model_filtered_nm[r])
        ).tolist()  # fmt: skip
        mask = sum(1 << j for j in range(n) if est.on_trained_ground[r, j])
        want.append(
            m.pack_force_estimate(count, int(stamps[count]), int(sources[count]), n, values, mask)
        )
    assert got == want
    assert m.decode(got[2]).source_seq == 0
