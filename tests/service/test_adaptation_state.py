"""The force service's adaptation switch: on, off, unavailable, and across model loads."""

import dataclasses

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service.adaptation_state import AdaptationState


@pytest.fixture(scope="module")
def base():
    """The shipped model with its wavelet network's coupled-CV fallback as the friction."""
    shipped = DynamicModel.load(DEFAULT_MODEL_PATH)
    assert isinstance(shipped.friction, WaveletNetwork)
    return dataclasses.replace(shipped, friction=shipped.friction.fallback)


def wn_estimator(base: DynamicModel) -> ForceEstimator:
    """An estimator of ``base`` with an (untrained) wavelet-network friction."""
    network = WaveletNetwork(3, omni_wavelet_specs(), fallback=base.friction)
    return ForceEstimator(
        DynamicModel(
            base.robot, base.n_joints, base.filter_config, base.base, base.base_values,
            base.base_std, network, base.offsets_nm,
        )
    )  # fmt: skip


def test_adaptation_is_unavailable_without_a_wavelet_network(base):
    cv = ForceEstimator(base)
    state = AdaptationState(cv)
    assert "coupled-cv" in state.note
    with pytest.raises(ConfigurationError, match="coupled-cv"):
        state.switch(True, cv)
    state.switch(False, cv)
    assert state.to_dict() == {
        "enabled": False, "available": False, "note": state.note, "samples": 0,
    }  # fmt: skip


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
    assert state.to_dict() == {"enabled": False, "available": True, "note": "", "samples": 0}
