"""The offline rigid-body fit: zero-phase smoothing, nuisance friction, and its effect on bias."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from teleop_force.errors import ConfigurationError
from teleop_force.experiments import SPRING_STIFFNESS_NM_PER_RAD, full_parameters
from teleop_force.interchange_csv import Recording
from teleop_force.model_fitting import identify_model
from teleop_force.omni import omni_description
from teleop_force.rigid_body_fit import (
    RigidBodyFitOptions,
    nuisance_friction_basis,
    zero_phase_smoothed,
)
from teleop_force.simulation.plant import PlantConfig
from teleop_force.simulation.session import rigid_body_protocol


def test_zero_phase_smoothing_removes_noise_without_delay() -> None:
    t = np.arange(5000) * 1e-3
    clean = np.sin(2 * np.pi * 1.5 * t)[:, None]
    noisy = clean + np.random.default_rng(0).uniform(-2e-4, 2e-4, clean.shape)
    smoothed = zero_phase_smoothed(t, noisy, 40.0)
    inner = slice(200, -200)
    assert np.sqrt(np.mean((smoothed - clean)[inner] ** 2)) < 0.3 * np.sqrt(
        np.mean((noisy - clean)[inner] ** 2)
    )
    lag = np.argmax(np.correlate(smoothed[inner, 0], clean[inner, 0], "full")) - (
        clean[inner].size - 1
    )
    assert lag == 0


def test_zero_phase_smoothing_leaves_short_or_slow_recordings_alone() -> None:
    q = np.arange(10.0)[:, None]
    assert np.array_equal(zero_phase_smoothed(np.arange(10) * 1e-3, q, 40.0), q)
    slow = np.random.default_rng(1).normal(size=(100, 2))
    assert np.array_equal(zero_phase_smoothed(np.arange(100) / 50.0, slow, 40.0), slow)


@settings(max_examples=50, deadline=None)
@given(arrays(float, (20, 3), elements=st.floats(-5, 5)))
def test_nuisance_friction_is_odd_in_the_velocities(qd: np.ndarray) -> None:
    options = RigidBodyFitOptions()
    for joint in range(3):
        plus, names = nuisance_friction_basis(qd, joint, ((0,), (1, 2), (1, 2)), options)
        minus, _ = nuisance_friction_basis(-qd, joint, ((0,), (1, 2), (1, 2)), options)
        np.testing.assert_allclose(minus, -plus, atol=1e-12)
        assert plus.shape == (20, len(names))
    assert len(nuisance_friction_basis(qd, 1, ((0,), (1, 2), (1, 2)), options)[1]) == 2 * 5 + 2


def test_options_reject_nonsense() -> None:
    with pytest.raises(ConfigurationError):
        RigidBodyFitOptions(smoothing_hz=0.0)
    with pytest.raises(ConfigurationError):
        RigidBodyFitOptions(stribeck_scales_rad_s=(0.1, -1.0))


def test_guarded_fit_beats_plain_least_squares_on_a_quantized_closed_loop_session() -> None:
    """Quantization alone (no friction, no torque noise) biases plain least squares."""
    config = dataclasses.replace(PlantConfig(), torque_noise_std_nm=0.0, friction=None)
    session = rigid_body_protocol(60.0, 1, plant_config=config)
    recording = Recording(session.t_s, session.q_rad, session.tau_nm)
    description = omni_description()
    errors = {}
    for label, options in (
        ("plain", RigidBodyFitOptions.plain()),
        ("guarded", RigidBodyFitOptions()),
    ):
        model, _ = identify_model([recording], description, "cv", rigid_body=options)
        assert model.base is not None
        truth = model.base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
        big = np.abs(truth) > 1e-4
        errors[label] = np.abs(model.base_values - truth)[big] / np.abs(truth[big])
    assert errors["guarded"].max() < 0.05
    assert errors["guarded"].max() < 0.5 * errors["plain"].max()
