"""Part of ``teleop-force bench``: CDR encode and decode cost per ROS 2 message type.

Times :mod:`teleop_force.ros2.codec` (``rosbags``' CDR serializer) on the Omni's messages,
one call at a time with ``perf_counter_ns`` (as the service's receive thread calls it), and
the binary wire format's ``encode`` / ``decode`` of the same values for reference. The 1 kHz
budget is 1000 µs per sample for everything a process does; these are what the encoding adds
per message.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from teleop_force.bench.measure import percentiles, rounded
from teleop_force.ros2 import codec
from teleop_force.ros2.topics import BASE_FRAME, OMNI_MODEL_JOINT_NAMES
from teleop_force.transport import messages as m

_T_NS = 1_764_158_400_123_456_789
_NAMES = OMNI_MODEL_JOINT_NAMES
_JS = m.JointState(1, _T_NS, (0.1, 0.8, 0.3), (0.01, -0.02, 0.03), (0.02, 0.15, 0.05))
_SETPOINT = m.JointSetpoint(1, _T_NS, (0.1, 0.8, 0.3))
_FORCE = m.ContactForce(1, _T_NS, (0.0, -1.8, 0.1))
_ESTIMATE = m.ForceEstimateMessage(
    seq=1, t_ns=_T_NS, source_seq=1, f_n=(0.1, -1.7, 0.2), tau_ext_nm=(0.01, 0.02, 0.03),
    on_trained_ground=(True, True, False), coverage_weight=(1.0, 0.9, 0.2),
    tau_motor_filtered_nm=(0.02, 0.15, 0.05), tau_model_filtered_nm=(0.01, 0.13, 0.02),
)  # fmt: skip
_STATUS = m.Status(1, _T_NS, m.SafetyState.FOLLOWING, "following the master")


def _time_us(call: Callable[[], Any], samples: int) -> tuple[float | None, float | None]:
    """Return the p50 and p99 of one ``call()`` [µs], after a warm-up of 100 calls."""
    for _ in range(100):
        call()
    out = np.empty(samples)
    clock = time.perf_counter_ns
    for k in range(samples):
        start = clock()
        call()
        out[k] = clock() - start
    p50, p99 = percentiles(out / 1000.0, (50, 99))
    return rounded(p50), rounded(p99)


def _cases() -> dict[str, tuple[Callable[[], Any], Callable[[], Any], Callable[[], Any],
                                Callable[[], Any]]]:  # fmt: skip
    """Per type: CDR encode, CDR decode, wire encode, wire decode."""
    js_cdr = codec.encode_joint_state(_JS, _NAMES)
    sp_cdr = codec.encode_joint_setpoint(_SETPOINT, _NAMES)
    cf_cdr = codec.encode_contact_force(_FORCE, BASE_FRAME)
    wrench, diagnostics = codec.encode_estimate(_ESTIMATE, _NAMES, BASE_FRAME)
    st_cdr = codec.encode_status(_STATUS)
    values: dict[str, m.Message] = {
        "js": _JS, "sp": _SETPOINT, "cf": _FORCE, "fe": _ESTIMATE, "st": _STATUS,
    }  # fmt: skip
    wires = {k: v.encode() for k, v in values.items()}

    def estimate_decode() -> Any:
        return codec.estimate_message(
            1, codec.decode_wrench(wrench), codec.decode_estimate_diagnostics(diagnostics)
        )

    return {
        "JointState (measured_js)": (
            lambda: codec.encode_joint_state(_JS, _NAMES),
            lambda: codec.decode_joint_state(js_cdr, 1),
            _JS.encode, lambda: m.decode(wires["js"]),
        ),
        "JointState (setpoint_js)": (
            lambda: codec.encode_joint_setpoint(_SETPOINT, _NAMES),
            lambda: codec.decode_joint_setpoint(sp_cdr, 1),
            _SETPOINT.encode, lambda: m.decode(wires["sp"]),
        ),
        "WrenchStamped (true_cf)": (
            lambda: codec.encode_contact_force(_FORCE, BASE_FRAME),
            lambda: codec.decode_contact_force(cf_cdr, 1),
            _FORCE.encode, lambda: m.decode(wires["cf"]),
        ),
        "WrenchStamped + EstimateDiagnostics (estimated_cf)": (
            lambda: codec.encode_estimate(_ESTIMATE, _NAMES, BASE_FRAME),
            estimate_decode,
            _ESTIMATE.encode, lambda: m.decode(wires["fe"]),
        ),
        "Status (status)": (
            lambda: codec.encode_status(_STATUS),
            lambda: codec.decode_status(st_cdr, 1),
            _STATUS.encode, lambda: m.decode(wires["st"]),
        ),
    }  # fmt: skip


def cdr_figures(samples: int) -> dict[str, Any]:
    """Return ``cdr_{encode,decode}_{p50,p99}_us_by_type`` and the wire format's p50s."""
    figures: dict[str, Any] = {
        "cdr_encode_p50_us_by_type": {}, "cdr_encode_p99_us_by_type": {},
        "cdr_decode_p50_us_by_type": {}, "cdr_decode_p99_us_by_type": {},
        "wire_encode_p50_us_by_type": {}, "wire_decode_p50_us_by_type": {},
        "cdr_samples": samples,
    }  # fmt: skip
    for name, (encode, decode, wire_encode, wire_decode) in _cases().items():
        p50, p99 = _time_us(encode, samples)
        figures["cdr_encode_p50_us_by_type"][name] = p50
        figures["cdr_encode_p99_us_by_type"][name] = p99
        p50, p99 = _time_us(decode, samples)
        figures["cdr_decode_p50_us_by_type"][name] = p50
        figures["cdr_decode_p99_us_by_type"][name] = p99
        figures["wire_encode_p50_us_by_type"][name] = _time_us(wire_encode, samples)[0]
        figures["wire_decode_p50_us_by_type"][name] = _time_us(wire_decode, samples)[0]
    return figures
