"""The generalised-momentum observer: no false force in free motion, a first-order response."""

import math

import numpy as np
import pytest

from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import ForceEstimator, with_estimator
from teleop_force.estimation.momentum_observer import observer_gain, observer_update_into
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
        observer_prefilter_hz=1e5,
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
