import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.simulation.pid import PID, PIDGains
from teleop_force.simulation.session import rigid_body_protocol


def _gains(**changes: object) -> PIDGains:
    values = {
        "kp_nm_per_rad": [10.0, 10.0],
        "ki_nm_per_rad_s": [100.0, 100.0],
        "kd_nms_per_rad": [0.1, 0.1],
        "derivative_cutoff_hz": 30.0,
        "integral_limit_nm": 0.3,
        "torque_limit_nm": 0.6,
    }
    values.update(changes)
    return PIDGains(**values)  # type: ignore[arg-type]


def test_proportional_and_integral_terms() -> None:
    pid = PID(_gains(), n_joints=2)
    tau = pid.update(np.array([0.01, -0.02]), np.zeros(2))
    np.testing.assert_allclose(tau, [0.1, -0.2])  # no derivative on the first sample
    np.testing.assert_allclose(pid.integral_nm, [100 * 0.01e-3, -100 * 0.02e-3])


def test_derivative_acts_on_the_measurement_only() -> None:
    pid = PID(_gains(ki_nm_per_rad_s=[0.0, 0.0]), n_joints=2)
    pid.update(np.zeros(2), np.zeros(2))
    tau = pid.update(np.array([0.05, 0.0]), np.zeros(2))  # reference step: no derivative kick
    np.testing.assert_allclose(tau, [0.5, 0.0])
    tau = pid.update(np.zeros(2), np.array([1e-3, 0.0]))  # measured motion: damped
    a = np.exp(-2 * np.pi * 30.0 * 1e-3)
    assert tau[0] == pytest.approx(-10 * 1e-3 - 0.1 * (1 - a) * 1.0)
    tau = pid.update(np.zeros(2), np.array([1e-3, 0.0]), qd_ref_rad_s=np.array([2.0, 0.0]))
    assert tau[0] > 0.0  # the reference velocity enters as a damping target


def test_saturation_and_anti_windup() -> None:
    pid = PID(_gains(), n_joints=2)
    for _ in range(500):
        tau = pid.update(np.array([1.0, 0.0]), np.zeros(2))
    assert tau[0] == pytest.approx(0.6)
    assert pid.integral_nm[0] == 0.0  # frozen while saturated in the error's direction
    pid.reset(integral_nm=np.array([0.5, -0.1]))
    np.testing.assert_allclose(pid.integral_nm, [0.3, -0.1])  # clipped to the limit
    assert pid.q_previous_rad is None
    pid.reset()
    np.testing.assert_array_equal(pid.integral_nm, 0.0)


def test_validation() -> None:
    with pytest.raises(ConfigurationError):
        _gains(kp_nm_per_rad=[-1.0, 1.0])
    with pytest.raises(ConfigurationError):
        _gains(derivative_cutoff_hz=0.0)
    with pytest.raises(ConfigurationError):
        PID(_gains(), n_joints=3)
    with pytest.raises(DataError):
        PID(_gains(), n_joints=2).update(np.zeros(3), np.zeros(3))


def test_tracks_the_rigid_body_protocol() -> None:
    session = rigid_body_protocol(duration_s=5.0, seed=0)
    reference_rms = np.std(session.q_ref_rad[2000:], axis=0)
    error_rms = session.tracking_rms_rad(skip_s=2.0)
    assert np.all(error_rms < 0.006)
    assert np.all(error_rms < 0.03 * reference_rms)
    assert session.clipped_ticks == 0
