import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from teleop_force.cli.main import build_parser
from teleop_force.errors import ConfigurationError
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.reports.accuracy import (
    AccuracyOptions,
    BatchEstimate,
    CascadeReference,
    accuracy_figures,
    accuracy_table,
    identify_free_motion,
    session_accuracy,
    write_accuracy_report,
)
from teleop_force.simulation import SimulatedSession, floor_touch_protocol


@pytest.fixture(scope="module")
def touching() -> SimulatedSession:
    return floor_touch_protocol(6.0, 3)


def test_figures_of_known_estimates(touching: SimulatedSession) -> None:
    force = touching.f_tip_in_base_n
    contact = np.linalg.norm(force, axis=1) > 0.0
    assert contact.any() and (~contact).any()
    offset = np.array([0.0, 0.1, 0.0])
    figures = accuracy_figures(touching, force + offset, force, warmup_s=0.0)
    assert figures["contact_error_n"] == pytest.approx(0.1)
    assert figures["free_false_force_n"] == pytest.approx(0.1)
    assert figures["lag_n"] == 0.0 and figures["bias_n"] == pytest.approx(0.1)
    assert figures["contact_fraction"] == pytest.approx(contact.mean())
    rms = np.sqrt(np.mean(np.sum(force[contact] ** 2, axis=1)))
    assert figures["contact_error_pct"] == pytest.approx(10.0 / rms)
    exact = accuracy_figures(touching, force, force, warmup_s=0.0)
    assert exact["contact_error_n"] == 0.0 and exact["free_false_force_n"] == 0.0
    broken = force.copy()
    broken[:10] = np.nan
    assert accuracy_figures(touching, broken, force, 0.0)["nan_samples"] == 10
    with pytest.raises(ConfigurationError):
        accuracy_figures(touching, force[:5], force, 0.0)


def test_cascade_reference_lags_a_step() -> None:
    force = np.zeros((400, 3))
    force[100:, 2] = 1.0
    out = CascadeReference(FilterConfig(estimator="filter"))(force, 1e-3)
    assert out[100, 2] == 0.0  # one sample of torque lag
    assert 0.0 < out[150, 2] < 0.95 and out[-1, 2] > 0.99
    faster = CascadeReference(FilterConfig(estimator="filter", cutoff_hz=30.0))(force, 1e-3)
    on_lv = FilterConfig(
        estimator="observer", observer_hz=30.0, observer_prefilter_hz=20.0,
        observer_prefilter_stages=1, observer_output_hz=0.0,
    )  # fmt: skip
    observer = CascadeReference(on_lv)(force, 1e-3)
    np.testing.assert_allclose(observer, faster)  # both first order at 30 Hz after L_v
    assert faster[150, 2] > out[150, 2]
    # the observer's own pre-filter: a second stage at the same cutoff lags more
    two = CascadeReference(dataclasses.replace(on_lv, observer_prefilter_stages=2))(force, 1e-3)
    assert two[110, 2] < observer[110, 2] and two[-1, 2] > 0.99
    # the output Butterworth: scipy's second-order low-pass after the first-order lags
    butter = CascadeReference(dataclasses.replace(on_lv, observer_output_hz=40.0))(force, 1e-3)
    lags = np.concatenate([observer[1:], observer[-1:]])  # before the torque lag
    sos = signal.butter(2, 40.0, fs=1000.0, output="sos")
    expected = signal.sosfilt(sos, lags, axis=0)
    np.testing.assert_allclose(butter, np.concatenate([expected[:1], expected[:-1]]), atol=1e-12)
    assert butter[110, 2] < observer[110, 2] and butter[-1, 2] > 0.99


def test_batch_estimate_takes_overrides() -> None:
    assert BatchEstimate().describe() == "batch (model's filters)"
    estimate = BatchEstimate({"cutoff_hz": 12.0})
    assert "cutoff_hz=12.0" in estimate.describe()
    with pytest.raises(ConfigurationError):
        AccuracyOptions(identify_duration_s=0.0)


