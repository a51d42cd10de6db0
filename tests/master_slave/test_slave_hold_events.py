"""The slave keeps its hold events bounded: the count of all, the last 20 in its statistics."""

from __future__ import annotations

import json
import time

from master_slave.slave import HOLD_EVENTS_KEPT, SlaveConfig, SlaveProcess
from teleop_force.process.lifetime import StopSignal
from teleop_force.transport.session import ZenohOptions


def test_hold_events_keep_the_count_and_the_last_20():
    slave = SlaveProcess(SlaveConfig(), ZenohOptions(), StopSignal())  # opens nothing
    try:
        assert slave.stats()["hold_events"] == [] and slave.stats()["hold_events_total"] == 0
        now = time.perf_counter()
        for k in range(5000):  # e.g. a master flapping for hours
            slave._record_hold(now, now - 0.051, f"master setpoint stale: hold {k}")
        stats = json.loads(json.dumps(slave.stats()))  # what the stats queryable replies
        assert stats["hold_events_total"] == 5000
        events = stats["hold_events"]
        assert len(events) == HOLD_EVENTS_KEPT == 20
        assert [e["reason"] for e in events] == [
            f"master setpoint stale: hold {k}" for k in range(5000 - 20, 5000)
        ]
        assert events[-1]["setpoint_age_ms"] == 51.0
        assert len(slave.hold_events) == 20  # the process keeps no more than it reports
    finally:
        slave.plant.close()
