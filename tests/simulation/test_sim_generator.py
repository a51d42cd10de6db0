import math
from collections import Counter

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.robots.device import Device
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from teleop_force.simulation import (
    PlantTwoConfig,
    SimulatedOmni,
    SimulatedOmniTwo,
    rigid_body_protocol,
)
from teleop_force.simulation.generator import (
    DrawnPlant,
    draw_plant,
    family_one_draw,
    family_two_draw,
)
from teleop_force.simulation.generator_spec import (
    CABLE_FORMS,
    CHOICE_SEEDS,
    FRICTION_LAWS,
    MOTION_KINDS,
    SPEC,
    reported_seeds,
)
from teleop_force.simulation.lugre_friction import LuGreFriction, lugre_step

DRAWS = tuple(draw_plant(seed) for seed in range(200))


def _friction(plant: DrawnPlant) -> LuGreFriction:
    assert isinstance(plant.config, PlantTwoConfig) and plant.config.drawn_arm is not None
    return plant.config.drawn_arm.friction


def _element(friction: LuGreFriction, e: int) -> dict[str, float]:
    return {
        "sigma0": friction.bristle_stiffness_nm_per_rad[e],
        "sigma1": friction.bristle_damping_nms_per_rad[e],
        "b": friction.viscous_nms_per_rad[e],
        "fc": friction.coulomb_nm[e],
        "fs": friction.static_nm[e],
        "vs": friction.stribeck_velocity_rad_s[e],
    }


def test_a_draw_is_deterministic_per_seed_and_seeds_differ() -> None:
    again = draw_plant(7)
    assert again.config == DRAWS[7].config
    for name in ("kp_nm_per_rad", "ki_nm_per_rad_s", "kd_nms_per_rad"):
        np.testing.assert_array_equal(
            getattr(again.pid_gains, name), getattr(DRAWS[7].pid_gains, name)
        )
    assert _friction(again) == _friction(DRAWS[7])
    assert again.structure() == DRAWS[7].structure()
    assert _friction(DRAWS[7]) != _friction(DRAWS[8])
    with pytest.raises(ConfigurationError):
        draw_plant(-1)


def test_each_joint_law_is_the_one_the_spec_says() -> None:
    f = SPEC.friction
    base = LuGreFriction()
    for plant in DRAWS:
        friction = _friction(plant)
        for j, law in enumerate(plant.friction_laws):
            p = _element(friction, j)
            assert f.coulomb_scale.contains(p["fc"] / base.coulomb_nm[j])
            assert f.viscous_scale.contains(p["b"] / base.viscous_nms_per_rad[j])
            if law in ("coulomb-viscous", "stribeck"):
                assert p["sigma0"] == f.stiff_bristle_nm_per_rad
            else:
                assert f.soft_bristle_nm_per_rad.contains(p["sigma0"])
            if law in ("stribeck", "lugre"):
                assert f.static_ratio.contains(p["fs"] / p["fc"]) and p["fs"] > p["fc"]
                assert f.stribeck_velocity_rad_s.contains(p["vs"])
            else:
                assert p["fs"] == p["fc"]
            if law == "lugre":
                assert f.soft_damping_nms_per_rad.contains(p["sigma1"])
            if law == "dahl":
                assert p["sigma1"] == 0.0


def test_each_cable_form_is_the_one_the_spec_says() -> None:
    c = SPEC.cable
    for plant in DRAWS:
        friction = _friction(plant)
        p = _element(friction, 3)
        assert c.pulley_ratio.contains(friction.pulley_ratio)
        if plant.cable_form == "none":
            assert p["fc"] == p["fs"] == c.absent_level_nm and p["b"] == 0.0
            continue
        assert c.coulomb_nm.contains(p["fc"]) and c.static_ratio.contains(p["fs"] / p["fc"])
        if plant.cable_form == "static":
            assert p["sigma0"] == SPEC.friction.stiff_bristle_nm_per_rad
        else:
            assert c.soft_bristle_nm_per_rad.contains(p["sigma0"])


def test_every_choice_is_drawn_about_uniformly() -> None:
    laws = Counter(law for plant in DRAWS for law in plant.friction_laws)
    forms = Counter(plant.cable_form for plant in DRAWS)
    # 600 joints, p = 1/4: mean 150, sd 10.6; 200 cables, p = 1/3: mean 67, sd 6.7
    assert set(laws) == set(FRICTION_LAWS) and all(105 < n < 195 for n in laws.values())
    assert set(forms) == set(CABLE_FORMS) and all(40 < n < 94 for n in forms.values())
    for plant in DRAWS:
        assert plant.identification_motion != plant.test_motion
        assert {plant.identification_motion, plant.test_motion} <= set(MOTION_KINDS)