def test_harness_on_a_short_session(tmp_path: Path) -> None:
    options = AccuracyOptions(identify_duration_s=8.0, test_duration_s=5.0)
    calls = []

    def estimate(model: object, session: SimulatedSession) -> np.ndarray:
        calls.append(session)
        return BatchEstimate()(model, session)  # type: ignore[arg-type]

    result = session_accuracy("two", 4, estimate=estimate, options=options)
    assert result.family == "two" and result.seed == 4
    assert calls and calls[0].family == "two" and calls[0].name == "floor-touch"
    assert calls[0].seed != 4  # the test session is not the identification session
    assert 0.0 < result.contact_fraction < 1.0 and result.rms_contact_force_n > 0.1
    assert np.isfinite(result.contact_error_n) and result.lag_n > 0.0
    markdown, path = write_accuracy_report([result], tmp_path, options)
    assert "| two | 4 |" in markdown.read_text() and "friction wn on-cv" in markdown.read_text()
    session_json = json.loads(path.read_text())["sessions"][0]
    assert session_json["seed"] == 4 and session_json["wn_structure"] == "on-cv"
    assert accuracy_table([result]).count("\n") == 2


def test_cli_flags() -> None:
    args = build_parser().parse_args(
        ["accuracy", "--family", "one", "two", "--seeds", "1", "2", "-o", "out", "--json"]
    )
    assert args.family == ["one", "two"] and args.seeds == [1, 2] and args.json


def test_identification_protocol_and_friction_are_options() -> None:
    with pytest.raises(ConfigurationError):
        AccuracyOptions(identify_protocol="palpation")
    with pytest.raises(ConfigurationError):
        AccuracyOptions(friction="lugre")
    assert AccuracyOptions().identify_protocol == "teleoperation"
    assert AccuracyOptions().friction is None  # the Omni's default, as `identify` fits it
    model, session = identify_free_motion(
        "one", 2, 8.0, protocol="slow-stretch", friction="coupled-cv"
    )
    assert session.name == "slow-stretch" and session.contact is None
    assert str(model.friction.kind) == "coupled-cv"
    with pytest.raises(ConfigurationError):
        identify_free_motion("one", 2, 8.0, protocol="palpation")


def test_cli_protocol_and_friction_flags() -> None:
    args = build_parser().parse_args(
        ["accuracy", "--identify-protocol", "slow-stretch", "--friction", "coupled-cv", "-o", "x"]
    )
    assert args.identify_protocol == "slow-stretch" and args.friction == "coupled-cv"
    defaults = build_parser().parse_args(["accuracy", "-o", "x"])
    assert defaults.identify_protocol == "teleoperation" and defaults.friction is None


def test_the_network_structure_is_an_option() -> None:
    with pytest.raises(ConfigurationError, match="wn structure"):
        AccuracyOptions(wn_structure="beside")
    assert AccuracyOptions().wn_structure == "on-cv"  # as `identify` fits it
    on, _ = identify_free_motion("one", 2, 8.0)
    alone, _ = identify_free_motion("one", 2, 8.0, wn_structure="alone")
    assert on.friction.on_fallback and not alone.friction.on_fallback
    args = build_parser().parse_args(["accuracy", "--wn-structure", "alone", "-o", "x"])
    assert args.wn_structure == "alone"
    assert build_parser().parse_args(["accuracy", "-o", "x"]).wn_structure == "on-cv"
    identify = build_parser().parse_args(["identify", "d.csv", "-o", "m.json"])
    assert identify.wn_structure == "on-cv"


