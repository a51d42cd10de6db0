import math

import numpy as np

from teleop_force.transport import messages as m
from web.telemetry import FE_F, FE_SOURCE_SEQ, FE_TRAINED, JS_QD, Telemetry


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def estimate(seq, trained=(True, True, True), f=(0.1, -1.0, 0.2)):
    return m.ForceEstimateMessage(
        seq, 1_000_000_000 + seq * 1_000_000, seq + 7, f, (0.01, 0.02, 0.03), trained,
        (1.0, 0.5, 0.2), (0.1, 0.2, 0.3), (0.09, 0.19, 0.29),
    ).encode()  # fmt: skip


def test_handlers_fill_the_rings_and_counters():
    clock = Clock()
    tel = Telemetry(capacity=64, clock=clock, wall_clock_ns=lambda: 2_000_000_000)
    for k in range(5):
        tel.on_joint_state(
            m.JointState(
                k, 1_000_000_000 + k * 1_000_000, (0.1, 0.2, 0.3), (1.0, 2.0, 3.0), (0.0,) * 3
            ).encode()
        )
        tel.on_estimate(estimate(k))
        tel.on_contact(m.ContactForce(k, 1_000_000_000 + k * 1_000_000, (0.0, -1.0, 0.0)).encode())
    tel.on_setpoint(m.JointSetpoint(0, 1, (0.5, 0.6, 0.7)).encode())
    tel.on_status(m.Status(0, 1, m.SafetyState.HOLDING, "limit").encode())
    js = tel.joint_state.window()
    assert len(js) == 5 and js.values[0, JS_QD].tolist() == [1.0, 2.0, 3.0]
    assert math.isclose(js.t_s[1] - js.t_s[0], 1e-3)
    _, row = tel.estimate.latest()
    assert row[FE_F].tolist() == [0.1, -1.0, 0.2] and row[FE_SOURCE_SEQ] == 11
    assert row[FE_TRAINED].tolist() == [1.0, 1.0, 1.0]
    assert tel.setpoint.latest()[1].tolist() == [0.5, 0.6, 0.7]
    assert tel.status().state is m.SafetyState.HOLDING and tel.status().reason == "limit"
    snaps = tel.snapshots()
    assert snaps["measured_js"].received == 5 and snaps["measured_js"].lost == 0
    assert math.isclose(snaps["estimated_cf"].latency_ms_mean, 1000.0 - 2.0)
    clock.now += 2.0
    assert math.isclose(tel.estimate_age_s(), 2.0) and math.isclose(tel.status_age_s(), 2.0)


def test_malformed_and_wrong_joint_count_are_counted_not_raised():
    tel = Telemetry(capacity=8)
    tel.on_joint_state(b"garbage")
    tel.on_joint_state(m.JointState(0, 1, (0.1, 0.2), (0.0, 0.0), (0.0, 0.0)).encode())
    tel.on_estimate(m.ContactForce(0, 1, (0, 0, 0)).encode())  # wrong type on the key
    tel.on_status(b"TF")
    snaps = tel.snapshots()
    assert snaps["measured_js"].malformed == 2 and len(tel.joint_state) == 0
    assert snaps["estimated_cf"].malformed == 1 and snaps["status"].malformed == 1


def test_untrained_joints_are_held_for_a_while_and_nan_force_is_stored():
    clock = Clock()
    tel = Telemetry(capacity=8, clock=clock)
    assert math.isinf(tel.estimate_age_s()) and tel.untrained_joints(0.5) == ()
    tel.on_estimate(estimate(0, trained=(True, False, False), f=(math.nan,) * 3))
    tel.on_estimate(estimate(1))  # back on trained ground
    assert tel.untrained_joints(0.5) == (1, 2)
    assert np.all(np.isnan(tel.estimate.window().values[0, FE_F]))
    clock.now += 0.6
    assert tel.untrained_joints(0.5) == ()
