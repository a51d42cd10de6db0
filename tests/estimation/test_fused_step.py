"""The one-call compiled step against the two halves around pinocchio it replaces."""

import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.packed_tables import HEADER_WIDTH, pack
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from tests.estimation.network_cases import CV_PARAMETERS, random_network

EFFECTS = (
    FoundEffect(BasisSpec(0, "q1", "constant", "sign"), np.array([0.004])),
    FoundEffect(BasisSpec(1, "tau2", "linear", "positive"), np.array([0.05])),
    FoundEffect(BasisSpec(1, "t", "linear"), np.array([1e-3])),
)


def _model(friction: str, effects: bool = False, **config) -> DynamicModel:
    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    model_friction = {
        "cv": lambda: CoulombViscous(3, CV_PARAMETERS[[0, 1, 2, 3, 6, 7]]),
        "coupled-cv": lambda: CoupledCoulombViscous(3, description.friction_inputs, CV_PARAMETERS),
        "wn": lambda: random_network(0, 60, 0.15),
    }[friction]()
    return DynamicModel(
        "omni", 3, FilterConfig(**config), base, beta, 0 * beta, model_friction, np.zeros(3),
        EFFECTS if effects else (),
    )  # fmt: skip


def _motion(n: int = 1200, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.9e-3, 1.1e-3, n))
    q = np.column_stack(
        [0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)]
    )
    q = np.round(q / 4e-4) * 4e-4
    tau = np.column_stack([0.05 * np.sin(5 * t), 0.2 + 0.05 * np.cos(t), 0.01 * np.sin(7 * t)])
    return t, q, tau


@pytest.mark.parametrize(
    ("friction", "effects", "config"),
    [
        ("cv", False, {}),
        ("coupled-cv", True, {"torque_lag_samples": 0}),
        ("wn", True, {}),
        ("wn", False, {"estimator": "observer", "observer_hz": 25.0}),
        ("coupled-cv", False, {"standstill_band_rad_s": 0.05}),
        ("cv", True, {"sticking_rad": 0.002}),
        ("wn", False, {"sticking_rad": 0.002, "standstill_band_rad_s": 0.05}),
    ],
)
def test_the_fused_step_equals_the_two_halves(friction, effects, config) -> None:
    config = dict(config)
    sticking = config.pop("sticking_rad", 0.0)
    model = _model(friction, effects, **config)
    if sticking:  # the Coulomb terms' sticking state (a network's fallback's)
        table = getattr(model.friction, "fallback", None) or model.friction
        table.set_sticking(sticking)
    fused, halves = ForceEstimator(model), ForceEstimator(model, fused=False)
    assert fused.fused and not halves.fused
    t, q, tau = _motion()
    for k in range(t.size):
        a = fused.step(t[k], tuple(q[k]), tuple(tau[k]))
        b = halves.step(t[k], q[k], tau[k])
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_the_fused_step_follows_new_network_coefficients() -> None:
    model = _model("wn")
    network = model.friction
    fused, halves = ForceEstimator(model), ForceEstimator(model, fused=False)
    t, q, tau = _motion(600)
    for k in range(t.size):
        if k == 300:  # what online adaptation does: coefficients changed in place
            indices = network.active_indices(1) + int(network.pool.joint_offsets[1])
            assert indices.size > 0
            network.set_coefficients_at(indices, network.coefficients_at(indices) * 3.0 + 1e-3)
        np.testing.assert_allclose(
            fused.step(t[k], q[k], tau[k]), halves.step(t[k], q[k], tau[k]), rtol=0, atol=1e-12
        )


def test_a_bad_sample_leaves_the_fused_state_untouched() -> None:
    estimator = ForceEstimator(_model("coupled-cv"))
    t, q, tau = _motion(20)
    for k in range(10):
        estimator.step(t[k], q[k], tau[k])
    estimator.step(t[10], q[10], tau[10])
    estimator2 = ForceEstimator(_model("coupled-cv"))
    for k in range(11):
        estimator2.step(t[k], q[k], tau[k])
    with pytest.raises(DataError, match="does not increase"):
        estimator.step(t[5], q[11], tau[11])
    with pytest.raises(DataError, match="non-finite"):
        estimator.step(t[11], (np.nan, 0.0, 0.0), tau[11])
    with pytest.raises(DataError, match="3 joint angles"):
        estimator.step(t[11], q[11][:2], tau[11])
    np.testing.assert_allclose(
        estimator.step(t[11], q[11], tau[11]), estimator2.step(t[11], q[11], tau[11]), atol=0
    )


def test_pack_records_offsets_and_shapes() -> None:
    floats, ints = pack([np.arange(6.0).reshape(2, 3), np.ones(4)], [np.arange(3)])
    header = ints[: 3 * HEADER_WIDTH].reshape(3, HEADER_WIDTH)
    np.testing.assert_array_equal(header[0], [0, 2, 3, 1])
    np.testing.assert_array_equal(header[1], [6, 4, 1, 1])
    np.testing.assert_array_equal(header[2], [3 * HEADER_WIDTH, 3, 1, 1])
    np.testing.assert_array_equal(floats[:6], np.arange(6.0))
    np.testing.assert_array_equal(ints[3 * HEADER_WIDTH :], [0, 1, 2])
