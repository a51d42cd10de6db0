import numpy as np
import pytest

from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.description import Robot
from teleop_force.robots.omni import (
    Q_MAX_RAD,
    Q_MIN_RAD,
    SPRING_STIFFNESS_NM_PER_RAD,
    omni_description,
)

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
        [
            regressor.standard(
                rng.uniform(Q_MIN_RAD, Q_MAX_RAD), rng.normal(size=3), rng.normal(size=3)
            )
            for _ in range(100)
        ]
    )
    tol = 1e-10 * np.linalg.norm(rows, 2)
    assert np.linalg.matrix_rank(rows, tol=tol) == base.count
    assert np.linalg.matrix_rank(rows[:, base.independent], tol=tol) == base.count
    # parameters absent from the dynamics (link 2's first moment along its own axis) are dropped
    assert "mcx_2" not in " ".join(base.names())


def test_momentum_and_coriolis_gravity_match_pinocchio(setup) -> None:
    description, robot, regressor, _ = setup
    pi = full_parameters(description, K)
    for q, qd, _ in _states(3):
        p = robot.momentum(q, qd)
        assert np.abs(regressor.momentum(q, qd) @ pi - p).max() < 1e-9 * _scale(p)
        w = robot.coriolis_transpose_gravity(q, qd) + robot.spring_torque(q, K)
        assert np.abs(regressor.coriolis_gravity(q, qd) @ pi - w).max() < 1e-9 * _scale(w)


def test_momentum_form_equals_inverse_dynamics(setup) -> None:
    # d/dt (M qd) - C^T qd + N == M qdd + C qd + N along a smooth trajectory.
    description, _, regressor, _ = setup
    pi = full_parameters(description, K)
    t0, h = 0.37, 1e-5

    def state(t):
        q = np.array([0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)])
        qd = np.array([0.6 * np.cos(2 * t), 1.2 * np.cos(3 * t), -0.75 * np.sin(1.5 * t)])
        qdd = np.array([-1.2 * np.sin(2 * t), -3.6 * np.sin(3 * t), -1.125 * np.cos(1.5 * t)])
        return q, qd, qdd

    q, qd, qdd = state(t0)
    dp = (
        (regressor.momentum(*state(t0 + h)[:2]) - regressor.momentum(*state(t0 - h)[:2]))
        / (2 * h)
        @ pi
    )
    lhs = dp + regressor.coriolis_gravity(q, qd) @ pi
    np.testing.assert_allclose(lhs, regressor.standard(q, qd, qdd) @ pi, atol=1e-8)


def test_representative_parameters_keep_base_values(setup) -> None:
    description, _, _, base = setup
    pi = full_parameters(description, K)
    beta = base.project(pi) * 1.1
    rep = base.representative(beta, pi)
    np.testing.assert_allclose(base.project(rep), beta, rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------- closed chains
# A tree with more joints than motors (a parallelogram's closing link as an extra branch):
# the coupling T is n_model x n_motor, q_model = T q_motor, tau_motor = T^T tau_model.


def _closed_chain(seed: int = 7):
    import pinocchio as pin

    from teleop_force.robots.description import JointSpring, RobotDescription

    pin.seed(seed)
    model = pin.Model()
    yaw = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "yaw")
    shoulder = pin.SE3(pin.utils.rotate("x", np.pi / 2), np.array([0.0, 0.0, 0.1]))
    upper = model.addJoint(yaw, pin.JointModelRZ(), shoulder, "upper")

    def along_x(length: float) -> pin.SE3:
        return pin.SE3(np.eye(3), np.array([length, 0.0, 0.0]))

    fore = model.addJoint(upper, pin.JointModelRZ(), along_x(0.3), "fore")
    back = model.addJoint(yaw, pin.JointModelRZ(), shoulder, "back")  # branch: absolute elbow
    top = model.addJoint(back, pin.JointModelRZ(), along_x(0.1), "top")
    for joint in (yaw, upper, fore, back, top):
        model.appendBodyToJoint(joint, pin.Inertia.Random(), pin.SE3.Identity())
    model.addFrame(pin.Frame("tip", fore, along_x(0.35), pin.FrameType.OP_FRAME))
    # motors: yaw, upper arm angle, absolute elbow angle
    coupling = np.array([[1, 0, 0], [0, 1, 0], [0, -1, 1], [0, 0, 1], [0, 1, -1]], dtype=float)
    description = RobotDescription(
        name="closed-chain",
        model=model,
        n_joints=3,
        coupling=coupling,
        tip_frame="tip",
        rotor_inertia_kgm2=np.array([0.01, 0.02, 0.03]),
        springs=(JointSpring(2, 0.4),),
    )
    return description, np.array([0.7])


