import numpy as np

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig, filter_signals
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description


def _model() -> DynamicModel:
    description = omni_description()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    friction = CoupledCoulombViscous(
        3,
        description.friction_inputs,
        np.array([0.02, 0.002, 0.02, 0.01, 0.003, 0.004, 0.01, 0.002, 0.018, 0.005]),
    )
    return DynamicModel("omni", 3, FilterConfig(), base, beta, 0 * beta, friction, np.zeros(3))


def _motion(n: int = 1500):
    t = np.arange(n) * 1e-3
    q = np.column_stack(
        [0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)]
    )
    q = np.round(q / 4e-4) * 4e-4
    tau = np.column_stack([0.05 * np.sin(5 * t), 0.2 + 0.05 * np.cos(t), 0.01 * np.sin(7 * t)])
    return t, q, tau


def test_streaming_estimate_equals_batch_model_torque() -> None:
    model = _model()
    t, q, tau = _motion()
    signals = filter_signals(
        t, q, tau, RigidBodyRegressor(model.description()), model.base, model.filter_config
    )
    batch = model.predict_filtered_torque(signals, tau)
    estimator = ForceEstimator(model)
    streamed = np.array(
        [estimator.update(t[k], q[k], tau[k]).tau_model_filtered_nm for k in range(t.size)]
    )
    np.testing.assert_allclose(streamed, batch, atol=1e-9)
    ext = np.array([0.0])
    estimator.reset()
    first = estimator.update(t[0], q[0], tau[0])
    ext = first.tau_external_nm
    assert ext.shape == (3,)


def test_force_is_recovered_from_a_pure_external_torque() -> None:
    # A robot at rest whose motors push on a sensor: tau = model + J^T F.
    model = _model()
    estimator = ForceEstimator(model)
    q = np.array([0.1, 0.7, 0.3])
    force = np.array([0.2, -1.5, 0.4])
    from teleop_force.robots.description import Robot

    robot = Robot(model.description())
    k = np.array([SPRING_STIFFNESS_NM_PER_RAD])
    tau = (
        robot.gravity_torque(q)
        + robot.spring_torque(q, k)
        + robot.tip_jacobian_in_base(q).T @ force
    )
    for i in range(2000):
        est = estimator.update(i * 1e-3, q, tau)
    np.testing.assert_allclose(est.force_tip_in_base_n, force, atol=1e-6)
    assert not est.singular


def test_singular_jacobian_is_reported_not_divided() -> None:
    model = _model()
    estimator = ForceEstimator(model)
    # r = l1 cos q2 + l2 sin q3 = 0: the tip is on the yaw axis, the Jacobian loses rank.
    q = np.array([0.0, np.pi / 2, 0.0])
    est = estimator.update(0.0, q, np.zeros(3))
    assert est.singular
    assert np.all(np.isnan(est.force_tip_in_base_n))
