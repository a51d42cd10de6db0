"""The shipped model's protocol: the paper's network, on which the residual watch was measured."""

import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.models.make_default import ProtocolConfig


def test_the_shipped_network_is_the_papers_not_identifys_default():
    assert ProtocolConfig().wn_structure == "alone"
    shipped = DynamicModel.load(DEFAULT_MODEL_PATH)
    assert isinstance(shipped.friction, WaveletNetwork)
    assert shipped.friction.on_fallback is False


def test_the_protocol_checks_the_network_structure():
    assert ProtocolConfig(wn_structure="on-cv").wn_structure == "on-cv"
    with pytest.raises(ConfigurationError, match="wn structure"):
        ProtocolConfig(wn_structure="beside")