def _closed_states(seed: int, count: int = 60):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(-1.0, 1.0, 3), rng.normal(0, 2, 3), rng.normal(0, 10, 3)


def test_non_square_coupling_regressor_matches_rnea_through_t() -> None:
    import pinocchio as pin

    description, k = _closed_chain()
    assert description.coupling.shape == (5, 3) and description.n_model == 5
    assert not description.is_serial
    t = description.coupling
    model = description.model
    data = model.createData()
    regressor = RigidBodyRegressor(description)
    pi = full_parameters(description, k)
    for q, qd, qdd in _closed_states(11):
        tau = t.T @ pin.rnea(model, data, t @ q, t @ qd, t @ qdd)
        tau += description.rotor_inertia_kgm2 * qdd
        tau[2] += k[0] * (q[2] - 0.4)
        assert np.abs(regressor.standard(q, qd, qdd) @ pi - tau).max() < 1e-9 * _scale(tau)


def test_non_square_coupling_momentum_form_matches_pinocchio() -> None:
    import pinocchio as pin

    description, k = _closed_chain()
    t = description.coupling
    model = description.model
    data = model.createData()
    regressor = RigidBodyRegressor(description)
    robot = Robot(description)
    pi = full_parameters(description, k)
    for q, qd, qdd in _closed_states(12):
        mass = pin.crba(model, data, t @ q)
        mass = np.triu(mass) + np.triu(mass, 1).T
        p = t.T @ mass @ t @ qd + description.rotor_inertia_kgm2 * qd
        assert np.abs(regressor.momentum(q, qd) @ pi - p).max() < 1e-9 * _scale(p)
        assert np.abs(robot.momentum(q, qd) - p).max() < 1e-9 * _scale(p)
        coriolis = t.T @ pin.computeCoriolisMatrix(model, data, t @ q, t @ qd) @ t
        gravity = t.T @ pin.computeGeneralizedGravity(model, data, t @ q)
        w = -coriolis.T @ qd + gravity + robot.spring_torque(q, k)
        assert np.abs(regressor.coriolis_gravity(q, qd) @ pi - w).max() < 1e-9 * _scale(w)
        tau = robot.inverse_dynamics(q, qd, qdd) + robot.spring_torque(q, k)
        assert np.abs(regressor.standard(q, qd, qdd) @ pi - tau).max() < 1e-9 * _scale(tau)


def test_non_square_coupling_batch_and_base_parameters() -> None:
    description, k = _closed_chain()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    pi = full_parameters(description, k)
    beta = base.project(pi)
    rng = np.random.default_rng(13)
    q = rng.uniform(-1.0, 1.0, size=(300, 3))
    qd = rng.normal(0.0, 1.0, size=(300, 3))
    qd[:3] = 0.0
    y_p, y_w = regressor.momentum_form_batch(q, qd, base.independent, chunk=128)
    for i in range(q.shape[0]):
        p = regressor.momentum(q[i], qd[i]) @ pi
        w = regressor.coriolis_gravity(q[i], qd[i]) @ pi
        np.testing.assert_allclose(y_p[i] @ beta, p, rtol=0, atol=1e-9 * _scale(p))
        np.testing.assert_allclose(y_w[i] @ beta, w, rtol=0, atol=1e-9 * _scale(w))


