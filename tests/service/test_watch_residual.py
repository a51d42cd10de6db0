"""The watch's own estimator: its choice, and pieces of a stream equal to the whole stream."""

from __future__ import annotations

import numpy as np
import pytest

from teleop_force.bench.data import palpation_arrays
from teleop_force.errors import ConfigurationError
from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import with_estimator
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.service.watch_residual import (
    WATCH_OBSERVER_HZ,
    WatchResidual,
    watch_estimator_model,
)


@pytest.fixture(scope="module")
def fast_model() -> DynamicModel:
    """The shipped model publishing with a faster estimator than the watch's."""
    model = DynamicModel.load(DEFAULT_MODEL_PATH)
    return with_estimator(
        model, "observer", 40.0, observer_prefilter_hz=40.0, observer_prefilter_stages=2
    )


def test_the_watch_estimator_ignores_the_models_choice(fast_model: DynamicModel) -> None:
    config = watch_estimator_model(fast_model).filter_config
    assert config.estimator == "observer"
    assert config.observer_hz == WATCH_OBSERVER_HZ
    assert config.estimator_prefilter == (fast_model.filter_config.velocity_cutoff_hz, 1)
    paper = with_estimator(fast_model, "filter")
    assert watch_estimator_model(paper).filter_config == config


def test_pieces_equal_the_whole_stream(fast_model: DynamicModel) -> None:
    data = palpation_arrays(4.0, seed=3)
    t, q, tau = data["t_s"], data["q_rad"], data["tau_nm"]
    run = np.zeros(t.size, dtype=np.int64)
    run[2600:] = 1  # a stream restart in the middle of a piece
    run_start = np.where(run == 0, t[0], t[2600])
    whole = BatchEstimator(watch_estimator_model(fast_model)).estimate(
        t, q, tau, [2600], stream_time_s=t - run_start
    )
    residual = WatchResidual(fast_model)
    pieces = []
    for a, b in ((0, 700), (700, 1900), (1900, 3100), (3100, t.size)):
        pieces.append(residual(t[a:b], q[a:b], tau[a:b], run[a:b], run_start[a:b]))
    for name in ("force_tip_in_base_n", "tau_external_nm", "tau_motor_filtered_nm"):
        joined = np.concatenate([getattr(p, name) for p in pieces])
        np.testing.assert_allclose(joined, getattr(whole, name), rtol=0.0, atol=1e-9)
    # the published (faster) estimator would have given other values: the test can fail
    published = BatchEstimator(fast_model).estimate(t, q, tau, [2600])
    assert np.max(np.abs(published.tau_external_nm - whole.tau_external_nm)) > 1e-4


def test_reset_restarts_the_filters(fast_model: DynamicModel) -> None:
    data = palpation_arrays(2.0, seed=4)
    t, q, tau = data["t_s"], data["q_rad"], data["tau_nm"]
    run, start = np.zeros(t.size, dtype=np.int64), np.full(t.size, t[0])
    residual = WatchResidual(fast_model)
    residual(t[:1000], q[:1000], tau[:1000], run[:1000], start[:1000])
    residual.reset()
    after = residual(t[1000:], q[1000:], tau[1000:], run[1000:], start[1000:])
    alone = BatchEstimator(residual.model).estimate(
        t[1000:], q[1000:], tau[1000:], stream_time_s=t[1000:] - t[0]
    )
    np.testing.assert_array_equal(after.tau_external_nm, alone.tau_external_nm)


def test_refuses_an_empty_context(fast_model: DynamicModel) -> None:
    with pytest.raises(ConfigurationError, match="context_samples"):
        WatchResidual(fast_model, context_samples=0)
