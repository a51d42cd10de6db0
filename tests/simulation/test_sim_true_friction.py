import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.simulation.true_friction import TrueFriction


@pytest.fixture(scope="module")
def friction() -> TrueFriction:
    return TrueFriction()


@pytest.fixture(scope="module")
def velocities() -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.concatenate([rng.normal(0.0, 0.05, (300, 3)), rng.normal(0.0, 1.0, (300, 3))])


def test_fast_path_matches_vectorised(friction: TrueFriction, velocities: np.ndarray) -> None:
    fast = np.array([friction.evaluate_floats(*row) for row in velocities])
    np.testing.assert_allclose(fast[:, :3], friction.torque(velocities), rtol=1e-12, atol=1e-15)
    jac = friction.jacobian(velocities)
    np.testing.assert_allclose(fast[:, 3], jac[:, 0, 0], rtol=1e-12)
    np.testing.assert_allclose(fast[:, 4:6], jac[:, 1, 1:], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(fast[:, 6:8], jac[:, 2, 1:], rtol=1e-12, atol=1e-15)
    single = friction.torque(velocities[0])
    assert single.shape == (3,)


def test_jacobian_matches_finite_differences(
    friction: TrueFriction, velocities: np.ndarray
) -> None:
    h = 1e-7
    numeric = np.stack(
        [
            (friction.torque(velocities + h * e) - friction.torque(velocities - h * e)) / (2 * h)
            for e in np.eye(3)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(friction.jacobian(velocities), numeric, atol=1e-5)


def test_friction_is_passive(friction: TrueFriction, velocities: np.ndarray) -> None:
    power = np.sum(friction.torque(velocities) * velocities, axis=1)
    assert np.all(power >= 0.0)


def test_joints_2_and_3_are_coupled_and_joint_1_is_not(friction: TrueFriction) -> None:
    base = np.array([0.3, 0.4, 0.4])
    moved = np.array([0.3, 0.4, -0.4])
    a, b = friction.torque(base), friction.torque(moved)
    assert a[0] == b[0]
    assert abs(b[1] - a[1]) > 5e-3  # joint 2 feels joint 3's velocity
    np.testing.assert_allclose(friction.cable_torque(base), 0.0, atol=1e-15)


def test_magnitudes_follow_the_paper(friction: TrueFriction) -> None:
    # Least-squares Coulomb + viscous fit along the equal and opposite diagonals (Table III).
    v = np.linspace(-1.0, 1.0, 401)
    v = v[np.abs(v) > 0.05]
    fits = {}
    for name, sign in (("equal", 1.0), ("opposite", -1.0)):
        qd = np.stack([v, v, sign * v], axis=1)
        tau = friction.torque(qd)
        basis = np.stack([np.sign(v), v], axis=1)
        fits[name] = np.linalg.lstsq(basis, tau[:, 1], rcond=None)[0]
    coulomb_equal, viscous_equal = fits["equal"]
    coulomb_opposite, viscous_opposite = fits["opposite"]
    assert 0.015 < coulomb_equal < 0.025 and 2e-3 < viscous_equal < 8e-3
    assert coulomb_opposite > coulomb_equal + 2e-3
    assert viscous_opposite > viscous_equal + 3e-3 and viscous_opposite < 1.5e-2


def test_not_coulomb_plus_viscous(friction: TrueFriction) -> None:
    # A per-joint CV model cannot represent the Stribeck hump: the fit leaves a clear residual.
    v = np.linspace(-0.6, 0.6, 601)
    qd = np.stack([v, np.zeros_like(v), np.zeros_like(v)], axis=1)
    tau = friction.torque(qd)[:, 0]
    basis = np.stack([np.sign(v), v], axis=1)
    residual = tau - basis @ np.linalg.lstsq(basis, tau, rcond=None)[0]
    assert np.max(np.abs(residual)) > 3e-3


def test_scaled_and_validation(friction: TrueFriction) -> None:
    qd = np.array([0.2, -0.1, 0.3])
    np.testing.assert_allclose(friction.scaled(2.0).torque(qd), 2.0 * friction.torque(qd))
    np.testing.assert_allclose(friction.scaled(0.0).torque(qd), 0.0)
    with pytest.raises(ConfigurationError):
        TrueFriction(coulomb_nm=(0.01, -0.02, 0.01))
    with pytest.raises(ConfigurationError):
        TrueFriction(smoothing_velocity_rad_s=0.0)
    with pytest.raises(ConfigurationError):
        TrueFriction(viscous_nms_per_rad=(1e-3, 1e-3))  # type: ignore[arg-type]
    with pytest.raises(DataError):
        friction.torque(np.zeros(2))