def test_coulomb_viscous_law_slides_as_coulomb_plus_viscous() -> None:
    plant = next(p for p in DRAWS if p.friction_laws[0] == "coulomb-viscous")
    friction = _friction(plant)
    p = _element(friction, 0)
    for v in (-0.3, -0.01, 0.02, 0.5):
        torque = friction.steady_state_torque(np.array([v, 0.0, 0.0]))[0]
        assert torque == pytest.approx(p["fc"] * math.copysign(1.0, v) + p["b"] * v, rel=1e-12)


def _presliding_force(friction: LuGreFriction, joint: int, travel_rad: float) -> float:
    """Force after moving ``travel_rad`` slowly from a relaxed bristle (joint 1 or 3)."""
    z = np.zeros(4)
    h, steps = 1e-4, 100
    v = travel_rad / (h * steps)
    force = 0.0
    for _ in range(steps):
        velocity = [0.0, 0.0, 0.0]
        velocity[joint] = v
        out = lugre_step(np.array(friction.kernel_parameters), z, *velocity, h)
        force = out[joint] - _element(friction, joint)["b"] * v
    return force


def test_dahl_law_has_a_pre_sliding_spring_and_static_laws_do_not() -> None:
    travel = 2e-5  # rad: far below breakaway for a soft bristle (Fc / sigma0 > 1e-4)
    soft = next(p for p in DRAWS if p.friction_laws[0] == "dahl")
    stiff = next(p for p in DRAWS if p.friction_laws[0] == "coulomb-viscous")
    dahl = _element(_friction(soft), 0)
    # Dahl: F = Fc (1 - exp(-sigma0 x / Fc)) from rest
    expected = dahl["fc"] * (1.0 - math.exp(-dahl["sigma0"] * travel / dahl["fc"]))
    assert _presliding_force(_friction(soft), 0, travel) == pytest.approx(expected, rel=0.02)
    assert expected < 0.2 * dahl["fc"]
    # A stiff bristle is at its sliding level within 0.4 of the finest encoder count.
    cv = _element(_friction(stiff), 0)
    assert _presliding_force(_friction(stiff), 0, 1e-4) > 0.99 * cv["fc"]


def test_masses_and_spring_within_thirty_percent() -> None:
    masses = omni_description().link_parameters()[0::10]
    for plant in DRAWS[:3]:
        description, _, stiffness = plant.config.arm()  # type: ignore[union-attr]
        ratio = description.link_parameters()[0::10] / masses
        assert np.all((ratio >= 0.7) & (ratio <= 1.3)) and not np.allclose(ratio, 1.0)
        assert 0.7 <= stiffness / SPRING_STIFFNESS_NM_PER_RAD <= 1.3


def test_a_drawn_plant_is_a_device_and_runs_its_sessions() -> None:
    plant = DRAWS[1]
    device = plant.make_device(seed=0)
    assert isinstance(device, Device) and isinstance(device, SimulatedOmniTwo)
    with device:
        device.command_torque(np.zeros(3))
        device.step()
        assert device.read().q_rad.shape == (3,)
    session = plant.session("multi-sine", 1.0, 1, effects=(plant.effect(),))
    assert np.isfinite(session.q_true_rad).all() and session.tracking_rms_rad().max() < 0.01
    assert plant.effect().name == plant.planted_effect


def test_the_fixed_families_are_draws() -> None:
    assert isinstance(family_one_draw().make_device(seed=0), SimulatedOmni)
    ours = family_two_draw(3).session("multi-sine", 0.5, 3)
    theirs = rigid_body_protocol(0.5, 3, family="two")
    np.testing.assert_array_equal(ours.q_rad, theirs.q_rad)
    np.testing.assert_array_equal(ours.tau_nm, theirs.tau_nm)


def test_reported_seeds_follow_the_rule() -> None:
    commit = "fb917da" + "0" * 33
    seeds = reported_seeds(commit)
    assert seeds == reported_seeds(commit) and len(set(seeds)) == 20
    assert all(1000 <= s < 1_000_000 for s in seeds) and not set(seeds) & set(CHOICE_SEEDS)
    assert reported_seeds("1" + commit[1:]) != seeds
    for bad in ("fb917da", commit.upper(), commit + "0"):
        with pytest.raises(ConfigurationError):
            reported_seeds(bad)
