import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.robots.omni import omni_description
from teleop_force.simulation import (
    HuntCrossleyFloor,
    PlaneContact,
    PlantConfig,
    PlantFamily,
    PlantTwoConfig,
    SimulatedOmni,
    SimulatedOmniTwo,
    floor_touch_protocol,
    make_effect,
    make_plant,
    palpation_protocol,
    rigid_body_protocol,
    teleoperation_protocol,
    with_tip_payload,
)
from teleop_force.simulation.lugre_friction import LuGreFriction


def _link_parameters(plant: SimulatedOmniTwo) -> np.ndarray:
    return plant.description.link_parameters()


def test_family_enum_and_factory() -> None:
    assert PlantFamily("two") is PlantFamily.TWO and PlantFamily.ONE == "one"
    assert isinstance(make_plant(PlantFamily.ONE, seed=0), SimulatedOmni)
    two = make_plant("two", seed=3)
    assert isinstance(two, SimulatedOmniTwo) and two.config.instance_seed == 3
    with pytest.raises(ConfigurationError):
        make_plant("three", seed=0)
    with pytest.raises(ConfigurationError):
        make_plant("one", seed=0, config=PlantTwoConfig())
    with pytest.raises(ConfigurationError):
        make_plant("one", seed=0, contact=HuntCrossleyFloor())
    with pytest.raises(ConfigurationError):
        make_plant("two", seed=0, config=PlantConfig())


def test_family_two_masses_differ_from_family_one_within_twenty_percent() -> None:
    omni = omni_description().link_parameters()
    masses = omni[0::10]
    seen = []
    for seed in (1, 2):
        plant = make_plant("two", seed=seed)
        assert isinstance(plant, SimulatedOmniTwo)
        params = _link_parameters(plant)
        ratio = params[0::10] / masses
        assert np.all((ratio >= 0.8) & (ratio <= 1.2)) and not np.allclose(ratio, 1.0)
        seen.append(params)
    assert not np.allclose(seen[0], seen[1])  # another seed, another arm
    again = make_plant("two", seed=1)
    assert isinstance(again, SimulatedOmniTwo)
    np.testing.assert_array_equal(_link_parameters(again), seen[0])


