"""The force service's adaptation switch: on, off, unavailable, and across model loads."""

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.service.adaptation_state import AdaptationState
from tests.service.adaptation_cases import shipped_cv_model, wn_estimator


@pytest.fixture(scope="module")
def base():
    """The shipped model with its wavelet network's coupled-CV fallback as the friction."""
    return shipped_cv_model()


def test_adaptation_is_unavailable_without_a_wavelet_network(base):
    cv = ForceEstimator(base)
    state = AdaptationState(cv)
    assert "coupled-cv" in state.note
    with pytest.raises(ConfigurationError, match="coupled-cv"):
        state.switch(True, cv)
    state.switch(False, cv)
    stats = state.to_dict()
    assert {k: stats[k] for k in ("enabled", "available", "note", "samples")} == {
        "enabled": False, "available": False, "note": state.note, "samples": 0,
    }  # fmt: skip
    assert stats["skipped_contact"] == 0 and stats["force_threshold_n"] == 0.5


def test_adaptation_switches_and_follows_model_loads(base):
    wn = wn_estimator(base)
    state = AdaptationState(wn)
    assert state.note == "" and state.adaptation is None and not state.enabled
    state.switch(True, wn)
    driver = state.adaptation
    assert state.enabled and driver is not None
    state.switch(False, wn)
    state.switch(True, wn)
    assert state.adaptation is driver  # made once, kept while the model runs
    other = wn_estimator(base)
    state.follow(other)  # still on, on the new model
    assert state.enabled and state.adaptation is not driver and state.adaptation is not None
    state.follow(ForceEstimator(base))  # off: the new model cannot be adapted
    assert not state.enabled and state.adaptation is None and "coupled-cv" in state.note
    state.follow(other)  # stays off
    assert not state.enabled and state.adaptation is None and state.note == ""
    stats = state.to_dict()
    assert (stats["enabled"], stats["available"], stats["note"]) == (False, True, "")
    assert stats["samples"] == 0 and stats["skipped_contact"] == 0
    assert not driver.running  # the old model's worker thread was stopped
