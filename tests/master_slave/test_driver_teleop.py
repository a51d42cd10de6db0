"""The force commanded to a master driver: -scale F, clipped, zero when stale or not a number."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from master_slave.driver_teleop import FeedbackConfig, feedback_force_n
from teleop_force.errors import ConfigurationError

_CONFIG = FeedbackConfig(scale=0.5, max_force_n=2.0, stale_s=0.05)
_FORCE = st.lists(st.floats(-50.0, 50.0), min_size=3, max_size=3).map(np.array)


@given(_FORCE, st.floats(0.0, 0.05))
def test_fresh_estimate_is_opposed_scaled_and_clipped(estimate: np.ndarray, age_s: float) -> None:
    force = feedback_force_n(estimate, age_s, _CONFIG)
    assert np.linalg.norm(force) <= _CONFIG.max_force_n * (1.0 + 1e-12)
    expected = -_CONFIG.scale * estimate
    norm = float(np.linalg.norm(expected))
    if norm <= _CONFIG.max_force_n:
        np.testing.assert_array_equal(force, expected)
    else:  # same direction, shortened
        np.testing.assert_allclose(force, expected * (_CONFIG.max_force_n / norm), rtol=1e-12)


@given(_FORCE, st.floats(0.0501, 1e6) | st.none())
def test_stale_or_missing_estimate_commands_zero(estimate: np.ndarray, age_s: float | None) -> None:
    np.testing.assert_array_equal(feedback_force_n(estimate, age_s, _CONFIG), np.zeros(3))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_estimate_not_a_number_commands_zero(bad: float) -> None:
    estimate = np.array([1.0, bad, 0.0])
    np.testing.assert_array_equal(feedback_force_n(estimate, 0.0, _CONFIG), np.zeros(3))
    np.testing.assert_array_equal(feedback_force_n(np.ones(3), math.nan, _CONFIG), np.zeros(3))


@pytest.mark.parametrize(
    "kwargs",
    [{"scale": 1.5}, {"max_force_n": 0.0}, {"stale_s": math.nan}, {"rate_hz": -1.0},
     {"master": "no-dash"}, {"duration_s": 0.0}],
)  # fmt: skip
def test_config_refuses_bad_values(kwargs: dict) -> None:
    with pytest.raises(ConfigurationError):
        FeedbackConfig(**kwargs)
