"""The streaming estimator's single-sample kernels against the batch computations they replace."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import ModelError, SingularityError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.estimation.kernels import (
    ModelTerms,
    linear_map_into,
    rigid_terms_into,
    tip_force_into,
)
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect
from teleop_force.identification.filtered_regressor import FilterConfig, filter_signals
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.description import Robot
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from tests.estimation.network_cases import CV_PARAMETERS, random_network

EFFECT_SPECS = [
    (BasisSpec(0, "q1", "constant", "sign"), [0.004]),
    (BasisSpec(1, "q2", "periodic", frequency=2.0, harmonics=2), [1e-3, -2e-3, 5e-4, 1e-3]),
    (BasisSpec(2, "q2-q3", "smooth", lo=-1.0, hi=1.0, count=4), [1e-3, -1e-3, 2e-3, 0.0]),
    (BasisSpec(2, "qd3", "stribeck", "sign", scales=(0.05, 0.2)), [2e-3, 1e-3]),
    (BasisSpec(1, "tau2", "linear", "positive"), [0.05]),
    (BasisSpec(0, "qd2", "abs"), [0.003]),
    (BasisSpec(1, "t", "linear"), [1e-3]),
    (
        BasisSpec(1, "q1-q2", "smooth", "both", lo=-1.0, hi=1.0, count=3),
        [1e-3, -2e-3, 3e-3, 4e-4, 0.0, -1e-3],
    ),
    (BasisSpec(0, "q3", "periodic", "both", frequency=1.5, harmonics=1), [1e-3, 2e-3, -5e-4, 7e-4]),
]

#: The paper's filtered dynamics without a dead band: what identification's batch form computes.
PAPER_FILTER = FilterConfig(estimator="filter", standstill_band_rad_s=0.0)


def _network(seed: int = 0) -> WaveletNetwork:
    return random_network(seed)


def _model(friction, effects=()) -> DynamicModel:
    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    effects = tuple(FoundEffect(spec, np.asarray(c, dtype=float)) for spec, c in effects)
    return DynamicModel(
        "omni", 3, PAPER_FILTER, base, beta, 0 * beta, friction, np.zeros(3), effects
    )


def _motion(n: int = 1500):
    t = 0.3 + np.arange(n) * 1e-3
    q = np.column_stack(
        [0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)]
    )
    q = np.round(q / 4e-4) * 4e-4
    tau = np.column_stack([0.05 * np.sin(5 * t), 0.2 + 0.05 * np.cos(t), 0.01 * np.sin(7 * t)])
    return t, q, tau


@pytest.mark.parametrize("friction", ["wn", "cv", "coupled-cv"])
def test_streaming_estimate_with_network_and_effects_equals_batch(friction) -> None:
    description = omni_description()
    model_friction = {
        "wn": _network(),
        "cv": CoulombViscous(3, CV_PARAMETERS[[0, 1, 2, 3, 6, 7]]),
        "coupled-cv": CoupledCoulombViscous(3, description.friction_inputs, CV_PARAMETERS),
    }[friction]
    model = _model(model_friction, EFFECT_SPECS)
    t, q, tau = _motion()
    signals = filter_signals(
        t, q, tau, RigidBodyRegressor(description), model.base, model.filter_config
    )
    batch = model.predict_filtered_torque(signals, tau)
    estimator = ForceEstimator(model)
    estimates = [estimator.update(t[k], q[k], tau[k]) for k in range(t.size)]
    streamed = np.array([e.tau_model_filtered_nm for e in estimates])
    np.testing.assert_allclose(streamed, batch, rtol=0, atol=1e-9)
    weight = np.array([e.coverage_weight for e in estimates])
    np.testing.assert_allclose(weight, model.friction.coverage_weight(signals.qd_rad_s), atol=1e-12)
    # a reset starts a new stream: the same samples give the same estimates
    estimator.reset()
    again = [estimator.update(t[k], q[k], tau[k]) for k in range(50)]
    for a, b in zip(again, estimates[:50], strict=True):
        np.testing.assert_array_equal(a.tau_model_filtered_nm, b.tau_model_filtered_nm)
        np.testing.assert_array_equal(a.force_tip_in_base_n, b.force_tip_in_base_n)


def test_force_equals_least_squares_of_the_robot() -> None:
    model = _model(_network())
    estimator = ForceEstimator(model)
    robot = estimator.robot
    assert robot is not None and estimator._rigid is not None
    pinocchio = estimator._rigid

    def jacobian(q):
        return pin.computeFrameJacobian(
            robot.model, pinocchio.data, robot.to_model(np.asarray(q)), pinocchio.tip,
            pin.LOCAL_WORLD_ALIGNED,
        )  # fmt: skip

    def tip_force(q, tau):
        force = np.full(3, np.nan)
        motor = np.zeros((3, 3))
        ok = tip_force_into(jacobian(q), robot.coupling, np.asarray(tau), 5e-3, motor, force)
        if not ok:
            raise SingularityError(0.0, 5e-3)
        return force, motor

    rng = np.random.default_rng(3)
    description = omni_description()
    checked = 0
    for _ in range(300):
        q = rng.uniform(description.q_min_rad, description.q_max_rad)
        tau = rng.normal(0.0, 0.1, 3)
        try:
            expected = robot.tip_force_from_joint_torque(q, tau, 5e-3)
        except Exception:
            expected = None
        try:
            got = tip_force(q, tau)[0]
        except SingularityError:
            got = None
        assert (expected is None) == (got is None)
        if got is not None:
            np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
            checked += 1
    assert checked > 250
    jac = robot.tip_jacobian_in_base(np.array([0.2, 0.5, 0.4]))
    _, motor = tip_force([0.2, 0.5, 0.4], [0.1, 0.0, 0.0])
    np.testing.assert_allclose(motor, jac, atol=1e-14)


def test_model_terms_follow_new_coverage_counts() -> None:
    net = _network()
    terms = ModelTerms(_model(net))
    rng = np.random.default_rng(1)
    points = rng.uniform(-2.6, 2.6, size=(300, 3))
    points[:10] = [[-2.0, -2.0, -1.5]] * 10  # outside the grids
    zero = [0.0, 0.0, 0.0]
    got = np.array([terms(0.0, zero, p.tolist(), zero)[1] for p in points])
    np.testing.assert_allclose(got, net.coverage.trust(points), rtol=0, atol=1e-12)
    assert 0.0 < got.mean() < 1.0
    net.coverage.add(rng.normal(0.5, 0.1, size=(5000, 3)))  # the terms follow new counts
    again = np.array([terms(0.0, zero, p.tolist(), zero)[1] for p in points])
    np.testing.assert_allclose(again, net.coverage.trust(points), atol=1e-12)
    assert np.abs(again - got).max() > 0.1


@pytest.mark.parametrize("friction", ["cv", "coupled-cv"])
def test_model_terms_equal_friction_offsets_and_effects(friction) -> None:
    description = omni_description()
    rng = np.random.default_rng(2)
    model_friction = {
        "cv": CoulombViscous(3, rng.normal(size=6)),
        "coupled-cv": CoupledCoulombViscous(3, description.friction_inputs, rng.normal(size=10)),
    }[friction]
    model = dataclasses.replace(_model(model_friction, EFFECT_SPECS), offsets_nm=rng.normal(size=3))
    terms = ModelTerms(model)
    t = np.sort(rng.uniform(0.0, 5.0, 200))
    q, qd, load = (rng.normal(0.0, 1.0, size=(200, 3)) for _ in range(3))
    qd[:5, 1] = qd[:5, 2]  # zero relative velocity
    qd[5:10, 0] = 0.0
    expected = model.friction_torque(qd) + model.offsets_nm + model.effects_torque(t, q, qd, load)
    got = [terms(t[k] - t[0], q[k].tolist(), qd[k].tolist(), load[k].tolist())[0]
           for k in range(200)]  # fmt: skip
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    model_friction.parameters[:] = rng.normal(size=model_friction.parameters.size)  # followed
    got = terms(0.0, q[0].tolist(), qd[0].tolist(), load[0].tolist())[0]
    np.testing.assert_allclose(got, model.friction_torque(qd[:1])[0] + model.offsets_nm
                               + model.effects_torque(t[:1], q[:1], qd[:1], load[:1])[0],
                               atol=1e-12)  # fmt: skip


def test_model_terms_refuse_an_effect_outside_the_joints() -> None:
    model = _model(CoulombViscous(3), [(BasisSpec(0, "q7", "linear"), [1.0])])
    with pytest.raises(ModelError):
        ModelTerms(model)


def test_torque_one_equals_torque_and_follows_changes() -> None:
    net = _network()
    qd = np.random.default_rng(5).uniform(-2.2, 2.2, size=(500, 3))
    np.testing.assert_allclose([net.torque_one(v) for v in qd], net.torque(qd), atol=1e-13)
    net.set_joint_parameters(1, np.ones(net.parameter_counts()[1]) * 1e-3)
    np.testing.assert_allclose(net.torque_one(qd[0]), net.torque(qd[0]), atol=1e-13)
    idx = net.active_global_indices(2)[:3]
    net.set_coefficients_at(idx, [1e-2, 2e-2, 3e-2])
    np.testing.assert_allclose(net.torque_one(qd[1]), net.torque(qd[1]), atol=1e-13)
    net.deactivate(idx)
    np.testing.assert_allclose(net.torque_one(qd[2].tolist()), net.torque(qd[2]), atol=1e-13)
    net.parameters = np.zeros(net.parameters.size)
    np.testing.assert_array_equal(net.torque_one(qd[3]), np.zeros(3))


@pytest.mark.parametrize("with_coverage", [True, False])
def test_network_without_fallback_raises_on_update(with_coverage) -> None:
    net = _network()
    net.fallback = None
    if not with_coverage:
        net.coverage = None
    estimator = ForceEstimator(_model(net))
    with pytest.raises(ModelError):
        estimator.update(0.0, np.zeros(3), np.zeros(3))


def test_linear_map_into() -> None:
    matrix = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.5], [0.0, 0.0, 0.0]])
    x = np.array([0.3, -1.2, 2.5])
    out = np.full(3, np.nan)
    linear_map_into(matrix, x, out)
    np.testing.assert_array_equal(out, matrix @ x)


def test_estimator_matches_robot_terms() -> None:
    model = _model(CoupledCoulombViscous(3, omni_description().friction_inputs, CV_PARAMETERS))
    estimator = ForceEstimator(model)
    robot = estimator.robot
    assert isinstance(robot, Robot) and estimator._rigid is not None
    q, qd = np.array([0.2, 0.9, 0.1]), np.array([0.4, -0.7, 1.1])
    data = estimator._rigid.data
    q_model, v_model = robot.to_model(q), robot.coupling @ qd
    mass = pin.crba(robot.model, data, q_model)
    coriolis = pin.computeCoriolisMatrix(robot.model, data, q_model, v_model)
    gravity = pin.computeGeneralizedGravity(robot.model, data, q_model)
    momentum, other = np.zeros(3), np.zeros(3)
    rigid_terms_into(
        q, qd, v_model, mass, coriolis, gravity, robot.coupling, estimator._rotor,
        estimator._springs, momentum, other,
    )  # fmt: skip
    np.testing.assert_allclose(momentum, robot.momentum(q, qd), atol=1e-15)
    expected = robot.coriolis_transpose_gravity(q, qd) + robot.spring_torque(
        q, estimator.spring_stiffness
    )
    np.testing.assert_allclose(other, expected, atol=1e-14)


def test_replaced_friction_objects_are_picked_up() -> None:
    net = _network()
    model = _model(net)
    estimator = ForceEstimator(model)
    fast = np.array([1.5, -1.8, 1.9])  # off the trained ground
    estimator.update(0.0, np.zeros(3), np.zeros(3))
    first = estimator.update(1e-3, fast * 0.01, np.zeros(3))
    assert np.all(first.coverage_weight < 1.0)
    net.coverage = None
    estimator.reset()
    estimator.update(0.0, np.zeros(3), np.zeros(3))
    second = estimator.update(1e-3, fast * 0.01, np.zeros(3))
    np.testing.assert_array_equal(second.coverage_weight, np.ones(3))
    assert dataclasses.is_dataclass(second)


def test_streaming_estimate_spreads_effects_at_model_joints_like_batch() -> None:
    """An effect with a reach (a torque at a model joint, through the coupling) lands on every
    joint it reaches, in the compiled stream as in the batch prediction."""
    description = omni_description()
    spec = BasisSpec(2, "q3", "smooth", "both", -0.5, 1.0, 4)
    reach = np.array([0.0, -1.0, 1.0])
    effect = FoundEffect(
        spec, np.array([0.01, -0.02, 0.015, 0.005, 0.002, -0.001, 0.0, 0.003]), 0, reach
    )
    without = _model(CoulombViscous(3, CV_PARAMETERS[[0, 1, 2, 3, 6, 7]]))
    model = dataclasses.replace(without, effects=(effect,))
    t, q, tau = _motion()
    signals = filter_signals(
        t, q, tau, RigidBodyRegressor(description), model.base, model.filter_config
    )
    batch = model.predict_filtered_torque(signals, tau)
    spread = batch - without.predict_filtered_torque(signals, tau)
    np.testing.assert_allclose(spread[:, 1], -spread[:, 2], atol=1e-15)
    assert np.abs(spread[:, 2]).max() > 1e-3 and np.all(spread[:, 0] == 0.0)
    estimator = ForceEstimator(model)
    streamed = np.array(
        [estimator.update(t[k], q[k], tau[k]).tau_model_filtered_nm for k in range(t.size)]
    )
    np.testing.assert_allclose(streamed, batch, rtol=0, atol=1e-9)
