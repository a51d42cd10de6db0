import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.cli.main import main
from teleop_force.estimation.batch import evaluate_recordings
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect, effect_from_dict
from teleop_force.identification.pipeline import evaluate_model
from teleop_force.io.interchange_csv import Recording, write_interchange_csv
from teleop_force.io.recordings import read_recording
from teleop_force.residual.loop import trace_residual
from teleop_force.residual.options import ResidualOptions
from teleop_force.robots.registry import resolve_robot
from tests.shared_data import require


def _sweep(cable: bool, seed: int = 0) -> Recording:
    """A one-joint sweep like the dVRK joint-4 test: forward then back at 0.4 rad/s."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 24.0, 0.005)
    q = np.where(t < 12, -1.4 + 0.4 * t, -1.4 + 0.4 * (24 - t))
    qd = np.gradient(q, t)
    tau = 0.02 * np.sign(qd) + 0.003 * qd + 0.01
    if cable:
        tau = tau + 0.04 * np.sin(1.3 * q) + 0.01 * np.cos(2 * q) * np.sign(qd)
    tau = tau + rng.normal(0, 0.001, t.size)
    return Recording(t, q[:, None], tau[:, None])


def test_clean_sweep_adds_nothing() -> None:
    report = trace_residual([_sweep(cable=False)], resolve_robot("none", 1))
    assert report.effects == ()
    np.testing.assert_allclose(report.after, report.before)


def test_cable_torque_is_traced_to_the_joint_angle() -> None:
    report = trace_residual([_sweep(cable=True)], resolve_robot("none", 1))
    assert report.effects, "the angle-dependent torque was not found"
    first = report.effects[0]
    assert first.spec.joint == 0
    assert "q1" in first.spec.depends_on()
    assert report.after[0] < 0.5 * report.before[0]
    payload = report.to_json()
    assert set(payload) >= {"before", "after", "effects"}
    assert payload["effects"][0]["joint"] == 1


def test_found_effects_round_trip_through_the_model_file(tmp_path: Path) -> None:
    report = trace_residual([_sweep(cable=True)], resolve_robot("none", 1))
    path = tmp_path / "m.json"
    report.model.save(path)
    loaded = DynamicModel.load(path)
    assert len(loaded.effects) == len(report.model.effects)
    q = np.linspace(-1, 1, 7)[:, None]
    qd = np.ones_like(q)
    t = np.arange(7.0)
    for a, b in zip(loaded.effects, report.model.effects, strict=True):
        np.testing.assert_allclose(a.torque(t, q, qd, q), b.torque(t, q, qd, q))


def test_the_saved_model_reproduces_the_reported_figures_in_sample() -> None:
    # The Gaussian bumps of smooth(q1) x (1, sgn(qd1)) nearly sum to an offset and a Coulomb
    # term: the final fit must not split the torque into parts that cancel only on the fit's
    # samples (the wavelet network, refitted, did not: the dVRK MTM's --robot none model was
    # 149-202 % in-sample on joint 2 where the loop reported 46 %).
    recording = _sweep(cable=True)
    report = trace_residual([recording], resolve_robot("none", 1))
    assert report.effects
    model = report.model
    in_sample = evaluate_model(model, [recording])["relative_rms"]
    np.testing.assert_allclose(in_sample, report.after, atol=0.02)
    estimated = evaluate_recordings(model, [recording])["relative_rms"]
    assert np.all(estimated < report.after + 0.05)
    effect = model.effects[0]
    q = recording.q_rad
    qd = np.gradient(q[:, 0], recording.t_s)[:, None]
    torque = effect.torque(recording.t_s, q, qd, np.zeros_like(q))
    # the effect carries the cable's torque (0.04 N m), not a large part cancelled elsewhere
    assert np.sqrt(np.mean(torque**2)) < 0.1


@pytest.mark.timeout(1800)  # the loop on 7 joints: 73 s alone (BLAS on one thread)
def test_the_mtm_model_without_a_rigid_body_is_as_good_as_reported_and_carries_over() -> None:
    # Issue 18: the written --robot none model of trajectory one was 149 % (fit's filters) and
    # 202 % (estimator) in-sample on joint 2, where the loop reported 46 % held out; and on
    # trajectory two (same joint ranges, never seen) it was worse than predicting zero torque
    # on joints 2 and 3 (109 / 130 %) while the phase folds held out short, scattered blocks.
    path = require("dvrk_mtm", "mtm_traj_one_results.csv")
    recording = read_recording(path)
    report = trace_residual([recording], resolve_robot("none", 7))
    assert report.effects
    after = np.asarray(report.after)
    in_sample = evaluate_model(report.model, [recording])["relative_rms"]
    assert np.all(in_sample <= after + 0.05), (in_sample, after)
    # the estimator (observer) on the joints the effects act on; joint 7's estimator figure
    # differs from the fit's without any effect (the observer on a 1e-3 N m torque)
    estimated = evaluate_recordings(report.model, [recording])["relative_rms"]
    with_effects = sorted({e.spec.joint for e in report.effects})
    assert np.all(estimated[with_effects] <= after[with_effects] + 0.05), (estimated, after)
    other = read_recording(require("dvrk_mtm", "mtm_traj_two_results.csv"))
    carried = evaluate_recordings(report.model, [other])["relative_rms"]
    assert np.all(carried < 1.0), carried


def test_effect_basis_shapes_and_kinds() -> None:
    spec = BasisSpec(2, "q2-q3", "smooth", "both", -1.0, 1.0, 5)
    assert spec.size == 10
    assert spec.depends_on() == ["q2", "q3", "qd3"]
    q = np.zeros((4, 3))
    assert spec.basis(np.arange(4.0), q, q, q).shape == (4, 10)
    effect = FoundEffect(BasisSpec(0, "t", "linear", "sign"), np.array([0.5]))
    assert effect_from_dict(effect.to_dict()).spec == effect.spec
    assert BasisSpec(1, "tau2", "abs", "sign").kind == "load-dependent friction"


def test_residual_cli_json_contract(tmp_path: Path, capsys) -> None:
    path = tmp_path / "sweep.csv"
    write_interchange_csv(path, _sweep(cable=True))
    assert (
        main(["residual", str(path), "--robot", "none", "--json", "-o", str(tmp_path / "report")])
        == 0
    )
    payload = json.loads(capsys.readouterr().out)
    assert len(payload["before"]) == len(payload["after"]) == 1
    assert payload["effects"][0]["kind"]
    assert (tmp_path / "report" / "report.md").exists()
    assert (tmp_path / "report" / "error_per_joint.png").exists()


def test_residual_cli_takes_model_coordinate_friction_and_offsets(tmp_path: Path, capsys) -> None:
    """On a robot without coupling, model-coordinate CV is CV: the cable torque is found."""
    path = tmp_path / "sweep.csv"
    write_interchange_csv(path, _sweep(cable=True))
    argv = ["residual", str(path), "--robot", "none", "--friction", "model-cv", "--offsets"]
    assert main([*argv, "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["effects"] and "q1" in payload["effects"][0]["depends_on"]
    assert payload["after"][0] < 0.5 * payload["before"][0]


def test_measured_dvrk_cable_sweep_meets_the_target() -> None:
    raw = np.loadtxt(require("dvrk_mtm", "mtm_joint4_cable_test_results.csv"), delimiter=",")
    t = np.arange(raw.shape[0]) / 200.0
    recording = Recording(t, raw[:, [0]], raw[:, [2]])
    report = trace_residual([recording], resolve_robot("none", 1), ResidualOptions())
    assert report.before[0] > 0.4  # CV + viscous + offset leaves about half unexplained
    assert report.after[0] <= 0.10
    assert "q1" in report.effects[0].spec.depends_on()


def test_friction_controls_reject_a_velocity_function_in_disguise() -> None:
    """A residual that is friction (a function of qd1) is not named after the angle q1.

    The motion is a pure sinusoid, so q1 and qd1 determine each other on each half cycle and
    a direction-modulated smooth function of q1 explains the friction on held-out blocks as
    well as the friction shapes do: only the control can tell them apart.
    """
    from teleop_force.residual.controls import control_gain
    from teleop_force.residual.scoring import JointDesign

    rng = np.random.default_rng(3)
    t = np.arange(20000) * 1e-3
    folds = (np.arange(t.size) * 20 // t.size) % 5
    q1 = np.sin(2 * np.pi * 0.5 * t)
    qd1 = np.pi * np.cos(2 * np.pi * 0.5 * t)
    friction = 0.02 * np.tanh(qd1 / 0.05) * np.exp(-np.abs(qd1) / 0.3)
    y = friction + 1e-4 * rng.normal(size=t.size)
    base = np.stack([np.ones_like(t), np.sign(qd1), qd1], axis=1)
    control = JointDesign(
        np.concatenate(
            [
                base,
                np.stack(
                    [np.tanh(qd1 / 0.05) * np.exp(-np.abs(qd1) / s) for s in (0.1, 0.3, 1.0)],
                    axis=1,
                ),
            ],
            axis=1,
        ),
        y,
        folds,
        5,
        1e-8,
    )
    disguised = np.stack(
        [np.sign(qd1) * np.exp(-(((q1 - c) / 0.3) ** 2)) for c in np.linspace(-1, 1, 6)], axis=1
    )
    plain = JointDesign(base, y, folds, 5, 1e-8)
    plain_gain = 1 - np.sqrt(plain.held_out_errors(disguised).sum() / plain.held_out_errors().sum())
    assert plain_gain > 0.2  # without the control it would be accepted
    assert control_gain(control, disguised) < 0.05
    assert control_gain(None, disguised) == 1.0


def test_min_control_gain_is_validated() -> None:
    from teleop_force.errors import ConfigurationError

    with pytest.raises(ConfigurationError):
        ResidualOptions(min_control_gain=1.0)


def test_reversal_controls_reject_a_reversal_transient_in_disguise() -> None:
    """Friction that lags a motion reversal is not named after the angle of the reversals.

    On a sinusoid the reversals happen at the two extreme angles, so a transient that decays
    with the displacement since the reversal is a function of q1 on each half cycle.
    """
    from teleop_force.residual.controls import control_gain, reversal_transient_basis
    from teleop_force.residual.scoring import JointDesign

    rng = np.random.default_rng(4)
    t = np.arange(20000) * 1e-3
    folds = (np.arange(t.size) * 20 // t.size) % 5
    q1 = np.sin(2 * np.pi * 0.5 * t)
    qd1 = np.pi * np.cos(2 * np.pi * 0.5 * t)
    turn = np.where(qd1 > 0, -1.0, 1.0)  # the angle of the last reversal
    transient = -0.01 * np.sign(qd1) * np.exp(-np.abs(q1 - turn) / 0.02)
    y = transient + 1e-4 * rng.normal(size=t.size)
    base = np.stack([np.ones_like(t), np.sign(qd1), qd1], axis=1)
    controls = reversal_transient_basis(t, q1, qd1)
    control = JointDesign(np.concatenate([base, controls], axis=1), y, folds, 5, 1e-8)
    centres = np.linspace(-1, 1, 6)
    disguised = np.stack([np.sign(qd1) * np.exp(-(((q1 - c) / 0.3) ** 2)) for c in centres], axis=1)
    plain = JointDesign(base, y, folds, 5, 1e-8)
    plain_errors = plain.held_out_errors(disguised).sum()
    plain_gain = 1 - np.sqrt(plain_errors / plain.held_out_errors().sum())
    assert plain_gain > 2 * ResidualOptions().min_rms_gain  # without the controls: accepted
    assert control_gain(control, disguised) < ResidualOptions().min_control_gain


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=60),
    st.floats(0.0, 0.01),
)
def test_reversal_basis_is_bounded_odd_and_resets_at_reversals(velocities, dt_s) -> None:
    from teleop_force.residual.controls import REVERSAL_DEAD_BAND_RAD_S, reversal_transient_basis

    qd = np.asarray(velocities)
    t = np.arange(qd.size) * (dt_s + 1e-3)
    q = np.cumsum(qd) * 1e-3
    phi = reversal_transient_basis(t, q, qd)
    mirrored = reversal_transient_basis(t, -q, -qd)
    half = phi.shape[1] // 2
    assert phi.shape == (qd.size, 16) and np.all(np.abs(phi) <= 1.0)
    np.testing.assert_allclose(mirrored[:, :half], -phi[:, :half], atol=1e-15)  # odd part
    np.testing.assert_allclose(mirrored[:, half:], phi[:, half:], atol=1e-15)  # even part
    moving = np.flatnonzero(np.abs(qd) > REVERSAL_DEAD_BAND_RAD_S)
    for a, b in itertools.pairwise(moving):
        if np.sign(qd[a]) != np.sign(qd[b]):  # b is a reversal: every decay restarts at 1
            np.testing.assert_allclose(phi[b, half:], 1.0)


def _coupled_cable(
    spring: bool, seed: int = 0, at_model_joint: bool = False
) -> tuple[Recording, object]:
    """Two joints whose friction acts on model axes ``w = T qd`` (a cable over joint 1's pulley).

    Torque ``T^T f(T qd)`` plus offsets, and (``spring``) an angle-dependent torque on joint 2:
    on motor 2 alone, or (``at_model_joint``) at model joint 2, reaching motor 1 through the
    coupling (``T^T e_2 = (0.7, 1)``).
    """
    from dataclasses import replace

    from teleop_force.robots.registry import friction_only_description

    coupling = np.array([[1.0, 0.0], [0.7, 1.0]])
    description = replace(
        friction_only_description(2), coupling=coupling, friction_inputs=((0,), (0, 1))
    )
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 40.0, 0.005)
    q = np.column_stack(
        (
            0.8 * np.sin(2 * np.pi * 0.13 * t) + 0.3 * np.sin(2 * np.pi * 0.31 * t),
            0.7 * np.sin(2 * np.pi * 0.17 * t + 1.0) + 0.2 * np.sin(2 * np.pi * 0.41 * t),
        )
    )
    qd = np.gradient(q, t, axis=0)
    w = qd @ coupling.T
    f = np.array([0.02, 0.03]) * np.tanh(w / 0.01) + np.array([0.004, 0.006]) * w
    tau = f @ coupling + np.array([0.01, -0.005])
    if spring:
        torque = 0.03 * np.sin(1.5 * q[:, 1] + 0.3)
        tau += torque[:, None] * (coupling[1] if at_model_joint else np.array([0.0, 1.0]))
    tau += rng.normal(0.0, 0.001, tau.shape)
    return Recording(t, q, tau), description


def test_model_coordinate_friction_residual_traces_the_spring(tmp_path: Path) -> None:
    """With friction in model coordinates (and offsets) the loop names joint 2's spring."""
    from teleop_force.friction.model_coordinates import ModelCoordinateFriction
    from teleop_force.identification.pipeline import evaluate_model

    recording, description = _coupled_cable(spring=True)
    options = ResidualOptions(friction="model-cv", offsets=True)
    report = trace_residual([recording], description, options)
    assert report.effects, "the spring on joint 2 was not found"
    first = report.effects[0]
    assert first.spec.joint == 1 and "q2" in first.spec.depends_on(), first.spec.describe()
    # at model joint 2 it would load joint 1 too: the whole model refutes that placement
    assert first.reach is None
    assert report.after[1] < 0.5 * report.before[1], (report.before, report.after)
    assert isinstance(report.model.friction, ModelCoordinateFriction)
    held_out, _ = _coupled_cable(spring=True, seed=1)
    error = evaluate_model(report.model, [held_out])["relative_rms"]
    assert np.all(error < 0.1), error
    path = tmp_path / "model.json"
    report.model.save(path)
    again = evaluate_model(DynamicModel.load(path), [held_out])["relative_rms"]
    np.testing.assert_allclose(again, error, rtol=1e-9)


@pytest.mark.parametrize("placement", ["auto", "either", "model"])
def test_an_effect_at_a_model_joint_is_placed_there(placement: str) -> None:
    """The spring acts at model joint 2 (motor 1 sees 0.7 of it): found on joint 2, placed at
    model joint 2, and the model transfers to another recording."""
    from teleop_force.identification.pipeline import evaluate_model

    recording, description = _coupled_cable(spring=True, at_model_joint=True)
    options = ResidualOptions(friction="model-cv", offsets=True, effect_placement=placement)
    report = trace_residual([recording], description, options)
    assert report.effects, "the spring was not found"
    first = report.effects[0]
    assert first.spec.joint == 1 and "q2" in first.spec.depends_on(), first.spec.describe()
    np.testing.assert_allclose(first.reach, [0.7, 1.0])
    assert report.to_json()["effects"][0]["reach"] == [0.7, 1.0]
    saved = report.model.effects[0]
    np.testing.assert_allclose(saved.reach, [0.7, 1.0])
    held_out, _ = _coupled_cable(spring=True, seed=1, at_model_joint=True)
    error = evaluate_model(report.model, [held_out])["relative_rms"]
    assert np.all(error < 0.1), error


def test_effects_on_the_motor_joint_miss_the_coupled_share() -> None:
    """With placement ``motor`` the same spring is found on joint 2 alone."""
    recording, description = _coupled_cable(spring=True, at_model_joint=True)
    options = ResidualOptions(friction="model-cv", offsets=True, effect_placement="motor")
    report = trace_residual([recording], description, options)
    assert report.effects and all(e.reach is None for e in report.effects)
    assert "reach" not in report.to_json()["effects"][0]


def test_unknown_effect_placement_is_refused() -> None:
    with pytest.raises(ValueError, match="effect placement"):
        ResidualOptions(effect_placement="elbow")


def test_effect_reaches_are_the_rows_of_the_coupling() -> None:
    from teleop_force.residual.placement import effect_reaches
    from teleop_force.robots.dvrk_mtm import CABLE_RATIO, dvrk_mtm_description

    reaches = effect_reaches(dvrk_mtm_description())
    assert [r is None for r in reaches] == [True, True, False, False, True, True, True]
    np.testing.assert_allclose(reaches[2], [0, -1, 1, 0, 0, 0, 0])
    np.testing.assert_allclose(reaches[3], [0, CABLE_RATIO, -CABLE_RATIO, 1, 0, 0, 0])
    assert effect_reaches(resolve_robot("none", 2)) == [None, None]


def test_found_effect_reach_spreads_its_torque_and_round_trips() -> None:
    from teleop_force.errors import ModelError

    spec = BasisSpec(1, "q2", "linear")
    effect = FoundEffect(spec, np.array([2.0]), 0.5, np.array([0.7, 1.0]))
    q = np.array([[0.0, 0.5], [0.0, -1.0]])
    np.testing.assert_allclose(effect.torque(np.zeros(2), q, q, q), [[0.7, 1.0], [-1.4, -2.0]])
    again = effect_from_dict(effect.to_dict())
    np.testing.assert_array_equal(again.reach, [0.7, 1.0])
    assert effect_from_dict(FoundEffect(spec, np.array([2.0])).to_dict()).reach is None
    with pytest.raises(ModelError, match="reach"):
        FoundEffect(spec, np.array([2.0]), 0.0, np.array([1.0]))
    with pytest.raises(ModelError, match="reaches 2 joints, not 3"):
        effect.torque(np.zeros(1), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))


