"""The demo supervisor's cheap monitor, its loop summary and how it starts its children."""

from __future__ import annotations

import math
import os
import sys

import pytest

from teleop_force.cli import demo
from teleop_force.errors import ConfigurationError
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.accuracy import AccuracyConfig
from teleop_force.transport import messages as m

GID = bytes(range(16))


def attachment(seq: int) -> Attachment:
    return Attachment(seq, 1, GID)


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
    monitor = demo._Monitor(AccuracyConfig(contact_threshold_n=0.5))
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
    monitor = demo._Monitor(AccuracyConfig())
    for k, state in enumerate(
        [m.SafetyState.FOLLOWING, m.SafetyState.HOLDING, m.SafetyState.HOLDING,
         m.SafetyState.FOLLOWING, m.SafetyState.HOLDING]
    ):  # fmt: skip
        payload = codec.encode_status(m.Status(k, 0, state, f"reason {k}"))
        monitor.take(monitor._on_status, payload, attachment(k + 1))
    assert monitor.holds_seen == 2 and monitor.state == "holding" and monitor.reason == "reason 4"


def test_loop_summary_and_its_line():
    stats = {
        "loop": {
            "ticks": 29_990, "expected_ticks": 30_001.2, "ticks_fraction": 0.999627,
            "overruns": 12, "overrun_fraction": 0.0004, "missed_ticks": 5, "resyncs": 1,
            "rate_hz": 999.6, "gc_full_collections": 3, "lateness_ms": {"p99": 0.1},
            "timer_slack_ns": 1000,
        }
    }  # fmt: skip
    loop = demo._loop_summary(stats)
    assert loop["ticks"] == 29_990 and loop["missed_ticks"] == 5
    assert loop["lateness_ms"] == {"p99": 0.1} and "timer_slack_ns" not in loop
    line = demo._fmt_loop(loop)
    assert line == "29990 ticks of 30001 expected (99.96%), overruns 12 (0.04%), missed 5"
    assert demo._fmt_loop(demo._loop_summary(None)) == "n/a"
    assert demo._loop_summary(None)["ticks"] is None


def test_config_checks_the_scheduling_ranges():
    assert demo.DemoConfig().rt_priority == demo.DEFAULT_RT_PRIORITY > 0
    with pytest.raises(ConfigurationError):
        demo.DemoConfig(rt_priority=100)
    with pytest.raises(ConfigurationError):
        demo.DemoConfig(realtime_nice=-21)


def test_child_gets_its_nice_value_and_reports_its_scheduling(tmp_path):
    argv = [sys.executable, "-c", "import time; time.sleep(30)"]
    with open(tmp_path / "child.log", "wb") as log:
        child = demo.Child("sleeper", argv, log, nice=5)
        try:
            assert child.scheduling() == {"policy": "other", "priority": 0, "nice": 5}
        finally:
            child.stop()
        if sys.platform.startswith("linux") and os.geteuid() == 0:  # privileged: real time
            child = demo.Child("sleeper", argv, log, nice=-3, rt_priority=7)
            try:
                assert child.scheduling() == {"policy": "fifo", "priority": 7, "nice": -3}
            finally:
                child.stop()
    assert child.scheduling() is None  # gone
