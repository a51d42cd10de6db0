"""Sensorless contact-force estimation for teleoperated haptic robots.

The front door: identify a model from recordings, estimate contact forces sample by sample,
close the loop on what the model lacks. Zenoh keys and wire messages live in
:mod:`teleop_force.transport.keys` and :mod:`teleop_force.transport.messages`; the simulated Omni in
:mod:`teleop_force.simulation`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: Where each public name lives; imported on first use so that processes start fast.
_LOCATIONS = {
    "BaseParameters": "teleop_force.identification.regressor",
    "ConfigurationError": "teleop_force.errors",
    "CoulombViscous": "teleop_force.friction.coulomb_viscous",
    "CoupledCoulombViscous": "teleop_force.friction.coulomb_viscous",
    "CoverageMap": "teleop_force.friction.coverage",
    "DataError": "teleop_force.errors",
    "Device": "teleop_force.robots.device",
    "DynamicModel": "teleop_force.identification.dynamic_model",
    "FilterConfig": "teleop_force.identification.filtered_regressor",
    "ForceEstimate": "teleop_force.estimation.estimator",
    "ForceEstimator": "teleop_force.estimation.estimator",
    "FrictionModel": "teleop_force.friction.base",
    "Identification": "teleop_force.identification.least_squares",
    "LowPass": "teleop_force.lowpass",
    "LyapunovAdapter": "teleop_force.friction.adaptation",
    "MessageError": "teleop_force.errors",
    "ModelError": "teleop_force.errors",
    "ModelFileError": "teleop_force.errors",
    "Recording": "teleop_force.io.interchange_csv",
    "ResidualReport": "teleop_force.residual.report",
    "RigidBodyRegressor": "teleop_force.identification.regressor",
    "Robot": "teleop_force.robots.description",
    "RobotDescription": "teleop_force.robots.description",
    "SessionReader": "teleop_force.io.mcap_session",
    "SessionWriter": "teleop_force.io.mcap_session",
    "SingularityError": "teleop_force.errors",
    "TeleopForceError": "teleop_force.errors",
    "TransportError": "teleop_force.errors",
    "WaveletNetwork": "teleop_force.friction.wavelet_network",
    "evaluate_model": "teleop_force.identification.pipeline",
    "fit_batch": "teleop_force.friction.batch_fit",
    "identify_model": "teleop_force.identification.pipeline",
    "least_squares": "teleop_force.identification.least_squares",
    "omni_description": "teleop_force.robots.omni",
    "read_interchange_csv": "teleop_force.io.interchange_csv",
    "read_recording": "teleop_force.io.recordings",
    "relative_rms": "teleop_force.identification.least_squares",
    "resolve_robot": "teleop_force.robots.registry",
    "trace_residual": "teleop_force.residual.loop",
    "write_interchange_csv": "teleop_force.io.interchange_csv",
}

if TYPE_CHECKING:
    from teleop_force.errors import (
        ConfigurationError,
        DataError,
        MessageError,
        ModelError,
        ModelFileError,
        SingularityError,
        TeleopForceError,
        TransportError,
    )
    from teleop_force.estimation.estimator import ForceEstimate, ForceEstimator
    from teleop_force.friction.adaptation import LyapunovAdapter
    from teleop_force.friction.base import FrictionModel
    from teleop_force.friction.batch_fit import fit_batch
    from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
    from teleop_force.friction.coverage import CoverageMap
    from teleop_force.friction.wavelet_network import WaveletNetwork
    from teleop_force.identification.dynamic_model import DynamicModel
    from teleop_force.identification.filtered_regressor import FilterConfig
    from teleop_force.identification.least_squares import (
        Identification,
        least_squares,
        relative_rms,
    )
    from teleop_force.identification.pipeline import evaluate_model, identify_model
    from teleop_force.identification.regressor import BaseParameters, RigidBodyRegressor
    from teleop_force.io.interchange_csv import (
        Recording,
        read_interchange_csv,
        write_interchange_csv,
    )
    from teleop_force.io.mcap_session import SessionReader, SessionWriter
    from teleop_force.io.recordings import read_recording
    from teleop_force.lowpass import LowPass
    from teleop_force.residual.loop import trace_residual
    from teleop_force.residual.report import ResidualReport
    from teleop_force.robots.description import Robot, RobotDescription
    from teleop_force.robots.device import Device
    from teleop_force.robots.omni import omni_description
    from teleop_force.robots.registry import resolve_robot

__all__ = [
    "BaseParameters",
    "ConfigurationError",
    "CoulombViscous",
    "CoupledCoulombViscous",
    "CoverageMap",
    "DataError",
    "Device",
    "DynamicModel",
    "FilterConfig",
    "ForceEstimate",
    "ForceEstimator",
    "FrictionModel",
    "Identification",
    "LowPass",
    "LyapunovAdapter",
    "MessageError",
    "ModelError",
    "ModelFileError",
    "Recording",
    "ResidualReport",
    "RigidBodyRegressor",
    "Robot",
    "RobotDescription",
    "SessionReader",
    "SessionWriter",
    "SingularityError",
    "TeleopForceError",
    "TransportError",
    "WaveletNetwork",
    "evaluate_model",
    "fit_batch",
    "identify_model",
    "least_squares",
    "omni_description",
    "read_interchange_csv",
    "read_recording",
    "relative_rms",
    "resolve_robot",
    "trace_residual",
    "write_interchange_csv",
]


def __getattr__(name: str) -> Any:
    """Import a public name on first use (PEP 562)."""
    module = _LOCATIONS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """Public names."""
    return sorted(__all__)
