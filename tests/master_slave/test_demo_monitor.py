"""The demo supervisor's loop summary and how it starts its children."""

from __future__ import annotations

import os
import sys

import pytest

from teleop_force.cli import demo
from teleop_force.errors import ConfigurationError


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