def test_non_square_coupling_is_checked() -> None:
    from dataclasses import replace

    from teleop_force.errors import ModelError

    description, _ = _closed_chain()
    deficient = description.coupling.copy()
    deficient[:, 2] = deficient[:, 1]
    with pytest.raises(ModelError, match="full column rank"):
        replace(description, coupling=deficient)
    with pytest.raises(ModelError, match="one per model joint"):
        replace(description, coupling=description.coupling[:4])
    with pytest.raises(ModelError, match="coupling must be 3x3"):
        replace(description, coupling=description.coupling.T)
    with pytest.raises(ModelError, match="coupling must be 3x3"):
        replace(description, model=None, coupling=description.coupling)


def test_representative_with_masses_keeps_base_values_and_pinocchio_finite() -> None:
    """The MTM with an elbow mass driven negative: the plain representative breaks
    pinocchio's composite inertias (negative subtree mass, clamped to epsilon); the
    representative with masses keeps the base parameters and M(q) finite and right."""
    import pinocchio as pin

    from teleop_force.robots.dvrk_mtm import dvrk_mtm_description

    description = dvrk_mtm_description()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    nominal = full_parameters(description, np.zeros(0))
    masses = range(0, 10 * description.n_links, 10)
    values = base.project(nominal)
    elbow = list(base.independent).index(20)  # link 3's mass is a base parameter
    values[elbow] -= 1.5  # the elbow link's mass, as identified, becomes -0.9 kg
    plain = base.representative(values, nominal)
    assert plain[20] < 0
    full = base.representative_with_masses(values, nominal, masses)
    assert np.all(full[list(masses)] >= 1e-2 * (1 - 1e-6))
    np.testing.assert_allclose(base.project(full), values, atol=1e-9)
    rng = np.random.default_rng(3)
    q_motor = rng.uniform(-0.5, 0.5, description.n_joints)
    q = description.coupling @ q_motor
    n_links = 10 * description.n_links
    for candidate, finite in ((plain, False), (full, True)):
        robot = Robot(description.with_link_parameters(candidate[:n_links]))
        mass = pin.crba(robot.model, robot.model.createData(), q)
        assert bool(np.all(np.abs(mass) < 1e6)) is finite
    # M(q) through the coupling equals the base-parameter momentum regressor's
    robot = Robot(
        description.with_link_parameters(full[:n_links]).with_rotor_inertia(
            full[n_links : n_links + description.n_joints]
        )
    )
    mass = pin.crba(robot.model, robot.model.createData(), q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    motor_mass = description.coupling.T @ mass @ description.coupling
    for j in range(description.n_joints):
        unit = np.eye(description.n_joints)[j]
        column = regressor.momentum(q_motor, unit)[:, base.independent] @ values
        rotor = full[n_links + j] * unit
        np.testing.assert_allclose(motor_mass @ unit + rotor, column, atol=1e-9)


def test_representative_with_masses_names_what_cannot_be_made_physical() -> None:
    from teleop_force.errors import ModelError
    from teleop_force.identification.regressor import BaseParameters

    alone = BaseParameters(("m_1", "mx_1"), np.array([0]), np.array([1]), np.zeros((1, 1)))
    with pytest.raises(ModelError, match="m_1"):
        alone.representative_with_masses(np.array([-1.0]), np.array([1.0, 0.0]), [0])
    grouped = BaseParameters(("m_1", "mx_1"), np.array([0]), np.array([1]), np.ones((1, 1)))
    full = grouped.representative_with_masses(np.array([-1.0]), np.array([1.0, 0.0]), [0])
    assert full[0] >= 1e-2 * (1 - 1e-6)
    assert grouped.project(full)[0] == pytest.approx(-1.0)
