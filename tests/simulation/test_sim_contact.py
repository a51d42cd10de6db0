import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni
from teleop_force.simulation.trajectories import omni_inverse_kinematics


def test_no_force_above_the_surface() -> None:
    tissue = PlaneContact.horizontal(-0.06)
    p = np.array([[0.0, -0.05, 0.12], [0.02, -0.06, 0.1], [0.0, 0.1, 0.1]])
    v = np.array([[0.0, -0.1, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(tissue.force_on_environment(p, v), 0.0)
    assert tissue.signed_distance_m(p[0]) == pytest.approx(0.01)


def test_pressing_down_gives_negative_fy() -> None:
    tissue = PlaneContact.horizontal(-0.06, stiffness_n_per_m=300.0)
    force = tissue.force_on_environment(np.array([0.0, -0.065, 0.12]), np.zeros(3))
    np.testing.assert_allclose(force, [0.0, -1.5, 0.0], atol=1e-12)
    pressing = tissue.force_on_environment(np.array([0.0, -0.065, 0.12]), [0.0, -0.05, 0.0])
    releasing = tissue.force_on_environment(np.array([0.0, -0.065, 0.12]), [0.0, 0.05, 0.0])
    assert pressing[1] < force[1] < releasing[1] <= 0.0  # Hunt-Crossley damping


def test_sliding_drags_the_tissue_along() -> None:
    tissue = PlaneContact.horizontal(-0.06)
    force = tissue.force_on_environment(np.array([0.0, -0.065, 0.12]), [0.05, 0.0, 0.0])
    assert force[1] < 0.0 and force[0] > 0.0  # the tip pushes the tissue the way it slides
    assert force[0] == pytest.approx(tissue.sliding_friction_s_per_m * 1.5 * 0.05)


def test_tilted_plane_force_is_along_its_normal() -> None:
    tissue = PlaneContact.tilted(-0.06, 0.3)
    normal = np.array(tissue.normal_in_base)
    p = np.array(tissue.point_in_base_m) - 0.004 * normal
    force = tissue.force_on_environment(p, np.zeros(3))
    np.testing.assert_allclose(force, -0.004 * tissue.stiffness_n_per_m * normal, atol=1e-12)


def test_validation() -> None:
    with pytest.raises(ConfigurationError):
        PlaneContact(normal_in_base=(0.0, 0.0, 0.0))
    with pytest.raises(ConfigurationError):
        PlaneContact(stiffness_n_per_m=-1.0)
    with pytest.raises(ConfigurationError):
        PlaneContact.tilted(-0.06, 2.0)
    with pytest.raises(DataError):
        PlaneContact().force_on_environment(np.zeros(2), np.zeros(2))


def test_plant_pressing_into_tissue_balances_j_transpose_f() -> None:
    tissue = PlaneContact.horizontal(-0.06)
    q0 = omni_inverse_kinematics(np.array([0.01, -0.063, 0.12]))  # 3 mm deep
    config = PlantConfig(torque_noise_std_nm=0.0, friction=None)
    plant = SimulatedOmni(config, contact=tissue, q0_rad=q0)
    force = plant.read().f_tip_in_base_n
    assert force is not None
    np.testing.assert_allclose(force, [0.0, -0.9, 0.0], atol=1e-9)
    jac = plant.robot.tip_jacobian_in_base(q0)
    hold = plant.holding_torque_nm(q0) + jac.T @ force
    for _ in range(300):
        plant.command_torque(hold)
        plant.step()
    np.testing.assert_allclose(plant.q_true_rad, q0, atol=1e-9)
    # Without the contact term the same torque would not hold it: the tissue carries 0.9 N.
    free = SimulatedOmni(config, q0_rad=q0)
    for _ in range(50):
        free.command_torque(hold)
        free.step()
    assert np.max(np.abs(free.q_true_rad - q0)) > 1e-3