def test_the_residual_loop_can_close_on_the_free_motion_first(tmp_path: Path) -> None:
    options = AccuracyOptions(identify_duration_s=30.0, test_duration_s=5.0, trace_residual=True)
    models = []

    def estimate(model: object, session: SimulatedSession) -> np.ndarray:
        models.append(model)
        return BatchEstimate()(model, session)  # type: ignore[arg-type]

    result = session_accuracy("one", 1, estimate=estimate, options=options)
    plain, _ = identify_free_motion("one", 1, 30.0)
    added = len(models[0].effects) - len(plain.effects)
    assert added >= 1 and len(result.found_effects) == added  # what was found is what is tested
    assert all("held out" in line for line in result.found_effects)
    assert np.isfinite(result.contact_error_n)
    markdown, path = write_accuracy_report([result], tmp_path, options)
    assert "| one | 1 |" in markdown.read_text()
    assert result.found_effects[0] in markdown.read_text()
    payload = json.loads(path.read_text())
    assert payload["trace_residual"] is True
    assert payload["sessions"][0]["found_effects"] == list(result.found_effects)
    with pytest.raises(ConfigurationError, match="trace_residual"):
        session_accuracy("one", 1, options=options, model=plain)
    args = build_parser().parse_args(["accuracy", "--trace-residual", "-o", "x"])
    assert args.trace_residual
    assert not build_parser().parse_args(["accuracy", "-o", "x"]).trace_residual


def test_the_sticking_search_is_identifys_default_and_reported(tmp_path: Path) -> None:
    """Family two's LuGre arm shows a sticking state in its free motion; family one's does not."""
    with pytest.raises(ConfigurationError, match="sticking"):
        AccuracyOptions(friction="model-cv", sticking=True)
    assert AccuracyOptions().sticking is None  # as `identify` does for the Omni: on
    lugre, _ = identify_free_motion("two", 4, 30.0)
    assert 1e-4 < lugre.friction.fallback.sticking_rad < 1e-2
    unasked, _ = identify_free_motion("two", 4, 30.0, sticking=False)
    assert unasked.friction.fallback.sticking_rad == 0.0
    static, _ = identify_free_motion("one", 1, 30.0, friction="coupled-cv")
    assert static.friction.sticking_rad == 0.0
    options = AccuracyOptions(identify_duration_s=30.0, test_duration_s=5.0)
    result = session_accuracy("two", 4, options=options, model=lugre)
    assert result.sticking_rad == lugre.friction.fallback.sticking_rad
    markdown, path = write_accuracy_report([result], tmp_path, options)
    assert f"two seed 4: {result.sticking_rad:.3g} rad" in markdown.read_text()
    assert json.loads(path.read_text())["sessions"][0]["sticking_rad"] == result.sticking_rad
    parse = build_parser().parse_args
    assert parse(["accuracy", "-o", "x"]).sticking is None
    assert parse(["accuracy", "--no-sticking", "-o", "x"]).sticking is False
    assert parse(["identify", "d.csv", "--sticking", "-o", "m.json"]).sticking is True


def test_the_count_observer_is_identifys_default_and_reported(tmp_path: Path) -> None:
    """Each family's own encoders: family two's counts differ per joint."""
    assert AccuracyOptions().count_observer is None  # as `identify` does for the Omni: on
    model, _ = identify_free_motion("two", 4, 30.0, sticking=False)
    config = model.filter_config
    assert config.count_observer and config.observer_hz == 400.0
    np.testing.assert_allclose(config.count_rad, (5.2e-4, 4.6e-4, 4.6e-4), rtol=1e-6)
    plain, _ = identify_free_motion("two", 4, 30.0, sticking=False, count_observer=False)
    assert not plain.filter_config.count_observer and plain.filter_config.observer_hz == 40.0
    options = AccuracyOptions(identify_duration_s=30.0, test_duration_s=5.0)
    result = session_accuracy("two", 4, options=options, model=model)
    assert result.count_rad == config.count_rad
    assert "count observer" in result.estimator
    markdown, path = write_accuracy_report([result], tmp_path, options)
    assert "two seed 4: 0.00052 / 0.00046 / 0.00046" in markdown.read_text()
    assert json.loads(path.read_text())["sessions"][0]["count_rad"] == list(config.count_rad)
    parse = build_parser().parse_args
    assert parse(["accuracy", "--no-count-observer", "-o", "x"]).count_observer is False
    assert parse(["identify", "d.csv", "-o", "m.json"]).count_observer is None
