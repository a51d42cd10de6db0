import numpy as np
import pytest

import teleop_force.identification.guards as guards
from teleop_force.errors import ConfigurationError, DataError, ModelError
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.guards import (
    fit_failure,
    identify_guarded,
    split_in_time,
)
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.omni import omni_description
from teleop_force.simulation import rigid_body_protocol


@pytest.fixture(scope="module")
def session_recording() -> Recording:
    session = rigid_body_protocol(24.0, 3)
    return Recording(session.t_s, session.q_rad, session.tau_nm)


def test_fit_failure_names_every_failed_joint_and_its_cause() -> None:
    assert fit_failure(np.array([0.2, 0.99, 1.0])) is None
    cause = fit_failure(np.array([0.2, 1.15, np.nan]))
    assert cause is not None
    assert "joint 2" in cause and "115.0 %" in cause and "joint 3" in cause
    assert "not finite" in cause and "joint 1" not in cause


def test_split_in_time_keeps_order_and_refuses_bad_fractions() -> None:
    t = np.arange(100) * 1e-3
    rec = Recording(t, np.zeros((100, 1)), np.ones((100, 1)))
    first, last = split_in_time(rec, 0.25)
    assert first.t_s.size == 75 and last.t_s.size == 25 and last.t_s[0] > first.t_s[-1]
    with pytest.raises(ConfigurationError):
        split_in_time(rec, 1.0)
    with pytest.raises(DataError):
        split_in_time(Recording(t[:3], np.zeros((3, 1)), np.ones((3, 1))), 0.5)


def test_wn_kept_only_on_joints_where_it_beats_the_coupled_cv(
    session_recording: Recording,
) -> None:
    model, report, guard = identify_guarded([session_recording], omni_description(), "wn")
    assert guard.chosen == "wn" and guard.fallbacks == ()
    assert guard.wn_joints is not None and guard.cv_relative_rms is not None
    wn = guard.check_relative_rms["wn"]
    for j, keep in enumerate(guard.wn_joints):
        assert keep == (wn[j] < guard.cv_relative_rms[j])
        network = model.friction
        assert isinstance(network, WaveletNetwork)
        if not keep:
            assert not np.any(network.joint_parameters(j))
    assert report.details["guards"]["wn_joints"] == list(guard.wn_joints)


def test_a_failed_fit_falls_back_to_the_next_simpler_friction(
    session_recording: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = guards.evaluate_model

    def failing_wn(model, recordings, blend=True):  # type: ignore[no-untyped-def]
        result = real(model, recordings, blend)
        if model.friction.kind == "wn":
            result = {**result, "relative_rms": np.array([0.3, 1.4, 0.2])}
        return result

    monkeypatch.setattr(guards, "evaluate_model", failing_wn)
    model, _, guard = identify_guarded([session_recording], omni_description(), "wn")
    assert guard.chosen == "coupled-cv" and model.friction.kind == "coupled-cv"
    assert [f.friction for f in guard.fallbacks] == ["wn"]
    assert "joint 2" in guard.fallbacks[0].cause
    assert any("fallback: wn refused" in line for line in guard.lines())


def test_every_friction_failing_is_reported_or_an_error(
    session_recording: Recording, monkeypatch: pytest.MonkeyPatch
) -> None:
    def nothing_fits(model, recordings, blend=True):  # type: ignore[no-untyped-def]
        return {"relative_rms": np.array([np.nan, 0.1, 0.1])}

    monkeypatch.setattr(guards, "evaluate_model", nothing_fits)
    with pytest.raises(ModelError, match=r"coupled-cv.*cv: joint 1"):
        identify_guarded([session_recording], omni_description(), "coupled-cv", strict=True)
    model, report, guard = identify_guarded([session_recording], omni_description(), "coupled-cv")
    assert guard.chosen == "cv" and model.friction.kind == "cv"
    assert guard.failed is not None and "cv: joint 1: check error not finite" in guard.failed
    assert report.details["guards"]["failed"] == guard.failed
    assert guard.lines()[-1].startswith("warning: every friction failed")
