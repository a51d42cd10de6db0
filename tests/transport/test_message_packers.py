"""The object-free packers and unpackers write and read exactly the bytes of the message classes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from teleop_force.errors import MessageError
from teleop_force.transport import messages as m

RNG = np.random.default_rng(17)
SEQS = (0, 1, 123_456, 0xFFFF_FFFF)
STAMPS = (0, 1_700_000_000_123_456_789, -(2**63), 2**63 - 1)


def floats(n: int = 3) -> list[float]:
    return (RNG.standard_normal(n) * 10.0 ** RNG.integers(-300, 300, n)).tolist()


@pytest.mark.parametrize("seq", SEQS)
@pytest.mark.parametrize("t_ns", STAMPS)
def test_packers_match_the_message_classes_byte_for_byte(seq, t_ns):
    for _ in range(20):
        q, qd, effort, force = floats(), floats(), floats(), floats()
        assert (
            m.pack_joint_state(seq, t_ns, q, qd, effort)
            == m.JointState(seq, t_ns, q, qd, effort).encode()
        )
        assert m.pack_joint_setpoint(seq, t_ns, q) == m.JointSetpoint(seq, t_ns, q).encode()
        assert m.pack_contact_force(seq, t_ns, force) == m.ContactForce(seq, t_ns, force).encode()
    # numpy arrays and tuples pack the same as lists; -0.0 keeps its sign bit
    q = np.array([-0.0, 1e-320, -1.5])
    assert m.pack_joint_setpoint(seq, t_ns, q) == m.JointSetpoint(seq, t_ns, q).encode()
    assert len(m.pack_joint_state(seq, t_ns, q, q, q)) == 17 + 24 * 3


@pytest.mark.parametrize(
    "call",
    [
        lambda: m.pack_joint_state(1, 2, [0.0, math.nan, 0.0], [0.0] * 3, [0.0] * 3),
        lambda: m.pack_joint_state(1, 2, [0.0] * 3, [math.inf, 0.0, 0.0], [0.0] * 3),
        lambda: m.pack_joint_state(1, 2, [0.0] * 3, [0.0] * 3, [1e308, 1e308, -math.inf]),
        lambda: m.pack_joint_state(1, 2, [0.0] * 2, [0.0] * 3, [0.0] * 3),
        lambda: m.pack_joint_state(-1, 2, [0.0] * 3, [0.0] * 3, [0.0] * 3),
        lambda: m.pack_joint_state(2**32, 2, [0.0] * 3, [0.0] * 3, [0.0] * 3),
        lambda: m.pack_joint_setpoint(1, 2**63, [0.0] * 3),
        lambda: m.pack_joint_setpoint(1, 2, []),  # no joint
        lambda: m.pack_joint_setpoint(1, 2, [0.0] * 256),  # beyond the joint count's byte
        lambda: m.pack_joint_setpoint(1, 2, ["a", 0.0, 0.0]),
        lambda: m.pack_joint_setpoint(1, 2, [math.nan, 0.0, 0.0]),
        lambda: m.pack_contact_force(1, 2, [0.0, 0.0]),
        lambda: m.pack_contact_force(1, 2, [0.0, -math.inf, 0.0]),
    ],
)
def test_packers_refuse_what_the_message_classes_refuse(call):
    with pytest.raises(MessageError):
        call()


def test_huge_finite_values_are_not_mistaken_for_infinities():
    big = [1e308, 1e308, 1e308]  # their sum overflows; each is finite
    assert m.pack_joint_state(3, 4, big, big, big) == m.JointState(3, 4, big, big, big).encode()
    payload = m.JointSetpoint(5, 6, big).encode()
    assert m.unpack_joint_setpoint(payload) == (5, 6, tuple(big))


def test_unpack_joint_setpoint_round_trip_and_strictness():
    q = floats()
    payload = m.JointSetpoint(7, -8, q).encode()
    seq, t_ns, q_back = m.unpack_joint_setpoint(payload)
    assert (seq, t_ns, q_back) == (7, -8, tuple(q))
    assert m.unpack_joint_setpoint(bytearray(payload))[2] == tuple(q)
    bad = [
        payload[:-1],  # truncated
        b"XF" + payload[2:],  # magic
        payload[:2] + bytes([2]) + payload[3:],  # version
        payload[:3] + bytes([1]) + payload[4:],  # type
        m.JointSetpoint(7, 8, [0.1, 0.2]).encode(),  # a valid message for 2 joints
        m.JointSetpoint(7, 8, [0.0] * 3).encode()[:-8] + np.float64(np.nan).tobytes(),
        b"",
    ]
    for payload_bad in bad:
        with pytest.raises(MessageError):
            m.unpack_joint_setpoint(payload_bad, 3)


def estimate(
    n: int = 3, force=(0.5, -1.5, 2.0), mask=(True, False, True)
) -> m.ForceEstimateMessage:
    return m.ForceEstimateMessage(
        11, 12, 13, force, floats(n), mask[:n], [0.5] * n, floats(n), floats(n)
    )


def test_unpack_force_estimate_returns_the_head_and_checks_the_whole_message():
    message = estimate()
    assert len(message.encode()) == 45 + 32 * 3 + 1
    assert m.unpack_force_estimate(estimate(n=2, mask=(True, True)).encode())[2] == 13
    assert m.unpack_force_estimate(message.encode()) == (11, 12, 13, (0.5, -1.5, 2.0))
    seq, _, _, force = m.unpack_force_estimate(estimate(force=(math.nan,) * 3).encode())
    assert seq == 11 and all(math.isnan(x) for x in force)  # no force: allowed
    good = message.encode()
    tau_at = 45  # first joint-space float
    bad = [
        good[:tau_at] + np.float64(np.inf).tobytes() + good[tau_at + 8 :],
        good[:21] + np.float64(np.inf).tobytes() + good[29:],  # infinite force
        good[:-1] + bytes([0b1000]),  # a mask bit beyond joint 3
        good[:-1],
        estimate(n=2, mask=(True, True)).encode(),  # valid, but not 3 joints
    ]
    for payload in bad:
        with pytest.raises(MessageError):
            m.unpack_force_estimate(payload, 3)


def test_unpack_contact_force_round_trip_and_strictness():
    force = floats()
    payload = m.ContactForce(9, 10, force).encode()
    assert m.unpack_contact_force(payload) == (9, 10, tuple(force))
    for bad in (
        payload[:-1],
        payload[:16] + np.float64(np.nan).tobytes() + payload[24:],
        m.JointSetpoint(9, 10, force).encode(),
    ):
        with pytest.raises(MessageError):
            m.unpack_contact_force(bad)
