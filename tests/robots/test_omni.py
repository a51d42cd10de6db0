import numpy as np
import pytest

from teleop_force.robots.description import Robot
from teleop_force.robots.omni import (
    Q_MAX_RAD,
    Q_MIN_RAD,
    omni_description,
    tip_jacobian_formula,
    tip_position_formula,
)


@pytest.fixture(scope="module")
def robot() -> Robot:
    return Robot(omni_description())


def test_forward_kinematics_matches_conventions(robot: Robot) -> None:
    rng = np.random.default_rng(11)
    for _ in range(200):
        q = rng.uniform(Q_MIN_RAD, Q_MAX_RAD)
        np.testing.assert_allclose(
            robot.tip_position_in_base(q), tip_position_formula(q), atol=1e-12
        )


def test_tip_jacobian_matches_conventions(robot: Robot) -> None:
    rng = np.random.default_rng(12)
    for _ in range(200):
        q = rng.uniform(Q_MIN_RAD, Q_MAX_RAD)
        np.testing.assert_allclose(
            robot.tip_jacobian_in_base(q), tip_jacobian_formula(q), atol=1e-12
        )


def test_jacobian_formula_is_the_derivative_of_the_position() -> None:
    q = np.array([0.3, 0.7, 0.2])
    h = 1e-6
    numeric = np.column_stack(
        [
            (tip_position_formula(q + h * e) - tip_position_formula(q - h * e)) / (2 * h)
            for e in np.eye(3)
        ]
    )
    np.testing.assert_allclose(tip_jacobian_formula(q), numeric, atol=1e-9)


def test_conventions_signs(robot: Robot) -> None:
    # q1 > 0 turns the arm toward -x; q2 > 0 raises link 1; q3 > 0 swings the tip toward the user.
    base = np.array([0.0, 0.5, 0.3])
    p0 = robot.tip_position_in_base(base)
    assert robot.tip_position_in_base(base + np.array([0.1, 0, 0]))[0] < p0[0]
    assert robot.tip_position_in_base(base + np.array([0, 0.1, 0]))[1] > p0[1]
    assert robot.tip_position_in_base(base + np.array([0, 0, 0.1]))[2] > p0[2]


def test_gravity_pulls_down_and_mass_matrix_is_symmetric_positive(robot: Robot) -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        q = rng.uniform(Q_MIN_RAD, Q_MAX_RAD)
        m = robot.mass_matrix(q)
        np.testing.assert_allclose(m, m.T, atol=1e-15)
        assert np.all(np.linalg.eigvalsh(m) > 0)
    # arm horizontal: gravity torque on joint 2 resists (positive torque needed to hold it up)
    assert robot.gravity_torque(np.array([0.0, 0.0, 0.0]))[1] > 0.05


def test_tip_force_mapping_inverts_jacobian_transpose(robot: Robot) -> None:
    q = np.array([0.2, 0.8, 0.1])
    force = np.array([0.3, -1.2, 0.5])
    tau = robot.tip_jacobian_in_base(q).T @ force
    np.testing.assert_allclose(robot.tip_force_from_joint_torque(q, tau), force, atol=1e-12)
