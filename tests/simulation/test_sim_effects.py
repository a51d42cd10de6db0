import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.simulation.effects import (
    EFFECT_NAMES,
    Cogging,
    ElbowAngleBump,
    LoadDependentFriction,
    PlantEffect,
    make_effect,
    total_effect_torque,
)
from teleop_force.simulation.session import rigid_body_protocol

Q = np.array([0.2, 1.2, 0.5])
QD = np.array([0.4, -0.3, 0.5])
TAU = np.array([0.1, -0.2, 0.15])


def test_registry_builds_every_effect() -> None:
    assert set(EFFECT_NAMES) == {
        "cogging",
        "position-friction",
        "drifting-friction",
        "load-friction",
        "elbow-bump",
        "direction-offset",
        "cross-direction-offset",
    }
    for name in EFFECT_NAMES:
        effect = make_effect(name)
        assert isinstance(effect, PlantEffect) and effect.name == name
        torque = effect.torque(100.0, Q, QD, TAU)
        assert torque.shape == (3,)
        assert torque[effect.joint] != 0.0
        assert np.count_nonzero(torque) == 1
        assert name in effect.describe()
    assert make_effect("cogging", joint=2, strength=0.05).torque(0.0, Q, QD, TAU)[2] != 0.0


def test_unknown_or_invalid_effects_are_refused() -> None:
    with pytest.raises(ConfigurationError):
        make_effect("gremlins")
    with pytest.raises(ConfigurationError):
        make_effect("cogging", joint=-1)
    with pytest.raises(ConfigurationError):
        Cogging(joint=0, wavenumber_per_rad=0.0)
    with pytest.raises(ConfigurationError):
        ElbowAngleBump(joint=2, first=1, second=1)
    with pytest.raises(ConfigurationError):
        make_effect("cogging", joint=5).torque(0.0, Q, QD, TAU)
    with pytest.raises(DataError):
        make_effect("cogging").torque(0.0, Q, QD[:2], TAU)


def test_batch_matches_single_samples() -> None:
    rng = np.random.default_rng(2)
    t = rng.uniform(0.0, 200.0, 50)
    q = rng.uniform(-0.5, 1.2, (50, 3))
    qd = rng.normal(0.0, 0.5, (50, 3))
    tau = rng.normal(0.0, 0.2, (50, 3))
    for name in EFFECT_NAMES:
        effect = make_effect(name)
        batch = effect.torque(t, q, qd, tau)
        single = np.array([effect.torque(t[k], q[k], qd[k], tau[k]) for k in range(50)])
        np.testing.assert_allclose(batch, single)


def test_velocity_slopes_match_finite_differences() -> None:
    h = 1e-7
    for name in EFFECT_NAMES:
        effect = make_effect(name)
        j = effect.joint
        step = h * np.eye(3)[j]
        numeric = (
            effect.joint_torque(50.0, Q, QD + step, TAU)
            - effect.joint_torque(50.0, Q, QD - step, TAU)
        ) / (2 * h)
        assert effect.velocity_slope(50.0, Q, QD, TAU) == pytest.approx(numeric, rel=1e-5, abs=1e-9)


def test_shapes_of_specific_effects() -> None:
    load = LoadDependentFriction(joint=1, coefficient=0.2)
    assert load.torque(0.0, Q, QD, TAU)[1] == pytest.approx(-0.2 * 0.2, rel=1e-6)
    drift = make_effect("drifting-friction", joint=0, strength=1e-4)
    assert drift.torque(200.0, Q, QD, TAU)[0] == pytest.approx(
        2.0 * drift.torque(100.0, Q, QD, TAU)[0]
    )
    offset = make_effect("direction-offset", joint=2, strength=0.01)
    assert offset.torque(0.0, Q, QD, TAU)[2] == pytest.approx(0.01)
    assert offset.torque(0.0, Q, -QD, TAU)[2] == pytest.approx(0.0, abs=1e-12)
    cross = make_effect("cross-direction-offset")  # joint 3, switched by joint 1's direction
    assert cross.joint == 2 and cross.switching_joint == 0
    only_joint_1 = np.array([QD[0], -QD[1], -QD[2]])
    assert cross.torque(0.0, Q, only_joint_1, TAU)[2] == pytest.approx(0.01)
    assert cross.torque(0.0, Q, -only_joint_1, TAU)[2] == pytest.approx(0.0, abs=1e-12)
    assert cross.velocity_slope(0.0, Q, QD, TAU) == 0.0  # not a function of its own velocity
    with pytest.raises(ConfigurationError, match="direction_joint"):
        make_effect("direction-offset").__class__(joint=2, direction_joint=-1)
    bump = ElbowAngleBump(joint=2)
    far = np.array([0.0, 0.0, 1.2])  # q2 - q3 far from the bump
    assert abs(bump.torque(0.0, far, QD, TAU)[2]) < 1e-9
    assert total_effect_torque((), 0.0, Q, QD, TAU).tolist() == [0.0, 0.0, 0.0]


def test_effects_switch_on_and_off_in_a_session() -> None:
    effect = make_effect("cogging", joint=0, strength=0.02)
    off = rigid_body_protocol(duration_s=1.0, seed=3)
    on = rigid_body_protocol(duration_s=1.0, seed=3, effects=(effect,))
    np.testing.assert_array_equal(off.tau_effects_true_nm, 0.0)
    assert on.effects == (effect,)
    assert np.max(np.abs(on.tau_effects_true_nm[:, 0])) > 0.015
    np.testing.assert_array_equal(on.tau_effects_true_nm[:, 1:], 0.0)
    # The PID now has to supply the cogging torque on joint 1.
    assert np.sqrt(np.mean((on.tau_nm[:, 0] - off.tau_nm[:, 0]) ** 2)) > 5e-3
    expected = total_effect_torque(
        (effect,), on.t_s, on.q_true_rad, on.qd_true_rad_s, on.tau_applied_nm
    )
    np.testing.assert_allclose(on.tau_effects_true_nm, expected)


def test_stiff_friction_like_effects_integrate_stably() -> None:
    effects = (
        make_effect("load-friction", joint=1, strength=0.2),
        make_effect("position-friction", joint=2, strength=0.03),
        make_effect("direction-offset", joint=0, strength=0.02),
    )
    session = rigid_body_protocol(duration_s=1.5, seed=1, effects=effects)
    assert np.all(np.isfinite(session.q_true_rad))
    assert np.all(session.tracking_rms_rad(skip_s=0.5) < 0.01)
