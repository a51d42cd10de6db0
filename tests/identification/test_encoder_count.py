"""The encoder count measured on recordings, and the estimator that goes with it."""

from __future__ import annotations

import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.identification.encoder_count import (
    COUNT_OBSERVER_HZ,
    COUNT_OUTPUT_HZ,
    measured_count_rad,
    with_count_observer,
)
from teleop_force.identification.filtered_regressor import FilterConfig


def _readings(counts, n: int = 2000, seed: int = 0) -> np.ndarray:
    """A smooth random motion read by encoders of ``counts`` (floored, as some encoders)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, n)[:, None]
    q = np.sin(2.0 * np.pi * rng.uniform(0.3, 1.0, len(counts)) * t) * 0.3
    return np.floor(q / np.asarray(counts)) * np.asarray(counts)


def test_the_count_is_the_smallest_step_between_readings() -> None:
    counts = (5.2e-4, 4.6e-4, 4e-4)
    np.testing.assert_allclose(measured_count_rad(_readings(counts)), counts, rtol=1e-9)
    # several recordings: each its own steps, none across the seam
    parts = [_readings(counts, seed=1), _readings(counts, n=1500, seed=2) + 1.0]
    np.testing.assert_allclose(measured_count_rad(parts), counts, rtol=1e-9)


def test_a_joint_that_never_moves_is_named() -> None:
    q = _readings((4e-4, 4e-4, 4e-4))
    q[:, 1] = q[0, 1]
    with pytest.raises(DataError, match="joint 2"):
        measured_count_rad(q)
    with pytest.raises(DataError, match="two samples"):
        measured_count_rad(q[:1])


def test_with_count_observer_sets_the_observer_and_its_estimator() -> None:
    config = with_count_observer(FilterConfig(), (4e-4, 4e-4, 4e-4))
    assert config.count_observer and config.count_rad == (4e-4, 4e-4, 4e-4)
    assert config.observer and config.observer_hz == COUNT_OBSERVER_HZ
    assert config.observer_output_hz == COUNT_OUTPUT_HZ
    assert config.cutoff_hz == FilterConfig().cutoff_hz  # the identification's filters kept
