import dataclasses

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.simulation.families import make_plant
from teleop_force.simulation.lugre_friction import LuGreFriction, lugre_step
from teleop_force.simulation.plant_two import PlantTwoConfig, SimulatedOmniTwo

H = 1e-4


def _drive(friction: LuGreFriction, velocities: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run the elements along joint velocity rows; return torques and bristle states."""
    z = np.zeros(4)
    torques, states = [], []
    for v in velocities:
        out = lugre_step(friction.kernel_parameters, z, v[0], v[1], v[2], H)
        torques.append(out[:3])
        states.append(z.copy())
    return np.array(torques), np.array(states)


def test_settles_on_the_stribeck_curve() -> None:
    friction = LuGreFriction()
    for v in ([0.02, 0.05, -0.3], [1.0, -0.4, 0.7], [-0.2, 0.9, 0.1]):
        torques, _ = _drive(friction, np.tile(v, (8000, 1)))
        np.testing.assert_allclose(
            torques[-1], friction.steady_state_torque(np.array(v)), atol=1e-6
        )
    slow = friction.steady_state_torque(np.array([0.03, 0.0, 0.0]))[0]
    fast = friction.steady_state_torque(np.array([0.2, 0.0, 0.0]))[0]
    assert slow > fast  # the Stribeck dip: friction falls as the joint speeds up


def test_presliding_is_a_spring_with_hysteresis_and_dissipates() -> None:
    friction = LuGreFriction()
    t = np.arange(40000) * H  # 4 s, 1 Hz, amplitude 1e-4 rad: below breakaway
    x = 1e-4 * np.sin(2 * np.pi * t)
    v = np.gradient(x, H)
    velocities = np.stack([v, np.zeros_like(v), np.zeros_like(v)], axis=1)
    torques, states = _drive(friction, velocities)
    # sticking: the bristle follows the displacement (a spring of stiffness sigma0)
    sigma0 = friction.bristle_stiffness_nm_per_rad[0]
    assert np.max(np.abs(torques[:, 0])) < friction.static_nm[0]
    np.testing.assert_allclose(torques[20000:, 0], sigma0 * states[20000:, 0], atol=2e-4)
    # work done on the friction over whole cycles is positive (a loop, not a line)
    work = np.sum(torques[20000:, 0] * v[20000:]) * H
    assert work > 0.0


def test_friction_never_creates_energy_in_the_plant() -> None:
    config = dataclasses.replace(
        PlantTwoConfig(instance_seed=4).ideal(), friction=True, gravity=False
    )
    plant = SimulatedOmniTwo(config, q0_rad=np.array([0.1, 0.8, 0.3]))
    plant.set_state(plant.q_true_rad, np.array([1.5, -2.0, 2.5]))
    energies = []
    for _ in range(1500):
        plant.command_torque(np.zeros(3))
        plant.step()
        energies.append(
            plant.kinetic_energy_j() + plant.potential_energy_j() + plant.bristle_energy_j()
        )
    energies_array = np.array(energies)
    assert energies_array[-1] < 0.2 * energies_array[0]
    assert np.max(np.diff(energies_array)) < 1e-6 * energies_array[0]


def test_energy_is_kept_without_friction() -> None:
    plant = make_plant("two", seed=5, config=PlantTwoConfig(instance_seed=5).ideal())
    assert isinstance(plant, SimulatedOmniTwo)
    plant.set_state(np.array([0.1, 0.8, 0.3]), np.array([1.0, -1.0, 1.5]))
    start = plant.kinetic_energy_j() + plant.potential_energy_j()
    for _ in range(1000):
        plant.command_torque(np.zeros(3))
        plant.step()
    end = plant.kinetic_energy_j() + plant.potential_energy_j()
    assert abs(end - start) < 0.01 * start


def test_cable_couples_joints_two_and_three() -> None:
    friction = LuGreFriction()
    torque = friction.steady_state_torque(np.array([0.0, 0.5, 0.0]))
    assert torque[2] < 0.0 and torque[1] > 0.0  # joint 2 moving drags joint 3 through the cable
    assert torque[0] == 0.0
    ratio = friction.pulley_ratio
    equal = friction.steady_state_torque(np.array([0.0, 0.4 * ratio, 0.4]))
    lone = friction.steady_state_torque(np.array([0.0, 0.0, 0.4]))
    assert equal[2] < lone[2]  # no cable slip when qd2 = r qd3


def test_perturbed_and_invalid() -> None:
    base = LuGreFriction()
    other = base.perturbed(np.random.default_rng(1))
    assert other != base
    for a, b in zip(other.coulomb_nm, base.coulomb_nm, strict=True):
        assert 0.8 * b <= a <= 1.2 * b
    assert all(s >= c for s, c in zip(other.static_nm, other.coulomb_nm, strict=True))
    with pytest.raises(ConfigurationError):
        LuGreFriction(static_nm=(0.001, 0.02, 0.02, 0.01))
    with pytest.raises(ConfigurationError):
        LuGreFriction(coulomb_nm=(0.01, 0.01, 0.01))  # type: ignore[arg-type]
