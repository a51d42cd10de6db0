"""The standstill dead band: at rest under load the Coulomb sign makes no phantom force."""

import math

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import with_estimator
from teleop_force.estimation.kernels import ModelTerms
from teleop_force.friction.coulomb_viscous import CoulombViscous
from teleop_force.friction.terms import standstill_factor, standstill_factors, standstill_scale_into
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.description import Robot
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description

#: Coulomb and viscous coefficients per joint ``[a_c1, a_v1, ...]``.
FRICTION = np.array([0.02, 0.002, 0.025, 0.003, 0.015, 0.002])


def _model(effects=(), **choice) -> DynamicModel:
    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    config = FilterConfig(**choice)
    friction = CoulombViscous(3, FRICTION)
    return DynamicModel(
        "omni", 3, config, base, beta, 0 * beta, friction, np.zeros(3), tuple(effects)
    )


#: A low-speed friction the residual loop finds (a Stribeck shape times ``sgn(qd2)``), largest
#: at rest.
STRIBECK_ON_JOINT_2 = FoundEffect(
    BasisSpec(1, "qd2", "stribeck", "sign", scales=(0.03, 0.1)), np.array([0.01, 0.005])
)


def test_factor_ramps_only_when_every_joint_is_slow() -> None:
    assert standstill_factor(np.array([0.001, -0.004, 0.0]), 0.0) == 1.0  # no band
    assert standstill_factor(np.array([0.001, -0.004, 0.0]), 0.01) == pytest.approx(0.4)
    assert standstill_factor(np.array([0.001, -0.02, 0.0]), 0.01) == 1.0  # one joint moves
    assert standstill_factor(np.array([0.0, 0.0, 0.0]), 0.01) == 0.0
    assert standstill_factor(np.array([0.0, math.nan, 0.0]), 0.01) == 1.0  # NaN stays NaN
    torque = np.array([0.02, -0.03, 0.01])
    standstill_scale_into(np.array([0.005, 0.0, 0.0]), 0.01, torque)
    np.testing.assert_allclose(torque, [0.01, -0.015, 0.005])
    qd = np.array([[0.005, 0.0, 0.0], [0.02, 0.0, 0.0]])
    np.testing.assert_allclose(standstill_factors(qd, 0.01), [0.5, 1.0])


def test_band_scales_friction_not_offsets() -> None:
    model = _model(standstill_band_rad_s=0.01)
    model = DynamicModel(
        "omni", 3, model.filter_config, model.base, model.base_values, model.base_std,
        model.friction, np.array([0.1, 0.2, 0.3]),
    )  # fmt: skip
    qd = [0.002, -0.001, 0.0]
    other, _ = ModelTerms(model)(0.0, [0.1, 0.2, 0.3], qd, [0.0, 0.0, 0.0])
    expected = 0.2 * model.friction.torque(np.array([qd]))[0] + model.offsets_nm
    np.testing.assert_allclose(other, expected, rtol=1e-12)


@pytest.mark.parametrize(
    ("modulation", "coefficients", "ramped"),
    [("sign", [0.01], [0.01]), ("positive", [0.01], [0.01]), ("none", [0.01], []),
     ("both", [0.01, 0.004], [0.004])],
)  # fmt: skip
def test_band_scales_the_direction_part_of_found_effects(modulation, coefficients, ramped) -> None:
    """Found friction (an effect times ``sgn(qd)`` or ``[qd > 0]``) ramps as the friction does;
    an effect of the pose alone, and the plain part of ``both``, do not."""
    effect = FoundEffect(BasisSpec(1, "q2", "linear", modulation), np.asarray(coefficients))
    q, qd_fast, qd_slow = [0.1, 0.5, 0.3], [0.0, 0.05, 0.0], [0.0, 0.002, 0.0]
    for band in (0.0, 0.01):
        model = _model(effects=[effect], standstill_band_rad_s=band)
        terms = ModelTerms(model)
        fast, _ = terms(0.0, q, qd_fast, [0.0, 0.0, 0.0])
        slow, _ = terms(0.0, q, qd_slow, [0.0, 0.0, 0.0])
        friction_fast = model.friction.torque(np.array([qd_fast]))[0]
        friction_slow = model.friction.torque(np.array([qd_slow]))[0]
        whole = effect.torque(np.zeros(1), np.array([q]), np.array([qd_fast]), np.zeros((1, 3)))
        np.testing.assert_allclose(fast, friction_fast + whole[0], rtol=1e-12)
        factor = 0.2 if band > 0 else 1.0  # 0.002 of 0.01
        direction = 0.5 * sum(ramped)  # q2 = 0.5, qd2 > 0
        expected_effect = whole[0][1] - (1.0 - factor) * direction
        np.testing.assert_allclose(slow[1], factor * friction_slow[1] + expected_effect, rtol=1e-12)


