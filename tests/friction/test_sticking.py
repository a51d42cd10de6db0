"""The Coulomb terms' sticking (Dahl) state: the law, one definition for the batch fit, the
streaming terms and the model file, and what identification makes of it."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import ConfigurationError, ModelError, ModelFileError
from teleop_force.estimation.kernels import ModelTerms
from teleop_force.friction import terms
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.model_file import friction_from_dict
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel, path_friction_torque
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.pipeline import identify_model
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.registry import resolve_robot
from tests.estimation.network_cases import random_network

states = st.floats(-1.0, 1.0)
steps = st.floats(-0.05, 0.05)
inverse_angles = st.floats(1.0, 1e4)


@settings(max_examples=200, deadline=None)
@given(states, steps, inverse_angles)
def test_the_state_stays_in_bounds_and_moves_towards_the_motion(z, dpsi, inv) -> None:
    new = terms.dahl_step(z, dpsi, inv)
    assert -1.0 <= new <= 1.0
    if dpsi > 0:
        assert new >= z
    elif dpsi < 0:
        assert new <= z
    else:
        assert new == z  # at rest it holds


@settings(max_examples=200, deadline=None)
@given(states, st.floats(0.0, 0.02), st.floats(0.0, 0.02), inverse_angles, st.booleans())
def test_the_state_follows_the_path_not_the_sampling(z, a, b, inv, backwards) -> None:
    """Two steps one way equal one step of their sum: the exact solution over a step."""
    sign = -1.0 if backwards else 1.0
    split = terms.dahl_step(terms.dahl_step(z, sign * a, inv), sign * b, inv)
    assert math.isclose(split, terms.dahl_step(z, sign * (a + b), inv), abs_tol=1e-12)


def test_the_states_begin_at_zero_reach_the_sign_and_restart() -> None:
    phi = 0.002
    q = np.concatenate(
        (np.linspace(0.0, 0.05, 200), np.full(100, 0.05), np.linspace(0.05, 0.0, 200))
    )
    angles = np.column_stack((q, 0.5 * q))
    rows = np.array([[1.0, 0.0], [1.0, -1.0]])
    starts = np.zeros(q.size, dtype=bool)
    z = terms.sticking_states(angles, rows, 1.0 / phi, starts)
    assert z[0, 0] == 0.0
    assert z[199, 0] > 0.999 and z[199, 1] > 0.999  # 0.05 and 0.025 rad of motion up
    np.testing.assert_array_equal(z[200:300], np.broadcast_to(z[199], (100, 2)))  # held
    assert z[-1, 0] < -0.999  # and down again
    starts[300] = True
    restarted = terms.sticking_states(angles, rows, 1.0 / phi, starts)
    np.testing.assert_array_equal(restarted[:300], z[:300])
    assert restarted[300, 0] == 0.0


def _path(seed: int, n: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    q = np.column_stack(
        [0.2 * np.sin(2 * np.pi * f * t + p) for f, p in rng.uniform(0.3, 2, (3, 2))]
    )
    q[600:800] = q[600]  # a stop
    return q, np.gradient(q, t, axis=0)


@pytest.mark.parametrize("kind", ["cv", "coupled-cv"])
def test_path_torque_regressor_and_streaming_terms_agree(kind) -> None:
    rng = np.random.default_rng(3)
    description = resolve_robot("omni", 3)
    friction = (
        CoulombViscous(3, rng.normal(size=6))
        if kind == "cv"
        else CoupledCoulombViscous(3, description.friction_inputs, rng.normal(size=10))
    )
    q, qd = _path(1)
    sliding = friction.path_torque(q, qd)
    np.testing.assert_array_equal(sliding, friction.torque(qd))  # no state: sgn(w)
    friction.set_sticking(0.003)
    torque = friction.path_torque(q, qd)
    np.testing.assert_allclose(
        torque, friction.path_regressor(q, qd) @ friction.parameters, rtol=0, atol=1e-12
    )
    model = DynamicModel(
        "none", 3, FilterConfig(standstill_band_rad_s=0.05), None, np.zeros(0), np.zeros(0),
        friction, np.zeros(3),
    )  # fmt: skip
    model_terms = ModelTerms(model)
    streamed = np.array([model_terms(0.0, q[k], qd[k], np.zeros(3))[0] for k in range(q.shape[0])])
    np.testing.assert_allclose(streamed, torque, rtol=0, atol=1e-9)  # and no dead band
    assert np.abs(torque[650:800]).max() > 0.1  # the stop keeps its friction
    np.testing.assert_allclose(path_friction_torque(friction, q, qd), torque, atol=0)


def test_a_network_on_a_sticking_fallback_adds_to_its_path_torque() -> None:
    network = random_network(0, 80, 0.15)
    assert isinstance(network, WaveletNetwork) and network.fallback is not None
    q, qd = _path(2)
    np.testing.assert_allclose(network.path_torque(q, qd), network.blended_torque(qd), atol=0)
    network.fallback.set_sticking(0.002)
    fallback = network.fallback.path_torque(q, qd)
    weight = network.coverage_weight(qd)
    expected = (
        fallback + weight * network.torque(qd)
        if network.on_fallback
        else weight * network.torque(qd) + (1 - weight) * fallback
    )
    np.testing.assert_allclose(network.path_torque(q, qd), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(network.path_torque(q, qd, blend=False), network.torque(qd))
    if network.on_fallback:
        np.testing.assert_allclose(network.path_base_torque(q, qd), fallback, atol=0)


def test_the_model_file_keeps_the_angle_and_names_a_bad_one() -> None:
    friction = CoupledCoulombViscous(3, ((0,), (1, 2), (1, 2)), np.arange(10.0))
    assert "sticking_rad" not in friction.to_dict()  # older readers keep reading
    friction.set_sticking(0.004)
    data = friction.to_dict()
    again = friction_from_dict(data)
    assert again.sticking_rad == 0.004
    np.testing.assert_array_equal(again.parameters, friction.parameters)
    with pytest.raises(ModelFileError, match="sticking_rad"):
        friction_from_dict({**data, "sticking_rad": -1.0})
    plain = CoulombViscous(2, np.ones(4))
    plain.set_sticking(0.01)
    assert friction_from_dict(plain.to_dict()).sticking_rad == 0.01
    for bad in (-1e-3, math.nan, math.inf):
        with pytest.raises(ModelError):
            plain.set_sticking(bad)
    with pytest.raises(ModelError, match="no sticking state"):
        CoulombViscous(2).sticking_states(np.zeros((3, 2)))


def _recording(transition_rad: float, seed: int = 0) -> Recording:
    """A one-joint friction-only recording: Coulomb 0.05 N m, viscous 0.01, noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(40_000) * 1e-3
    phase = np.cumsum(rng.uniform(0.2, 1.5, t.size)) * 2 * np.pi * 1e-3
    q = 0.3 * np.sin(phase) + 0.05 * np.sin(3.1 * phase)
    q[10_000:12_000] = q[10_000]
    truth = CoulombViscous(1, np.array([0.05, 0.01]))
    qd = np.gradient(q, t)
    if transition_rad > 0:
        truth.set_sticking(transition_rad)
    tau = truth.path_torque(q[:, None], qd[:, None]) + rng.normal(0, 2e-3, (t.size, 1))
    return Recording(t, q[:, None], tau)


def test_identification_keeps_a_sticking_state_only_where_the_motion_shows_one() -> None:
    description = resolve_robot("none", 1)
    sticky, report = identify_model(
        [_recording(0.004)], description, "cv", offsets=False, sticking=True
    )
    assert 0.002 < sticky.friction.sticking_rad < 0.008
    assert report.details["sticking_rad"] == sticky.friction.sticking_rad
    np.testing.assert_allclose(sticky.friction.parameters[0], 0.05, rtol=0.1)
    plain, report = identify_model(
        [_recording(0.0)], description, "cv", offsets=False, sticking=True
    )
    assert plain.friction.sticking_rad == 0.0
    assert (
        report.details["sticking_scores"]["sticking"]
        > 0.9 * report.details["sticking_scores"]["sign"]
    )
    off, _ = identify_model([_recording(0.004)], description, "cv", offsets=False)
    assert off.friction.sticking_rad == 0.0  # not asked


def test_identification_refuses_a_sticking_state_on_model_coordinates() -> None:
    with pytest.raises(ConfigurationError, match="sticking"):
        identify_model([_recording(0.0)], resolve_robot("none", 1), "model-cv", sticking=True)
