"""The offline rigid-body fit: zero-phase smoothing, nuisance friction, and its effect on bias."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from teleop_force.errors import ConfigurationError
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.identification.pipeline import evaluate_model, identify_model
from teleop_force.identification.rigid_body_fit import (
    RigidBodyFitOptions,
    axis_nuisance_regressor,
    nuisance_friction_basis,
    zero_phase_smoothed,
)
from teleop_force.io.interchange_csv import Recording
from teleop_force.reports.experiments import SPRING_STIFFNESS_NM_PER_RAD, full_parameters
from teleop_force.robots.omni import omni_description
from teleop_force.simulation.plant import PlantConfig
from teleop_force.simulation.session import rigid_body_protocol

#: A 3-joint coupling whose model joints 2 and 3 turn with the motors' difference.
OMNI_RELATIVE = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 1.0]])


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


@settings(max_examples=30, deadline=None)
@given(arrays(float, (20, 3), elements=st.floats(-5, 5)))
def test_axis_nuisance_is_odd_and_acts_along_the_axes(qd: np.ndarray) -> None:
    friction = ModelCoordinateFriction(OMNI_RELATIVE)
    options = RigidBodyFitOptions()
    plus, names = axis_nuisance_regressor(friction, qd, options)
    minus, _ = axis_nuisance_regressor(friction, -qd, options)
    np.testing.assert_allclose(minus, -plus, atol=1e-12)
    scales = len(options.stribeck_scales_rad_s)
    assert plus.shape == (20, 3, 3 * scales) and len(names) == 3 * scales
    for column in range(plus.shape[2]):
        axis = friction.axes[column // scales]  # every column is one axis's row times a shape
        np.testing.assert_allclose(
            plus[:, :, column],
            np.outer(plus[:, :, column] @ axis / (axis @ axis), axis),
            atol=1e-12,
        )
    assert axis_nuisance_regressor(friction, qd, RigidBodyFitOptions.plain())[0].shape == (
        20,
        3,
        0,
    )


def test_model_coordinate_friction_and_offsets_are_recovered_with_the_rigid_body() -> None:
    """Torques with friction on model joints (at the true velocities) and offsets added."""
    truth = ModelCoordinateFriction(OMNI_RELATIVE, [0.02, 0.004, 0.03, 0.006, 0.015, 0.003])
    config = dataclasses.replace(PlantConfig(), torque_noise_std_nm=0.0, friction=None)
    session = rigid_body_protocol(30.0, 1, plant_config=config)
    offsets = np.array([0.01, -0.02, 0.015])
    tau = session.tau_nm + truth.torque(session.qd_true_rad_s) + offsets
    recording = Recording(session.t_s, session.q_rad, tau)
    description = omni_description()
    model, report = identify_model([recording], description, "model-cv", offsets=True)
    assert isinstance(model.friction, ModelCoordinateFriction)
    np.testing.assert_allclose(model.friction.parameters, truth.parameters, rtol=0.15, atol=2e-3)
    # joint 2's constant shares its column space with the gravity and spring terms there
    np.testing.assert_allclose(model.offsets_nm[[0, 2]], offsets[[0, 2]], atol=3e-3)
    assert report.stage_one is not None and report.stage_one.parameter_names[-1] == "offset_3"
    per_motor, _ = identify_model([recording], description, "cv", offsets=True)
    # per-motor CV cannot carry motor 3's friction to joint 2
    assert (
        report.friction_relative_rms[1]
        < 0.5 * (evaluate_model(per_motor, [recording])["relative_rms"][1])
    )
