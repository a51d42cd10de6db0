"""The master's and slave's loops publish valid messages (fast packers) and follow as before."""

from __future__ import annotations

import time

import numpy as np
import pytest

from master_slave.master import MasterConfig, MasterProcess
from master_slave.process_args import RunConfig
from master_slave.realtime import LoopConfig
from master_slave.safety import SafetyConfig, SafetyMonitor
from master_slave.slave import SetpointInbox, SlaveConfig, SlaveProcess, slew_toward
from teleop_force.process.lifetime import StopSignal
from teleop_force.transport import messages as m
from teleop_force.transport.session import ZenohOptions

TICKS = 60
LOOP = LoopConfig(rate_hz=1000.0, timer_slack_ns=0)
RUN = RunConfig(duration_s=TICKS / 1000.0)


class Publisher:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []

    def put(self, payload: bytes) -> None:
        self.payloads.append(bytes(payload))


class FakeSample:
    def __init__(self, payload: bytes) -> None:
        self.payload = self

        def to_bytes() -> bytes:
            return payload

        self.to_bytes = to_bytes


def test_slew_toward_moves_each_joint_by_at_most_the_step():
    assert slew_toward([0.0, 1.0, -1.0], [0.5, 1.0005, -1.2], 0.001) == pytest.approx(
        [0.001, 1.0005, -1.001]
    )
    with pytest.raises(ValueError):
        slew_toward([0.0, 0.0], [0.0, 0.0, 0.0], 0.1)


def test_setpoint_inbox_keeps_the_latest_and_counts_the_rest():
    inbox = SetpointInbox()
    assert inbox.latest() == (None, None, 0)
    now_ns = time.time_ns()
    inbox.on_sample(FakeSample(m.JointSetpoint(1, now_ns, [0.1, 0.2, 0.3]).encode()))
    inbox.on_sample(FakeSample(m.JointSetpoint(3, now_ns, [0.4, 0.5, 0.6]).encode()))
    inbox.on_sample(FakeSample(b"TF\x01\x02garbage"))
    inbox.on_sample(FakeSample(m.JointSetpoint(4, now_ns, [0.1, 0.2]).encode()))  # 2 joints
    q, arrival_s, count = inbox.latest()
    assert q == (0.4, 0.5, 0.6) and count == 2 and arrival_s is not None
    stats = inbox.stats()
    assert stats["valid"] == 2 and stats["lost"] == 1 and stats["malformed"] == 2
    assert "2 joints" in stats["last_malformed"]
    assert stats["latency_ms"]["count"] == 2


def test_safety_unchanged_decisions_follow_the_state():
    monitor = SafetyMonitor(SafetyConfig(stale_s=0.05, resume_count=1))
    assert monitor.update(0.0, True, 0.0, 1).changed
    same = monitor.update(0.001, True, 0.001, 2)
    assert same.state == m.SafetyState.FOLLOWING and not same.changed
    assert monitor.update(0.2, True, 0.001, 2).state == m.SafetyState.HOLDING
    held = monitor.update(0.201, False, 0.001, 2)
    assert held.state == m.SafetyState.HOLDING and not held.changed
    assert held.reason.startswith("master setpoint stale")


def test_slave_loop_publishes_joint_states_and_true_forces_of_the_same_ticks():
    config = SlaveConfig(loop=LOOP, run=RUN, safety=SafetyConfig(stale_s=1.0))
    slave = SlaveProcess(config, ZenohOptions(), StopSignal())
    slave.presence.alive = True
    q0 = slave.plant.measured_q_rad()
    target = q0 + np.array([0.01, -0.01, 0.005])
    for k in range(12):  # enough fresh setpoints to follow
        slave.inbox.on_sample(FakeSample(m.JointSetpoint(k, time.time_ns(), target).encode()))
    js, cf = Publisher(), Publisher()
    try:
        slave._control_loop(js, cf)
    finally:
        slave.plant.close()
    states = [m.JointState.decode(p) for p in js.payloads]
    forces = [m.ContactForce.decode(p) for p in cf.payloads]
    assert len(states) == len(forces) == TICKS
    assert [s.seq for s in states] == [f.seq for f in forces] == list(range(TICKS))
    assert [s.t_ns for s in states] == [f.t_ns for f in forces]
    assert np.all(np.diff([s.t_ns for s in states]) == 1_000_000)  # nominal stamps
    assert slave.safety.state == m.SafetyState.FOLLOWING
    # the reference moved toward the setpoint by the slew limit: 2 rad/s x 1 ms per tick
    moved = np.array(states[-1].q_rad) - q0
    assert np.all(np.sign(moved[:2]) == np.sign(target - q0)[:2])
    assert np.all(np.abs(moved) <= 2.0 * 1e-3 * TICKS + 1e-3)


def test_master_loop_publishes_setpoints_and_joint_states_it_read():
    master = MasterProcess(MasterConfig(loop=LOOP, run=RUN), ZenohOptions(), StopSignal())
    setpoints, states = Publisher(), Publisher()
    try:
        master._control_loop(setpoints, states)
    finally:
        master.plant.close()
    sp = [m.JointSetpoint.decode(p) for p in setpoints.payloads]
    js = [m.JointState.decode(p) for p in states.payloads]
    assert len(sp) == len(js) == TICKS == master.published
    assert [s.seq for s in sp] == [s.seq for s in js] == list(range(TICKS))
    assert all(a.q_rad == b.q_rad and a.t_ns == b.t_ns for a, b in zip(sp, js, strict=True))
    assert all(s.effort_nm == (0.0, 0.0, 0.0) for s in js)  # no haptic feedback
    assert master.loop.stats()["ticks"] == TICKS + 1  # the last wait ends the loop
