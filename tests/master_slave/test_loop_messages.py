"""The master's and slave's loops publish valid ROS 2 messages and follow as before."""

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
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.transport import messages as m
from teleop_force.transport.session import ZenohOptions

TICKS = 60
LOOP = LoopConfig(rate_hz=1000.0, timer_slack_ns=0)
RUN = RunConfig(duration_s=TICKS / 1000.0)


GID = bytes(range(16))
NAMES = topics.OMNI_MODEL_JOINT_NAMES


class FakeOutputs:
    """What the loops publish, as the CDR payloads Ros2Outputs would put (no Zenoh)."""

    def __init__(self) -> None:
        self.joint_states: list[bytes] = []
        self.setpoints: list[bytes] = []
        self.true_forces: list[bytes] = []
        self.statuses: list[m.Status] = []

    def joint_state(self, t_ns, q, qd, effort) -> None:
        self.joint_states.append(codec.encode_joint_state_parts(t_ns, NAMES, "", q, qd, effort))

    def setpoint(self, t_ns, q) -> None:
        self.setpoints.append(codec.encode_joint_state_parts(t_ns, NAMES, "", q, (), ()))

    def true_force(self, t_ns, force_n) -> None:
        self.true_forces.append(codec.encode_wrench(t_ns, force_n, topics.BASE_FRAME))

    def status(self, msg: m.Status) -> None:
        self.statuses.append(msg)


def setpoint_payload(q) -> bytes:
    return codec.encode_joint_setpoint(m.JointSetpoint(0, time.time_ns(), tuple(q)), NAMES)


def attachment(seq: int) -> Attachment:
    return Attachment(seq, time.time_ns(), GID)


def test_slew_toward_moves_each_joint_by_at_most_the_step():
    assert slew_toward([0.0, 1.0, -1.0], [0.5, 1.0005, -1.2], 0.001) == pytest.approx(
        [0.001, 1.0005, -1.001]
    )
    with pytest.raises(ValueError):
        slew_toward([0.0, 0.0], [0.0, 0.0, 0.0], 0.1)


def test_setpoint_inbox_keeps_the_latest_and_counts_the_rest():
    inbox = SetpointInbox()
    assert inbox.latest() == (None, None, 0)
    inbox.on_sample(setpoint_payload([0.1, 0.2, 0.3]), attachment(1))
    inbox.on_sample(setpoint_payload([0.4, 0.5, 0.6]), attachment(3))
    inbox.on_sample(b"\x00\x01\x00\x00garbage", attachment(4))
    two = codec.encode_joint_setpoint(m.JointSetpoint(0, 1, (0.1, 0.2)), ())
    inbox.on_sample(two, attachment(5))  # 2 joints
    q, arrival_s, count = inbox.latest()
    assert q == (0.4, 0.5, 0.6) and count == 2 and arrival_s is not None
    stats = inbox.stats()
    assert stats["valid"] == 2 and stats["lost"] == 1 and stats["malformed"] == 2
    assert "2" in stats["last_malformed"]
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
        slave.inbox.on_sample(setpoint_payload(target), attachment(k + 1))
    out = FakeOutputs()
    try:
        slave._control_loop(out)
    finally:
        slave.plant.close()
    states = [codec.decode_joint_state(p, 0) for p in out.joint_states]
    assert all(named.names == NAMES for _, named in states)
    states = [s for s, _ in states]
    forces = [codec.decode_wrench(p) for p in out.true_forces]
    assert len(states) == len(forces) == TICKS
    assert all(f.frame_id == topics.BASE_FRAME for f in forces)
    assert [s.t_ns for s in states] == [f.t_ns for f in forces]
    assert np.all(np.diff([s.t_ns for s in states]) == 1_000_000)  # nominal stamps
    assert slave.safety.state == m.SafetyState.FOLLOWING
    # the reference moved toward the setpoint by the slew limit: 2 rad/s x 1 ms per tick
    moved = np.array(states[-1].q_rad) - q0
    assert np.all(np.sign(moved[:2]) == np.sign(target - q0)[:2])
    assert np.all(np.abs(moved) <= 2.0 * 1e-3 * TICKS + 1e-3)


def test_master_loop_publishes_setpoints_and_joint_states_it_read():
    master = MasterProcess(MasterConfig(loop=LOOP, run=RUN), ZenohOptions(), StopSignal())
    out = FakeOutputs()
    try:
        master._control_loop(out)
    finally:
        master.plant.close()
    sp = [codec.decode_joint_setpoint(p, 0)[0] for p in out.setpoints]
    js = [codec.decode_joint_state(p, 0)[0] for p in out.joint_states]
    assert len(sp) == len(js) == TICKS == master.published
    assert all(a.q_rad == b.q_rad and a.t_ns == b.t_ns for a, b in zip(sp, js, strict=True))
    assert all(s.effort_nm == (0.0, 0.0, 0.0) for s in js)  # no haptic feedback
    assert master.loop.stats()["ticks"] == TICKS + 1  # the last wait ends the loop
