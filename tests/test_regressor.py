import numpy as np
import pytest

from teleop_force.omni import Q_MAX_RAD, Q_MIN_RAD, SPRING_STIFFNESS_NM_PER_RAD, omni_description
from teleop_force.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robot import Robot

K = np.array([SPRING_STIFFNESS_NM_PER_RAD])


@pytest.fixture(scope="module")
def setup():
    description = omni_description()
    regressor = RigidBodyRegressor(description)
    return description, Robot(description), regressor, regressor.find_base_parameters()


def _states(seed: int, count: int = 100):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(Q_MIN_RAD, Q_MAX_RAD), rng.normal(0, 2, 3), rng.normal(0, 10, 3)


def _scale(tau: np.ndarray) -> float:
    return max(1.0, float(np.abs(tau).max()))


def test_standard_regressor_matches_rnea(setup) -> None:
    description, robot, regressor, _ = setup
    pi = full_parameters(description, K)
    for q, qd, qdd in _states(1):
        tau = robot.inverse_dynamics(q, qd, qdd) + robot.spring_torque(q, K)
        assert np.abs(regressor.standard(q, qd, qdd) @ pi - tau).max() < 1e-9 * _scale(tau)


def test_base_parameters_reproduce_rnea(setup) -> None:
    description, robot, regressor, base = setup
    pi = full_parameters(description, K)
    beta = base.project(pi)
    for q, qd, qdd in _states(2):
        tau = robot.inverse_dynamics(q, qd, qdd) + robot.spring_torque(q, K)
        y = regressor.standard(q, qd, qdd)[:, base.independent]
        assert np.abs(y @ beta - tau).max() < 1e-9 * _scale(tau)


def test_base_parameters_are_independent_and_complete(setup) -> None:
    _, _, regressor, base = setup
    rng = np.random.default_rng(5)
    rows = np.vstack(
        [regressor.standard(rng.uniform(Q_MIN_RAD, Q_MAX_RAD), rng.normal(size=3), rng.normal(size=3)) for _ in range(100)]
    )
    tol = 1e-10 * np.linalg.norm(rows, 2)
    assert np.linalg.matrix_rank(rows, tol=tol) == base.count
    assert np.linalg.matrix_rank(rows[:, base.independent], tol=tol) == base.count
    # parameters absent from the dynamics (link 2's first moment along its own axis) are dropped
    assert "mcx_2" not in " ".join(base.names())


def test_momentum_and_coriolis_gravity_match_pinocchio(setup) -> None:
    description, robot, regressor, base = setup
    pi = full_parameters(description, K)
    for q, qd, _ in _states(3):
        p = robot.momentum(q, qd)
        assert np.abs(regressor.momentum(q, qd) @ pi - p).max() < 1e-9 * _scale(p)
        w = robot.coriolis_transpose_gravity(q, qd) + robot.spring_torque(q, K)
        assert np.abs(regressor.coriolis_gravity(q, qd) @ pi - w).max() < 1e-9 * _scale(w)


def test_momentum_form_equals_inverse_dynamics(setup) -> None:
    # d/dt (M qd) - C^T qd + N == M qdd + C qd + N along a smooth trajectory.
    description, robot, regressor, _ = setup
    pi = full_parameters(description, K)
    t0, h = 0.37, 1e-5
    def state(t):
        q = np.array([0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)])
        qd = np.array([0.6 * np.cos(2 * t), 1.2 * np.cos(3 * t), -0.75 * np.sin(1.5 * t)])
        qdd = np.array([-1.2 * np.sin(2 * t), -3.6 * np.sin(3 * t), -1.125 * np.cos(1.5 * t)])
        return q, qd, qdd
    q, qd, qdd = state(t0)
    dp = (regressor.momentum(*state(t0 + h)[:2]) - regressor.momentum(*state(t0 - h)[:2])) / (2 * h) @ pi
    lhs = dp + regressor.coriolis_gravity(q, qd) @ pi
    np.testing.assert_allclose(lhs, regressor.standard(q, qd, qdd) @ pi, atol=1e-8)


def test_representative_parameters_keep_base_values(setup) -> None:
    description, _, _, base = setup
    pi = full_parameters(description, K)
    beta = base.project(pi) * 1.1
    rep = base.representative(beta, pi)
    np.testing.assert_allclose(base.project(rep), beta, rtol=1e-12, atol=1e-15)
