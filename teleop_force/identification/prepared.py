"""Recordings prepared for identification (filtered once), and the wavelet training options.

The floor below both the pipeline (:mod:`teleop_force.identification.pipeline`) and the
wavelet-network training (:mod:`teleop_force.identification.wavelet_training`), which both use it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.friction.kinds import wn_on_fallback
from teleop_force.identification.filtered_regressor import (
    FilterConfig,
    FilteredSignals,
    filter_signals,
)
from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
from teleop_force.io.interchange_csv import Recording
from teleop_force.robots.description import RobotDescription


@dataclass(frozen=True)
class WaveletOptions:
    """How the wavelet-network friction is trained (``--friction wn``)."""

    method: str = "batch"
    passes: int = 3
    #: Train the network on what the stage-one coupled CV leaves and add it to that CV
    #: (:attr:`~teleop_force.friction.wavelet_network.WaveletNetwork.on_fallback`); False: the
    #: paper's network, the whole friction, blended with the CV off its trained ground.
    on_fallback: bool = True

    def __post_init__(self) -> None:
        if self.method not in ("adaptive", "batch"):
            raise ConfigurationError(
                f"wavelet training method must be adaptive or batch, got {self.method!r}"
            )
        if self.passes < 1:
            raise ConfigurationError("passes must be >= 1")


def wavelet_options_for(structure: str, method: str = "batch") -> WaveletOptions:
    """Return the options of the network structure called ``structure`` (``WN_STRUCTURES``)."""
    return WaveletOptions(method=method, on_fallback=wn_on_fallback(structure))


@dataclass(frozen=True, eq=False)
class PreparedRecording:
    """A recording with its filtered signals."""

    recording: Recording
    signals: FilteredSignals


def prepare(
    recordings: Sequence[Recording],
    description: RobotDescription,
    config: FilterConfig,
    base: BaseParameters | None = None,
) -> tuple[list[PreparedRecording], BaseParameters | None]:
    """Filter every recording with the rigid-body regressor of ``description``."""
    regressor = RigidBodyRegressor(description) if description.has_rigid_body else None
    if regressor is not None and base is None:
        base = regressor.find_base_parameters()
    prepared = []
    for rec in recordings:
        if rec.q_rad.shape[1] != description.n_joints:
            raise DataError(
                f"has {rec.q_rad.shape[1]} joints,"
                f" robot {description.name!r} has {description.n_joints}",
                path=rec.source,
            )
        signals = filter_signals(rec.t_s, rec.q_rad, rec.tau_nm, regressor, base, config)
        prepared.append(PreparedRecording(rec, signals))
    return prepared, base
