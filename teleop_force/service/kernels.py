"""The service's kernel groups for :mod:`teleop_force.process.warm_up`.

Each function builds what the service builds for a model file (``None``: the shipped model)
with the default estimator flags, and runs one group of its kernels on samples of the types
the stream feeds them, so numba's cache holds what the service then loads.
"""

from __future__ import annotations

from pathlib import Path

from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service.watch_residual import WatchResidual


def _model(model_path: Path | None) -> DynamicModel:
    return DynamicModel.load(DEFAULT_MODEL_PATH if model_path is None else model_path)


def compile_step(model_path: Path | None) -> None:
    """Compile the estimator's step (the fused step or its two halves) on tuples of floats."""
    ForceEstimator(_model(model_path)).warm_up("step")


def compile_observer(model_path: Path | None) -> None:
    """Compile the count observer on tuples of floats (nothing if the model has none)."""
    ForceEstimator(_model(model_path)).warm_up("observer")


def compile_watch(model_path: Path | None) -> None:
    """Compile the residual watch's batch estimator."""
    WatchResidual(_model(model_path)).warm_up()
