"""SessionMonitor: loss, pairing, state and malformed samples from CDR payloads and attachments."""

from __future__ import annotations

import math

import pytest

from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.accuracy import AccuracyConfig
from teleop_force.service.session_monitor import MONITORED, SessionMonitor
from teleop_force.transport import messages as m

_GID = bytes(range(16))


def attachment(seq: int) -> Attachment:
    return Attachment(seq, 1, _GID)


def send_estimate(monitor, seq: int, source_seq: int, force=(0.1, -1.2, 0.3), n: int = 3):
    """Both halves of one estimate, in the order the monitor drains them (wrench first)."""
    estimate = m.ForceEstimateMessage(
        seq, 5 + seq, source_seq, force, [0.0] * n, [True] * n, [1.0] * n, [0.0] * n, [0.0] * n
    )
    wrench, diagnostics = codec.encode_estimate(estimate, (), topics.BASE_FRAME)
    monitor.take(monitor._joiner.on_wrench, wrench, attachment(seq))
    monitor.take(monitor._joiner.on_diagnostics, diagnostics, attachment(seq))


def send_true_force(monitor, seq: int, force) -> None:
    payload = codec.encode_wrench(7, force, topics.BASE_FRAME)
    monitor.take(monitor._on_true_force, payload, attachment(seq))


def test_monitor_counts_pairs_and_drops_what_it_reads_of_each_message():
    monitor = SessionMonitor("s", AccuracyConfig(contact_threshold_n=0.5))
    for k in range(10):
        if k != 4:  # estimate 4 lost
            send_estimate(monitor, k + 1, source_seq=100 + k)
        send_true_force(monitor, 100 + k, (0.1, -1.0, 0.3))
    send_estimate(monitor, 11, 110, n=5)  # any joint count is read
    send_estimate(monitor, 12, 111, force=(math.nan,) * 3)  # no force: fine
    assert monitor.estimates.received == 11 and monitor.estimates.lost == 1
    assert monitor.true_forces.received == 10 and monitor.true_forces.lost == 0
    summary = monitor.accuracy.summary()
    assert summary["paired_samples"] == 9 and summary["contact_samples"] == 9
    assert summary["rms_error_n"] == pytest.approx(0.2)
    assert summary["no_force_estimates"] == 1
    wrench = codec.encode_wrench(9, (0.0, 0.0, 0.0), topics.BASE_FRAME)
    bad = [
        (monitor._joiner.on_wrench, wrench[:10]),  # cut short
        (monitor._joiner.on_wrench, b"XF" + wrench[2:]),  # no CDR encapsulation
        (monitor._joiner.on_diagnostics, wrench[:12]),  # cut short
        (monitor._joiner.on_wrench, b""),
        (monitor._on_true_force, codec.encode_wrench(9, (math.nan,) * 3, topics.BASE_FRAME)),
        (monitor._on_true_force, wrench[:-1]),
        (monitor._on_status, b"nonsense"),
    ]
    for handle, payload in bad:
        monitor.take(handle, payload, attachment(99))
    assert monitor.malformed == len(bad)
    assert monitor.estimates.received == 11  # nothing malformed was counted as received


def test_monitor_tracks_the_slave_state_and_its_holds():
    monitor = SessionMonitor("s", AccuracyConfig())
    for k, state in enumerate(
        [m.SafetyState.FOLLOWING, m.SafetyState.HOLDING, m.SafetyState.HOLDING,
         m.SafetyState.FOLLOWING, m.SafetyState.HOLDING]
    ):  # fmt: skip
        payload = codec.encode_status(m.Status(k, 0, state, f"reason {k}"))
        monitor.take(monitor._on_status, payload, attachment(k + 1))
    assert monitor.holds_seen == 2 and monitor.state == "holding" and monitor.reason == "reason 4"


def _raw(seq: int) -> bytes:
    return Attachment(seq, 1_000 + seq, _GID).encode()


def _feed(monitor: SessionMonitor, seqs: list[int], estimate_y: float = -1.1) -> None:
    for k in seqs:
        force = m.ContactForce(k, 1_000 + k, (0.0, -1.0, 0.0))
        monitor.take_raw("/s/true_cf", codec.encode_contact_force(force, "base"), _raw(k))
        estimate = m.ForceEstimateMessage(
            k, 1_000 + k, k, (0.0, estimate_y, 0.0), [0.0] * 3, [True] * 3, [1.0] * 3,
            [0.0] * 3, [0.0] * 3,
        )  # fmt: skip
        wrench, diagnostics = codec.encode_estimate(estimate, (), topics.BASE_FRAME)
        monitor.take_raw("/s/estimated_cf", wrench, _raw(k))
        monitor.take_raw("/s/estimate_diagnostics", diagnostics, _raw(k))


def test_pairs_estimates_with_true_forces_and_counts_the_gaps() -> None:
    monitor = SessionMonitor("s", AccuracyConfig())
    _feed(monitor, [k for k in range(1, 201) if k not in (50, 51, 52)])
    figures = monitor.figures()
    assert figures["estimates"] == {"received": 197, "lost": 3}
    assert figures["true_forces"] == {"received": 197, "lost": 3}
    assert figures["first_estimate_ns"] == 1_001 and figures["first_source_seq"] == 1
    assert figures["force_error"]["paired_samples"] == 197
    assert figures["force_error"]["relative_rms_error"] == pytest.approx(0.1, rel=1e-9)
    assert figures["latest_estimate_n"] == (0.0, -1.1, 0.0)
    assert figures["malformed"] == 0


def test_malformed_payloads_and_attachments_are_counted_and_dropped() -> None:
    monitor = SessionMonitor("s")
    monitor.take_raw("/s/true_cf", b"not cdr", _raw(1))
    monitor.take_raw("/s/true_cf", codec.encode_contact_force(
        m.ContactForce(1, 1, (0.0, 0.0, 0.0)), "base"), b"short")  # fmt: skip
    monitor.take_raw("/other/true_cf", b"ignored", _raw(1))  # another device: not taken
    monitor.take_raw("/s/measured_js", b"ignored", _raw(1))  # not a monitored topic
    assert monitor.malformed == 2
    assert monitor.true_forces.received == 0


def test_handlers_exist_for_exactly_the_monitored_topics() -> None:
    monitor = SessionMonitor("s")
    for topic in MONITORED:
        assert monitor.handler(topics.topic_name("s", topic)) is not None
    assert monitor.handler(topics.topic_name("s", topics.MEASURED_JS)) is None