def _pressing_at_rest(n: int = 3000):
    """The arm held still (a dither far under the band) while the tip presses with ``F``."""
    model = _model()
    robot = Robot(model.description())
    t = np.arange(n) * 1e-3
    q0 = np.array([0.1, 0.7, 0.3])
    q = q0 + 2e-5 * np.sin(2 * math.pi * 3.0 * t)[:, None] * np.array([1.0, -1.0, 0.5])
    force = np.array([0.3, -1.2, 0.5])
    jacobian = robot.tip_jacobian_in_base(q0)
    holding = robot.gravity_torque(q0) + robot.spring_torque(q0, [SPRING_STIFFNESS_NM_PER_RAD])
    tau = np.tile(holding + jacobian.T @ force, (n, 1))  # static friction holds: no friction
    return t, q, tau, force


@pytest.mark.parametrize("estimator", ["filter", "observer"])
def test_band_removes_the_phantom_force_at_rest(estimator) -> None:
    t, q, tau, force = _pressing_at_rest()
    valid = t >= 0.5
    errors = {}
    for band in (0.0, 0.01):
        model = _model(estimator=estimator, standstill_band_rad_s=band)
        result = BatchEstimator(model).estimate(t, q, tau)
        assert (np.abs(result.tau_motor_filtered_nm[valid]) > 0).all()
        error = result.force_tip_in_base_n[valid] - force
        errors[band] = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    assert errors[0.0] > 0.05  # the Coulomb sign flips with the dither: a phantom force
    assert errors[0.01] < 0.1 * errors[0.0]


@pytest.mark.parametrize("estimator", ["filter", "observer"])
def test_band_removes_the_phantom_force_of_found_friction_at_rest(estimator) -> None:
    """A found low-speed friction (largest at rest, times a sign the dither flips) makes no
    phantom force at rest under load either: the band ramps it as it ramps the friction."""
    t, q, tau, force = _pressing_at_rest()
    valid = t >= 0.5
    errors = {}
    for band in (0.0, 0.01):
        model = _model(
            effects=[STRIBECK_ON_JOINT_2], estimator=estimator, standstill_band_rad_s=band
        )
        result = BatchEstimator(model).estimate(t, q, tau)
        error = result.force_tip_in_base_n[valid] - force
        errors[band] = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    assert errors[0.0] > 0.05
    assert errors[0.01] < 0.1 * errors[0.0]


def test_band_is_checked_and_overridden() -> None:
    with pytest.raises(ConfigurationError, match="standstill_band_rad_s"):
        FilterConfig(standstill_band_rad_s=-0.1)
    with pytest.raises(ConfigurationError, match="standstill_band_rad_s"):
        FilterConfig(standstill_band_rad_s=math.inf)
    model = _model()
    model = with_estimator(model, standstill_band_rad_s=0.0)
    banded = with_estimator(model, standstill_band_rad_s=0.05)
    assert banded.filter_config.standstill_band_rad_s == 0.05
    assert model.filter_config.standstill_band_rad_s == 0.0
    assert ModelTerms(banded).standstill_band_rad_s == 0.05
    assert with_estimator(banded, standstill_band_rad_s=0.05) is banded