def test_trajectory_period_of_repeated_and_unrepeated_motion() -> None:
    from teleop_force.residual.scoring import trajectory_period

    t = np.arange(0.0, 20.0, 0.005)
    q = np.column_stack((np.sin(2 * np.pi * t / 3.0), 0.2 * np.cos(4 * np.pi * t / 3.0)))
    assert trajectory_period(t, q) == pytest.approx(3.0, abs=0.005)
    rng = np.random.default_rng(0)
    assert trajectory_period(t, np.cumsum(rng.normal(size=(t.size, 2)), axis=0)) is None
    assert trajectory_period(t, np.zeros((t.size, 2))) is None  # nothing moves
    assert trajectory_period(t[:5], q[:5]) is None
    swept, _ = _coupled_cable(spring=False)  # two incommensurate sines over 40 s
    assert trajectory_period(swept.t_s, swept.q_rad) is None


@settings(max_examples=25, deadline=None)
@given(
    period=st.floats(1.5, 4.0),
    amplitudes=st.lists(st.floats(0.05, 1.0), min_size=3, max_size=3),
    phases=st.lists(st.floats(0.0, 6.3), min_size=3, max_size=3),
)
def test_trajectory_period_finds_the_period_of_a_fourier_trajectory(
    period: float, amplitudes: list[float], phases: list[float]
) -> None:
    """A Fourier trajectory (harmonics 1-3 of the base frequency) repeats every period."""
    from teleop_force.residual.scoring import trajectory_period

    t = np.arange(0.0, 2.5 * period, 0.01)
    q = sum(
        a * np.sin(2 * np.pi * (k + 1) * t / period + p)
        for k, (a, p) in enumerate(zip(amplitudes, phases, strict=True))
    )
    found = trajectory_period(t, np.column_stack((q, np.cos(2 * np.pi * t / period))))
    assert found is not None and abs(found - period) <= 0.01


