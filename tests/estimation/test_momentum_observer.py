"""The generalised-momentum observer: no false force in free motion, a first-order response."""

import math

import numpy as np
import pytest
from scipy import signal

from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import ForceEstimator, with_estimator
from teleop_force.estimation.momentum_observer import (
    butterworth_step_into,
    observer_gain,
    observer_update_into,
)
from teleop_force.friction.coulomb_viscous import CoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.description import Robot
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from teleop_force.simulation.plant import PlantConfig
from teleop_force.simulation.session import teleoperation_protocol


def _true_model(config: FilterConfig) -> DynamicModel:
    """The simulated Omni's own rigid body and spring, no friction (an ideal plant's model)."""
    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    friction = CoulombViscous(3, np.zeros(6))
    return DynamicModel("omni", 3, config, base, beta, 0 * beta, friction, np.zeros(3))


def test_free_motion_gives_no_external_torque() -> None:
    """An ideal plant (no friction, noise or quantization) moved freely: ``tau_ext`` ~ 0."""
    session = teleoperation_protocol(3.0, seed=11, plant_config=PlantConfig().ideal())
    assert not np.abs(session.f_tip_in_base_n).any()  # no contact
    model = _true_model(FilterConfig(estimator="observer"))
    result = BatchEstimator(model).estimate(session.t_s, session.q_rad, session.tau_nm)
    valid = session.t_s >= 0.5
    torque_rms = np.sqrt(np.mean(result.tau_motor_filtered_nm[valid] ** 2, axis=0))
    residual_rms = np.sqrt(np.mean(result.tau_external_nm[valid] ** 2, axis=0))
    assert (torque_rms > 1e-3).all()  # the arm does move and carry torque
    assert (residual_rms < 0.01 * torque_rms).all()
    assert np.nanmax(np.abs(result.force_tip_in_base_n[valid])) < 0.02


@pytest.mark.parametrize("observer_hz", [4.0, 8.0, 25.0])
def test_step_response_is_first_order_with_the_bandwidth(observer_hz) -> None:
    """At rest, a step of the external torque: ``r = E (1 - exp(-t K))``, ``K = 2 pi hz``."""
    # a pre-filter far above the observer passes the step unchanged (a = exp(-2 pi 100))
    config = FilterConfig(
        velocity_cutoff_hz=1e5, estimator="observer", observer_hz=observer_hz,
        observer_prefilter_hz=1e5, observer_output_hz=0.0,
    )  # fmt: skip
    model = _true_model(config)
    robot = Robot(model.description())
    q = np.array([0.1, 0.7, 0.3])
    force = np.array([0.3, -1.2, 0.5])
    tau_ext = robot.tip_jacobian_in_base(q).T @ force
    holding = robot.gravity_torque(q) + robot.spring_torque(q, [SPRING_STIFFNESS_NM_PER_RAD])
    n, step = 800, 200
    t = np.arange(n) * 1e-3
    tau = np.tile(holding, (n, 1))
    tau[step:] += tau_ext
    estimator = ForceEstimator(model)
    residual = np.array([estimator.update(t[k], q, tau[k]).tau_external_nm for k in range(n)])
    np.testing.assert_allclose(residual[: step + 1], 0.0, atol=1e-12)  # the torque acts late
    fraction = residual[step + 1 :] / tau_ext
    elapsed = t[step + 1 :] - t[step]
    rising = (fraction[:, 0] > 0.05) & (fraction[:, 0] < 0.95)
    assert rising.sum() > 5
    time_constants = -elapsed[rising, None] / np.log(1.0 - fraction[rising])
    np.testing.assert_allclose(time_constants, 1.0 / (2 * math.pi * observer_hz), rtol=0.02)
    np.testing.assert_allclose(residual[-1], tau_ext, rtol=1e-3)
    # the filter estimator is first order at its own cutoff: the same response at rest when
    # the bandwidths agree (the two discretisations coincide there), another one otherwise
    filtered = ForceEstimator(with_estimator(model, "filter"))
    other = np.array([filtered.update(t[k], q, tau[k]).tau_external_nm for k in range(n)])
    same = np.allclose(other, residual, rtol=0.0, atol=1e-9)
    assert same == (observer_hz == config.cutoff_hz)


def test_observer_update_starts_at_the_momentum_and_integrates_the_drive() -> None:
    p_hat, drive, residual = np.zeros(2), np.zeros(2), np.zeros(2)
    momentum = np.array([0.1, -0.2])
    tau, beta, friction = np.array([1.0, 2.0]), np.array([0.5, 0.5]), np.array([0.1, -0.1])
    observer_update_into(momentum, tau, beta, friction, 0.0, 50.0, 1, True, p_hat, drive, residual)
    np.testing.assert_array_equal(p_hat, momentum)
    np.testing.assert_array_equal(residual, 0.0)
    np.testing.assert_allclose(drive, tau - beta - friction)
    dt = 2e-3
    observer_update_into(momentum, tau, beta, friction, dt, 50.0, 1, False, p_hat, drive, residual)
    np.testing.assert_allclose(p_hat, momentum + dt * (tau - beta - friction))
    gain = observer_gain(50.0, dt)
    assert gain == pytest.approx((1 - math.exp(-0.1)) / dt, rel=1e-14)
    np.testing.assert_allclose(residual, gain * dt * (tau - beta - friction))


@pytest.mark.parametrize("output_hz", [10.0, 40.0])
def test_the_output_filter_is_scipys_butterworth_on_the_observer(output_hz) -> None:
    """At a constant 1 kHz the output filter is ``scipy.signal.butter(2, f)`` on the residual."""
    config = FilterConfig(estimator="observer", observer_hz=200.0, observer_output_hz=0.0)
    model = _true_model(config)
    filtered = with_estimator(model, observer_output_hz=output_hz)
    assert filtered.filter_config.observer_output_hz == output_hz
    assert with_estimator(filtered, observer_output_hz=0.0).filter_config == config
    session = teleoperation_protocol(1.5, seed=5)
    t, q, tau = session.t_s, session.q_rad, session.tau_nm
    tau = tau + np.where(t[:, None] > 0.7, 0.05, 0.0)  # a torque step on every joint
    plain = BatchEstimator(model).estimate(t, q, tau).tau_external_nm
    sos = signal.butter(2, output_hz, fs=1000.0, output="sos")
    expected = signal.sosfilt(sos, plain, axis=0)  # at rest at the first sample (r = 0 there)
    got = BatchEstimator(filtered).estimate(t, q, tau).tau_external_nm
    np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-12)
    assert np.max(np.abs(got - plain)) > 1e-3  # it does filter
    streaming = ForceEstimator(filtered)
    step = np.array([streaming.update(t[k], q[k], tau[k]).tau_external_nm for k in range(t.size)])
    np.testing.assert_allclose(step, got, rtol=0.0, atol=1e-9)


def test_the_output_filter_stays_bounded_across_a_gap() -> None:
    """A 200 ms pause inside a stream (no restart) must not fold the filter back."""
    values = np.zeros(3)
    state = np.zeros(9)
    omega = 2 * math.pi * 40.0
    butterworth_step_into(values, state, omega, 0.0, True)  # at rest at 0, then a unit step
    outputs = []
    for dt in [1e-3] * 5 + [0.2] + [1e-3] * 200:
        values[:] = 1.0
        butterworth_step_into(values, state, omega, dt, False)
        outputs.append(values[0])
    assert np.all(np.isfinite(outputs))
    assert max(outputs) < 1.05  # at most the step response's 4 % overshoot
    assert outputs[5] == 1.0 and outputs[-1] == 1.0  # settled over the gap
