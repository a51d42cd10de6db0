"""Pure logic of the teleoperation processes: safety monitor, rate loop, operator, feedback."""

import time

import numpy as np
import pytest

from master_slave.master import feedback_torque_nm
from master_slave.operator import OperatorConfig, ScriptedOperator, palpation_start_rad
from master_slave.realtime import LoopConfig, RateLoop
from master_slave.safety import SafetyConfig, SafetyMonitor
from teleop_force.errors import ConfigurationError
from teleop_force.robots import omni
from teleop_force.transport.messages import SafetyState


def test_safety_follows_then_holds_on_stale_setpoints_then_resumes():
    monitor = SafetyMonitor(SafetyConfig(stale_s=0.05, resume_count=3))
    assert monitor.update(0.0, True, None, 0).state == SafetyState.STARTING
    assert monitor.update(0.002, True, 0.001, 2).state == SafetyState.STARTING  # not enough yet
    decision = monitor.update(0.003, True, 0.003, 3)
    assert decision.state == SafetyState.FOLLOWING and decision.changed
    assert not monitor.update(0.05, True, 0.003, 3).changed  # 47 ms old: still fresh
    decision = monitor.update(0.0535, True, 0.003, 3)
    assert decision.state == SafetyState.HOLDING and decision.changed
    assert "stale" in decision.reason and "50.5 ms" in decision.reason
    assert monitor.update(0.06, True, 0.06, 4).state == SafetyState.HOLDING  # one is not enough
    assert monitor.update(0.062, True, 0.062, 6).state == SafetyState.FOLLOWING
    assert monitor.holds == 1


def test_safety_holds_at_once_when_the_token_goes():
    monitor = SafetyMonitor()
    monitor.update(0.0, True, 0.0, 10)
    decision = monitor.update(0.001, False, 0.001, 11)
    assert decision.state == SafetyState.HOLDING
    assert decision.reason == "master liveliness token lost"
    # fresh setpoints without the token do not resume
    assert monitor.update(0.1, False, 0.1, 100).state == SafetyState.HOLDING
    assert monitor.update(0.2, True, 0.2, 200).state == SafetyState.FOLLOWING
    assert monitor.stop("bye").state == SafetyState.STOPPED


def test_rate_loop_keeps_the_rate_and_counts_overruns():
    loop = RateLoop(LoopConfig(rate_hz=500.0, spin_s=1e-4))
    loop.start()
    stamps = []
    for _ in range(50):
        loop.wait()
        stamps.append(loop.stamp_ns)
    assert np.all(np.diff(stamps) == 2_000_000)  # exactly periodic stamps
    loop.wait()
    time.sleep(0.006)  # this tick overruns: the next ones start late
    loop.wait()
    assert loop.overruns >= 1
    stats = loop.stats()
    assert stats["ticks"] == 52 and stats["resyncs"] == 0


def test_rate_loop_resyncs_when_far_behind():
    loop = RateLoop(LoopConfig(rate_hz=1000.0, max_lag_s=0.01))
    loop.start()
    loop.wait()
    before = loop.stamp_ns
    time.sleep(0.05)
    loop.wait()
    assert loop.resyncs == 1
    assert loop.stamp_ns - before >= 40_000_000  # stamps follow the wall clock again
    with pytest.raises(ConfigurationError):
        LoopConfig(rate_hz=0.5)


def test_operator_script_starts_at_the_hover_point_and_is_sampled_in_blocks():
    operator = ScriptedOperator(
        OperatorConfig(motion="palpation", duration_s=20.0), 1e-3, block=100
    )
    np.testing.assert_allclose(operator.start_rad(), palpation_start_rad(), atol=1e-12)
    q0, _ = operator.reference(0)
    q250, _ = operator.reference(250)
    expected, _ = operator.trajectory.sample(0.25)
    np.testing.assert_allclose(q250, expected, atol=1e-12)
    np.testing.assert_allclose(q0, palpation_start_rad(), atol=1e-12)
    random = ScriptedOperator(OperatorConfig(motion="random"), 1e-3)
    assert random.reference(10)[0].shape == (3,)
    with pytest.raises(ConfigurationError):
        OperatorConfig(motion="dance")


def test_feedback_torque_displays_the_reaction_and_is_limited():
    q = palpation_start_rad()
    force = np.array([0.0, -2.0, 0.0])  # the slave presses down
    tau = feedback_torque_nm(q, force, 0.5, 0.6)
    np.testing.assert_allclose(tau, omni.tip_jacobian_formula(q).T @ np.array([0.0, 1.0, 0.0]))
    assert np.all(np.abs(feedback_torque_nm(q, 100 * force, 1.0, 0.05)) <= 0.05)
    assert np.all(feedback_torque_nm(q, np.array([np.nan, 0, 0]), 1.0, 0.6) == 0.0)