def test_periodic_recordings_also_get_phase_folds() -> None:
    from teleop_force.identification.filtered_regressor import FilterConfig
    from teleop_force.identification.pipeline import prepare
    from teleop_force.residual.samples import select_samples

    t = np.arange(0.0, 30.0, 0.005)
    q = np.column_stack((np.sin(2 * np.pi * t / 7.0), np.cos(4 * np.pi * t / 7.0)))
    periodic = Recording(t, q, np.zeros_like(q))
    description = resolve_robot("none", 2)
    options = ResidualOptions()
    prepared, _ = prepare([periodic], description, FilterConfig())
    data = select_samples(prepared, options, np.zeros(0))
    assert data.phase_folds is not None
    # a fold held out by phase is the same stretch of every period: the fold is a function
    # of the phase alone (up to the period's one-sample resolution at block edges)
    kept_t = t[data.rows[0]]
    n_blocks = options.folds * options.phase_blocks_per_fold
    phase = np.mod(kept_t - kept_t[0], 7.0) / 7.0
    expected = (np.floor(phase * n_blocks).astype(int)) % options.folds
    assert np.mean(data.phase_folds == expected) > 0.97
    # by default a fold is one contiguous stretch of the period: within one period the fold
    # changes once per fold boundary, not every few samples
    first_period = kept_t - kept_t[0] < 7.0
    assert np.count_nonzero(np.diff(data.phase_folds[first_period])) == options.folds - 1
    assert np.mean(data.folds == expected) < 0.5  # time blocks are not that
    assert (
        select_samples(prepared, ResidualOptions(phase_folds=False), np.zeros(0)).phase_folds
        is None
    )
    swept, _ = _coupled_cable(spring=False)
    prepared, _ = prepare([swept], description, FilterConfig())
    assert select_samples(prepared, options, np.zeros(0)).phase_folds is None


