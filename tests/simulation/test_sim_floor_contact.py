import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.simulation.floor_contact import HuntCrossleyFloor


def test_normal_force_is_nonlinear_in_the_penetration() -> None:
    floor = HuntCrossleyFloor.horizontal(-0.06)
    still = np.zeros(3)
    above = floor.force_on_environment(np.array([0.0, -0.059, 0.1]), still)
    np.testing.assert_array_equal(above, 0.0)
    f3 = floor.force_on_environment(np.array([0.0, -0.063, 0.1]), still)
    f6 = floor.force_on_environment(np.array([0.0, -0.066, 0.1]), still)
    assert f3[1] < 0.0  # pressing down: the tip pushes the floor along -y
    assert f6[1] / f3[1] == pytest.approx(2.0**1.5)  # k delta^1.5
    assert -f6[1] == pytest.approx(3200.0 * 0.006**1.5)
    np.testing.assert_array_equal(f6[[0, 2]], 0.0)


def test_damping_and_sliding_friction() -> None:
    floor = HuntCrossleyFloor.horizontal(-0.06)
    p = np.array([0.0, -0.065, 0.1])
    sinking = floor.force_on_environment(p, np.array([0.0, -0.05, 0.0]))
    rising = floor.force_on_environment(p, np.array([0.0, 0.05, 0.0]))
    assert -sinking[1] > -rising[1] > 0.0
    sliding = floor.force_on_environment(p, np.array([0.1, 0.0, 0.0]))
    normal = -sliding[1]
    # Coulomb: the tip drags the floor along its motion with mu f_n (speed >> v_eps)
    assert sliding[0] == pytest.approx(floor.sliding_friction * normal, rel=2e-3)
    faster = floor.force_on_environment(p, np.array([0.3, 0.0, 0.0]))
    assert faster[0] == pytest.approx(sliding[0], rel=2e-3)  # not viscous
    np.testing.assert_allclose(floor.signed_distance_m(np.array([[0, -0.05, 0]])), [0.01])


def test_invalid_floor() -> None:
    with pytest.raises(ConfigurationError):
        HuntCrossleyFloor(normal_in_base=(0.0, 0.0, 0.0))
    with pytest.raises(ConfigurationError):
        HuntCrossleyFloor(exponent=5.0)
    with pytest.raises(ConfigurationError):
        HuntCrossleyFloor(stiffness_n_per_m_e=-1.0)
