"""Models the adaptation tests share: the shipped model's CV fallback, an untrained network."""

import dataclasses

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH


def shipped_cv_model() -> DynamicModel:
    """The shipped model with its wavelet network's coupled-CV fallback as the friction."""
    shipped = DynamicModel.load(DEFAULT_MODEL_PATH)
    assert isinstance(shipped.friction, WaveletNetwork)
    return dataclasses.replace(shipped, friction=shipped.friction.fallback)


def wn_estimator(base: DynamicModel, on_fallback: bool = False) -> ForceEstimator:
    """An estimator of ``base`` with an (untrained) wavelet-network friction of its own.

    ``on_fallback``: the network adds to ``base``'s coupled CV instead of replacing it.
    """
    network = WaveletNetwork(
        3, omni_wavelet_specs(), fallback=base.friction, on_fallback=on_fallback
    )
    return ForceEstimator(
        DynamicModel(
            base.robot, base.n_joints, base.filter_config, base.base, base.base_values,
            base.base_std, network, base.offsets_nm,
        )
    )  # fmt: skip
