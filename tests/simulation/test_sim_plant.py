import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots import omni
from teleop_force.robots.device import DeviceClosedError
from teleop_force.simulation.plant import PlantConfig, SimulatedOmni

Q_MID = np.array([0.2, 0.8, 0.3])


def _energy_over(plant: SimulatedOmni, ticks: int) -> np.ndarray:
    energies = []
    for _ in range(ticks):
        plant.command_torque(np.zeros(3))
        plant.step()
        energies.append(plant.mechanical_energy_j().sum())
    return np.array(energies)


def test_fast_rigid_body_terms_match_robot() -> None:
    plant = SimulatedOmni()
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = rng.uniform(omni.Q_MIN_RAD, omni.Q_MAX_RAD)
        qd = rng.normal(0.0, 2.0, 3)
        mass, bias, jac, p = plant._terms.evaluate(q, qd)
        robot = plant.robot
        np.testing.assert_allclose(mass, robot.mass_matrix(q), atol=1e-15)
        np.testing.assert_allclose(bias, robot.bias_torque(q, qd), atol=1e-14)
        np.testing.assert_allclose(jac, robot.tip_jacobian_in_base(q), atol=1e-14)
        np.testing.assert_allclose(p, robot.tip_position_in_base(q), atol=1e-14)


def test_energy_is_conserved_without_torque_friction_gravity() -> None:
    config = PlantConfig(gravity=False, spring_stiffness_nm_per_rad=0.0).ideal()
    plant = SimulatedOmni(config, q0_rad=Q_MID, qd0_rad_s=np.array([2.0, -1.5, 3.0]))
    e0 = plant.mechanical_energy_j().sum()
    energies = _energy_over(plant, 1000)
    assert np.max(np.abs(energies - e0)) < 5e-3 * e0


def test_energy_is_conserved_with_gravity_and_spring() -> None:
    plant = SimulatedOmni(PlantConfig().ideal(), q0_rad=Q_MID, qd0_rad_s=np.array([2.0, -1.5, 3.0]))
    e0 = plant.mechanical_energy_j()
    energies = _energy_over(plant, 1000)
    assert np.max(np.abs(energies - e0.sum())) < 5e-3 * e0[0]  # vs the kinetic energy


def test_friction_dissipates() -> None:
    config = PlantConfig(gravity=False, torque_noise_std_nm=0.0)
    plant = SimulatedOmni(config, q0_rad=Q_MID, qd0_rad_s=np.array([2.0, -1.5, 3.0]))
    e0 = plant.mechanical_energy_j().sum()
    energies = _energy_over(plant, 1000)
    assert np.all(np.diff(energies) <= 1e-12)
    assert energies[-1] < 0.2 * e0
    np.testing.assert_allclose(plant.qd_true_rad_s, 0.0, atol=0.02)  # friction stopped it


def test_measured_angles_are_quantized() -> None:
    plant = SimulatedOmni(q0_rad=Q_MID, qd0_rad_s=np.array([0.5, 0.3, -0.4]))
    resolution = omni.ENCODER_RESOLUTION_RAD
    readings = []
    for _ in range(300):
        readings.append(plant.read().q_rad)
        plant.command_torque(plant.holding_torque_nm())
        plant.step()
    q = np.array(readings)
    counts = q / resolution
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    steps = np.abs(np.diff(q, axis=0))
    assert np.min(steps[steps > 0]) == pytest.approx(resolution)
    true_q = plant.q_true_rad
    assert np.all(np.abs(plant.measured_q_rad() - true_q) <= resolution / 2 + 1e-15)


def test_holding_torque_keeps_the_ideal_plant_still() -> None:
    plant = SimulatedOmni(PlantConfig().ideal(), q0_rad=Q_MID)
    for _ in range(200):
        plant.command_torque(plant.holding_torque_nm(Q_MID))
        plant.step()
    np.testing.assert_allclose(plant.q_true_rad, Q_MID, atol=1e-9)


def test_spring_pulls_joint_2_to_its_rest_angle() -> None:
    plant = SimulatedOmni(PlantConfig(gravity=False).ideal(), q0_rad=np.array([0.0, 1.0, 0.3]))
    tau = plant.spring_torque_nm()
    assert tau[1] == pytest.approx(omni.SPRING_STIFFNESS_NM_PER_RAD * (1.0 - np.pi / 2))
    for _ in range(50):
        plant.step()
    assert plant.qd_true_rad_s[1] > 0.0  # below the rest angle: pushed up


def test_same_seed_same_run_other_seed_differs() -> None:
    def run(seed: int) -> np.ndarray:
        plant = SimulatedOmni(seed=seed, q0_rad=Q_MID)
        for _ in range(200):
            plant.command_torque(plant.holding_torque_nm())
            plant.step()
        return plant.q_true_rad

    np.testing.assert_array_equal(run(1), run(1))
    assert not np.array_equal(run(1), run(2))


def test_torque_limit_and_noise() -> None:
    plant = SimulatedOmni(q0_rad=Q_MID, seed=4)
    command = plant.command_torque(np.array([1.0, -0.1, -2.0]))
    np.testing.assert_allclose(command.tau_nm, [0.6, -0.1, -0.6])
    np.testing.assert_array_equal(command.clipped, [True, False, True])
    plant.step()
    noise = plant.tau_applied_nm - command.tau_nm
    assert 0.0 < np.max(np.abs(noise)) < 0.02
    np.testing.assert_allclose(plant.read().tau_nm, command.tau_nm)


def test_read_reports_state_and_force() -> None:
    with SimulatedOmni(q0_rad=Q_MID) as plant:
        state = plant.read()
        assert state.t_s == 0.0
        assert state.f_tip_in_base_n is not None
        np.testing.assert_allclose(state.f_tip_in_base_n, 0.0)
        plant.step()
        assert plant.read().t_s == pytest.approx(1e-3)
    with pytest.raises(DeviceClosedError):
        plant.read()


def test_invalid_configuration() -> None:
    with pytest.raises(ConfigurationError):
        PlantConfig(substeps=0)
    with pytest.raises(ConfigurationError):
        PlantConfig(torque_noise_std_nm=-1.0)
    with pytest.raises(DataError):
        SimulatedOmni(q0_rad=np.zeros(2))