def test_family_two_sessions_are_deterministic_per_seed() -> None:
    a = teleoperation_protocol(0.4, 6, family="two")
    b = teleoperation_protocol(0.4, 6, family=PlantFamily.TWO)
    c = teleoperation_protocol(0.4, 7, family="two")
    assert a.family == "two" and isinstance(a.friction, LuGreFriction)
    for name in ("q_rad", "tau_nm", "q_true_rad", "tau_applied_nm", "tau_friction_true_nm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.tau_nm, c.tau_nm)
    # same arm, other session seed: other noise
    d = teleoperation_protocol(0.4, 7, family="two", plant_config=PlantTwoConfig(instance_seed=6))
    assert not np.array_equal(a.tau_applied_nm, d.tau_applied_nm)
    assert np.any(a.tau_friction_true_nm != 0.0)


def test_family_two_sensors_differ_from_family_one() -> None:
    session = rigid_body_protocol(0.3, 2, family="two")
    resolution = np.array(PlantTwoConfig().encoder_resolution_rad)
    counts = session.q_rad / resolution
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(session.q_rad <= session.q_true_rad + 1e-12)  # floored, not rounded
    noise = session.tau_applied_nm - session.tau_nm
    # coloured: successive noise samples are correlated (family one's are white)
    lag_one = np.corrcoef(noise[1:, 0], noise[:-1, 0])[0, 1]
    assert lag_one > 0.5


def test_family_one_is_unchanged_by_default() -> None:
    a = teleoperation_protocol(0.3, 4)
    b = teleoperation_protocol(0.3, 4, family=PlantFamily.ONE)
    assert a.family == "one" and a.tip_mass_kg == 0.0
    for name in ("q_rad", "tau_nm", "tau_applied_nm", "tau_friction_true_nm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("family", ["one", "two"])
def test_effects_switch_on(family: str) -> None:
    effect = make_effect("cogging", strength=0.05)
    clean = rigid_body_protocol(0.5, 1, family=family)
    planted = rigid_body_protocol(0.5, 1, family=family, effects=[effect])
    assert np.any(planted.tau_effects_true_nm[:, 0] != 0.0)
    np.testing.assert_array_equal(clean.tau_effects_true_nm, 0.0)
    np.testing.assert_allclose(
        planted.tau_effects_true_nm[:, 0],
        effect.joint_torque(planted.t_s, planted.q_true_rad, planted.qd_true_rad_s,
                            planted.tau_applied_nm),
    )  # fmt: skip
    assert not np.allclose(clean.tau_nm, planted.tau_nm, atol=1e-3)


@pytest.mark.parametrize("family", ["one", "two"])
def test_tip_payload_loads_the_arm(family: str) -> None:
    light = make_plant(family, seed=1, q0_rad=np.array([0.0, 0.5, 0.0]))
    heavy = make_plant(family, seed=1, tip_mass_kg=0.05, q0_rad=np.array([0.0, 0.5, 0.0]))
    assert isinstance(light, SimulatedOmni | SimulatedOmniTwo)
    assert isinstance(heavy, SimulatedOmni | SimulatedOmniTwo)
    extra = heavy.holding_torque_nm() - light.holding_torque_nm()
    # 0.05 kg at the tip: about 0.05 * 9.81 * lever on joints 2 and 3
    assert 0.02 < abs(extra[1]) < 0.08 and abs(extra[0]) < 1e-12
    session = teleoperation_protocol(0.2, 1, family=family, tip_mass_kg=0.05)
    assert session.tip_mass_kg == pytest.approx(0.05)
    with pytest.raises(ConfigurationError):
        with_tip_payload(omni_description(), -1.0)


@pytest.mark.parametrize("family", ["one", "two"])
def test_floor_touch_and_palpation_touch_the_family_surface(family: str) -> None:
    session = floor_touch_protocol(12.0, 2, family=family)
    expected = PlaneContact if family == "one" else HuntCrossleyFloor
    assert isinstance(session.contact, expected)
    in_contact = np.linalg.norm(session.f_tip_in_base_n, axis=1) > 0.0
    assert not in_contact[:1500].any() and in_contact.any()
    assert np.all(session.f_tip_in_base_n[in_contact, 1] < 0.5)  # pushing down, mostly
    palpation = palpation_protocol(3.5, 0, family=family)
    assert isinstance(palpation.contact, expected)
    assert np.any(palpation.f_tip_in_base_n != 0.0)


def test_family_two_runs_effects_it_cannot_compile() -> None:
    from dataclasses import dataclass

    from teleop_force.simulation.effects import Cogging

    @dataclass(frozen=True)
    class MyCogging(Cogging):  # a subclass: evaluated in Python, once per tick
        pass

    def one_tick(effects: list[Cogging]) -> np.ndarray:
        plant = make_plant("two", seed=2, effects=effects)
        assert isinstance(plant, SimulatedOmniTwo)
        plant.set_state(np.array([0.1, 0.8, 0.3]), np.array([0.5, -0.3, 0.2]))
        for _ in range(5):
            plant.command_torque(plant.holding_torque_nm())
            plant.step()
        return plant.qd_true_rad_s

    clean = one_tick([])
    compiled = one_tick([Cogging(0, 0.05)])
    python = one_tick([MyCogging(0, 0.05)])
    change = np.abs(compiled - clean)[0]
    assert change > 1e-3
    # per tick instead of per sub-step: the same effect, up to the hold
    assert abs(python[0] - compiled[0]) < 0.05 * change
    plant = make_plant("two", seed=0)
    with pytest.raises(ConfigurationError):
        plant.effects = [make_effect("cogging", joint=3)]  # type: ignore[attr-defined]