def test_model_coordinate_friction_residual_adds_nothing_without_the_spring() -> None:
    recording, description = _coupled_cable(spring=False)
    options = ResidualOptions(friction="model-cv", offsets=True)
    report = trace_residual([recording], description, options)
    assert report.effects == (), [e.spec.describe() for e in report.effects]


def test_unknown_residual_friction_is_refused() -> None:
    with pytest.raises(ValueError, match="residual friction"):
        ResidualOptions(friction="stribeck")


def test_choices_are_stored_as_enums_and_auto_placement_follows_the_friction() -> None:
    from teleop_force.friction.kinds import FrictionKind
    from teleop_force.residual.options import EffectPlacement

    options = ResidualOptions(friction="model-cv", effect_placement="auto")
    assert options.friction is FrictionKind.MODEL_CV
    assert options.effect_placement is EffectPlacement.AUTO
    assert options.placement is EffectPlacement.EITHER
    assert ResidualOptions().placement is EffectPlacement.MOTOR  # wn
    assert ResidualOptions(friction="model-cv", effect_placement="model").placement is (
        EffectPlacement.MODEL
    )
    assert ResidualOptions(friction=FrictionKind.CV) == ResidualOptions(friction="cv")


def test_report_history_rejections_and_plots_of_a_traced_sweep(tmp_path: Path) -> None:
    """Every accepted effect has a history entry and a plot; every rejection names its gain."""
    from teleop_force.residual.report import write_residual_report

    report = trace_residual([_sweep(cable=True)], resolve_robot("none", 1))
    assert len(report.history) == len(report.effects) == len(report.effect_plots) >= 1
    for entry, effect, plot in zip(
        report.history, report.effects, report.effect_plots, strict=True
    ):
        assert entry["effect"] == effect.spec.describe() == plot.spec.describe()
        assert entry["gain"] >= ResidualOptions().min_rms_gain
        assert plot.x.shape == plot.before.shape == plot.after.shape == (report.samples,)
        assert np.std(plot.after) < np.std(plot.before)
    for rejected in report.rejected:
        assert {"effect", "gain"} <= set(rejected)
        assert "control_gain" in rejected or "whole_model_after" in rejected
    json.dumps([*report.history, *report.rejected])  # the blind-test report saves them
    write_residual_report(report, tmp_path)
    assert (tmp_path / "effect_1.png").exists() and (tmp_path / "model.json").exists()
