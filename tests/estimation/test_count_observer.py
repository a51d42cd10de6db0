"""The encoder count observer: angles between the counts, from the model and the torques."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import ConfigurationError, DataError, ModelFileError
from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.count_observer import (
    observe_counts,
    observer_tables,
)
from teleop_force.estimation.estimator import ForceEstimator, equivalent_rigid_body
from teleop_force.estimation.kernels import ModelTerms
from teleop_force.estimation.rigid_chain import chain_tables
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig, FilterEntry
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.omni import (
    ENCODER_RESOLUTION_RAD,
    SPRING_STIFFNESS_NM_PER_RAD,
    omni_description,
)
from teleop_force.simulation import palpation_protocol
from tests.estimation.network_cases import CV_PARAMETERS, random_network

COUNTS = (ENCODER_RESOLUTION_RAD,) * 3


def _model(friction=None, **config) -> DynamicModel:
    """The Omni's nominal rigid body (the plant's) with a friction and filters."""
    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    if friction is None:
        friction = CoupledCoulombViscous(3, description.friction_inputs, CV_PARAMETERS)
    return DynamicModel(
        "omni", 3, FilterConfig(**config), base, beta, 0 * beta, friction, np.zeros(3)
    )


@pytest.fixture(scope="module")
def session():
    """A seeded simulated palpation (the plant's own friction, not the model's)."""
    return palpation_protocol(3.0, seed=7)


def _observe(model: DynamicModel, session, starts=None) -> np.ndarray:
    robot, _ = equivalent_rigid_body(model)
    n = session.t_s.size
    mask = np.zeros(n, dtype=bool)
    mask[0] = True
    if starts is not None:
        mask[list(starts)] = True
    springs = np.array([[1.0, SPRING_STIFFNESS_NM_PER_RAD, np.pi / 2]])
    floats, ints, scratch = observer_tables(
        np.array(model.filter_config.count_rad or COUNTS),
        chain_tables(robot.model, robot.description.tip_frame), robot.coupling,
        robot.description.rotor_inertia_kgm2, springs, ModelTerms(model),
    )  # fmt: skip
    t, q, tau = (np.ascontiguousarray(x) for x in (session.t_s, session.q_rad, session.tau_nm))
    return observe_counts(t, q, tau, mask, floats, ints, scratch)


def test_observed_angles_stay_within_each_reading_and_move_between_counts(session) -> None:
    observed = _observe(_model(), session)
    half = 0.5 * np.array(COUNTS)
    assert (np.abs(observed - session.q_rad) <= half + 1e-12).all()
    # between counts the readings stand still and the observed angles move on
    assert np.count_nonzero(np.diff(observed, axis=0)) > 2 * np.count_nonzero(
        np.diff(session.q_rad, axis=0)
    )


def test_observed_angles_give_a_better_velocity_than_the_readings(session) -> None:
    """Differentiated and filtered alike (two 150 Hz stages), against the true velocity."""
    t = np.asarray(session.t_s)

    def velocity(q: np.ndarray) -> np.ndarray:
        qd = np.vstack([np.zeros((1, 3)), np.diff(q, axis=0) / np.diff(t)[:, None]])
        return lowpass_batch(lowpass_batch(qd, t, 150.0), t, 150.0)

    truth = velocity(np.asarray(session.q_true_rad))
    keep = t > 0.25
    error_readings = np.sqrt(np.mean((velocity(session.q_rad) - truth)[keep] ** 2))
    error_observed = np.sqrt(np.mean((velocity(_observe(_model(), session)) - truth)[keep] ** 2))
    assert error_observed < 0.5 * error_readings


def test_a_stream_restarts_from_its_first_reading(session) -> None:
    whole = _observe(_model(), session, starts=[1000])
    tail = SimpleNamespace(
        **{name: getattr(session, name)[1000:] for name in ("t_s", "q_rad", "tau_nm")}
    )
    np.testing.assert_array_equal(whole[1000:], _observe(_model(), tail))
    np.testing.assert_array_equal(whole[1000], session.q_rad[1000])


def test_the_term_table_is_the_friction_or_a_network_fallback() -> None:
    network = random_network(0, 40, 0.15)
    rows, reach, parameters = ModelTerms(_model(network)).term_table()
    own = ModelTerms(_model(network.fallback)).term_table()
    for a, b in zip((rows, reach, parameters), own, strict=True):
        np.testing.assert_array_equal(a, b)
    assert rows.shape[0] > 0
    np.testing.assert_array_equal(parameters, network.fallback.parameters)


def test_the_streaming_estimator_needs_the_counts_and_a_rigid_body() -> None:
    with pytest.raises(ConfigurationError, match="count_rad"):
        ForceEstimator(_model(count_observer=True))


def test_a_bad_sample_leaves_the_observer_untouched(session) -> None:
    model = _model(count_observer=True, count_rad=COUNTS)
    t, q, tau = session.t_s, session.q_rad, session.tau_nm
    clean = ForceEstimator(model)
    probed = ForceEstimator(model)
    for k in range(300):
        expected = clean.step(t[k], q[k], tau[k]).copy()
        if k == 150:
            with pytest.raises(DataError):
                probed.step(t[k], np.array([np.nan, 0.0, 0.0]), tau[k])
            with pytest.raises(DataError, match="does not increase"):
                probed.step(t[k - 1], q[k], tau[k])
        np.testing.assert_array_equal(probed.step(t[k], q[k], tau[k]), expected)


def test_the_model_file_keeps_the_observer_and_its_counts(tmp_path) -> None:
    model = _model(count_observer=True, count_rad=COUNTS)
    path = tmp_path / "model.json"
    model.save(path)
    loaded = DynamicModel.load(path)
    assert loaded.filter_config.count_observer
    assert loaded.filter_config.count_rad == COUNTS
    plain = _model().to_dict()["filter"]
    assert "count_observer" not in plain and "count_rad" not in plain
    with pytest.raises(ModelFileError, match="count_rad"):
        FilterEntry(count_observer=True, count_rad=(4e-4, -1.0, 4e-4))
    data = model.to_dict()
    data["filter"]["count_rad"] = [4e-4, 4e-4]
    with pytest.raises(ModelFileError, match="count_rad"):
        DynamicModel.from_dict(data, "model.json")


def test_the_batch_estimator_measures_the_counts_when_the_model_has_none(session) -> None:
    t, q, tau = session.t_s, session.q_rad, session.tau_nm
    measured = BatchEstimator(_model(count_observer=True)).estimate(t, q, tau)
    given = BatchEstimator(_model(count_observer=True, count_rad=COUNTS)).estimate(t, q, tau)
    np.testing.assert_allclose(
        measured.force_tip_in_base_n, given.force_tip_in_base_n, rtol=0.0, atol=1e-9
    )


def test_the_two_halves_run_the_observer_as_the_fused_step(session) -> None:
    model = _model(count_observer=True, count_rad=COUNTS, estimator="observer", observer_hz=400.0)
    fused, halves = ForceEstimator(model), ForceEstimator(model, fused=False)
    assert fused.fused and not halves.fused
    t, q, tau = session.t_s, session.q_rad, session.tau_nm
    for k in range(600):
        np.testing.assert_allclose(
            halves.step(t[k], q[k], tau[k]), fused.step(t[k], q[k], tau[k]), rtol=0, atol=1e-9
        )
    fused.reset()
    halves.reset()
    np.testing.assert_allclose(halves.step(t[0], q[0], tau[0]), fused.step(t[0], q[0], tau[0]))


@settings(max_examples=25, deadline=None)
@given(
    count=st.floats(1e-4, 2e-3),
    torque_scale=st.floats(0.0, 0.2),
    seed=st.integers(0, 2**16),
)
def test_the_angles_stay_within_half_a_count_of_every_reading(count, torque_scale, seed) -> None:
    """Whatever the torques say (even wrong ones), the angle never leaves the count."""
    rng = np.random.default_rng(seed)
    n = 300
    t = np.arange(n) * 1e-3
    truth = 0.3 * np.sin(2.0 * np.pi * rng.uniform(0.2, 2.0, 3) * t[:, None]) + 0.5
    readings = np.round(truth / count) * count
    torques = torque_scale * rng.standard_normal((n, 3))
    model = _model(count_observer=True, count_rad=(count,) * 3)
    observed = _observe(model, SimpleNamespace(t_s=t, q_rad=readings, tau_nm=torques))
    assert np.isfinite(observed).all()
    assert (np.abs(observed - readings) <= 0.5 * count * (1 + 1e-9)).all()


def test_a_jump_the_model_cannot_follow_resyncs_the_observer(session) -> None:
    """A glitch of the encoder, a gap, garbage torques: the observer restarts at the reading."""
    model = _model(count_observer=True, count_rad=COUNTS)
    spiked = np.array(session.q_rad)
    spiked[500, 1] += 1.0  # one reading a radian off, then back
    torques = np.array(session.tau_nm)
    torques[800] = 2e6
    observed = _observe(model, SimpleNamespace(t_s=session.t_s, q_rad=spiked, tau_nm=torques))
    assert np.isfinite(observed).all()
    np.testing.assert_array_equal(observed[500], spiked[500])
    np.testing.assert_array_equal(observed[501], spiked[501])  # and again on the way back
    assert (np.abs(observed - spiked) <= 0.5 * np.array(COUNTS) + 1e-12).all()


def test_tuples_arrays_and_lists_give_the_same_angles(session) -> None:
    """The service passes tuples of floats; other callers arrays or lists."""
    model = _model(count_observer=True, count_rad=COUNTS)
    estimators = [ForceEstimator(model) for _ in range(3)]
    t, q, tau = session.t_s, session.q_rad, session.tau_nm
    for k in range(200):
        out = [
            e.step(t[k], convert(q[k]), convert(tau[k])).copy()
            for e, convert in zip(estimators, (tuple, np.asarray, list), strict=True)
        ]
        np.testing.assert_array_equal(out[0], out[1])
        np.testing.assert_array_equal(out[0], out[2])
    with pytest.raises(DataError, match="joint"):
        estimators[0].step(t[200], (0.1, 0.2), tau[200])
    with pytest.raises(DataError):
        estimators[1].step(t[200], ("a", 0.2, 0.3), tau[200])
