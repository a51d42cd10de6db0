import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.identification.least_squares import least_squares, relative_rms


def test_least_squares_recovers_parameters_with_honest_deviations() -> None:
    rng = np.random.default_rng(0)
    theta = np.array([1.0, -2.0, 0.5])
    y = rng.normal(size=(5000, 2, 3))
    noise = np.array([0.01, 0.1])
    tau = np.einsum("kjp,p->kj", y, theta) + rng.normal(size=(5000, 2)) * noise
    fit = least_squares(y, tau, ["a", "b", "c"])
    z = (fit.parameters - theta) / fit.standard_deviations
    assert np.all(np.abs(z) < 5)
    assert np.all(fit.standard_deviations < 1e-3)
    assert fit.condition_number < 2
    assert fit.relative_rms.shape == (2,)
    assert "a1" in fit.table()


def test_least_squares_rejects_nan_and_too_few_samples() -> None:
    y = np.ones((2, 1, 3))
    with pytest.raises(DataError):
        least_squares(y, np.ones((2, 1)), ["a", "b", "c"])
    y = np.ones((10, 1, 1))
    tau = np.ones((10, 1))
    tau[3] = np.nan
    with pytest.raises(DataError):
        least_squares(y, tau, ["a"])


def test_relative_rms() -> None:
    x = np.array([[1.0], [-1.0]])
    np.testing.assert_allclose(relative_rms(x, 0.9 * x), [0.1])


def test_coverage_warning_names_joints_mostly_off_trained_ground() -> None:
    from teleop_force.identification.wavelet_training import coverage_warning

    assert coverage_warning(np.array([0.9, 0.5])) is None
    line = coverage_warning(np.array([0.9, 0.1, 0.0]), ["hip", "knee", "ankle"])
    assert line is not None and "\n" not in line
    assert "knee 10%" in line and "ankle 0%" in line and "hip" not in line
    assert "Coulomb-viscous fallback" in line


def test_wavelet_identification_on_little_data_falls_back_to_the_cv_with_a_warning() -> None:
    """Too little data for a single trusted cell: identified all the same, the CV carrying."""
    import teleop_force as tf
    from teleop_force.identification.wavelet_training import (
        BATCH_MIN_VISITS,
        batch_min_visits,
    )
    from teleop_force.simulation import rigid_body_protocol

    session = rigid_body_protocol(0.6)
    recording = tf.Recording(session.t_s, session.q_rad, session.tau_nm)
    model, report = tf.identify_model([recording], tf.omni_description(), "wn")
    assert model.friction.kind == "wn" and model.friction.fallback is not None
    assert report.details["wn_trained_fraction"] == [0.0, 0.0, 0.0]
    assert "fallback" in report.details["warning"]
    assert 1 <= report.details.get("wn_min_visits", BATCH_MIN_VISITS) <= BATCH_MIN_VISITS
    # off the trained ground the friction is exactly the fitted coupled CV
    qd = np.array([[0.3, -0.2, 0.1], [-1.0, 0.5, 0.4]])
    np.testing.assert_allclose(
        model.friction_torque(qd), model.friction.fallback.torque(qd), atol=1e-12
    )
    assert np.any(model.friction.fallback.parameters != 0.0)
    assert batch_min_visits(model.friction, np.zeros((0, 3))) == 1


def test_a_network_on_its_fallback_is_trained_on_what_the_coupled_cv_leaves() -> None:
    """The default network adds to the stage-one CV: it fits the remainder, not the friction."""
    import teleop_force as tf
    from teleop_force.identification.prepared import WaveletOptions
    from teleop_force.simulation import rigid_body_protocol

    session = rigid_body_protocol(20.0)
    recording = tf.Recording(session.t_s, session.q_rad, session.tau_nm)
    description = tf.omni_description()
    on, on_report = tf.identify_model([recording], description, "wn")
    alone, alone_report = tf.identify_model(
        [recording], description, "wn", wavelet=WaveletOptions(on_fallback=False)
    )
    assert on.friction.on_fallback and not alone.friction.on_fallback
    assert on_report.details["wn_on_fallback"] is True
    np.testing.assert_array_equal(
        on.friction.fallback.parameters, alone.friction.fallback.parameters
    )
    qd = session.qd_true_rad_s
    own_on = np.sqrt(np.mean(on.friction.torque(qd) ** 2, axis=0))
    own_alone = np.sqrt(np.mean(alone.friction.torque(qd) ** 2, axis=0))
    assert np.all(own_on < 0.5 * own_alone)  # the CV carries most of the friction
    # both explain the training torques about as well
    np.testing.assert_allclose(
        on_report.friction_relative_rms, alone_report.friction_relative_rms, atol=0.05
    )
