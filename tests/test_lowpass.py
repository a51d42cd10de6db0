import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import DataError
from teleop_force.lowpass import (
    FilteredDerivative,
    LowPass,
    filtered_derivative_batch,
    lowpass_batch,
)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    n=st.integers(3, 300),
    cutoff=st.floats(0.5, 100.0),
    uniform=st.booleans(),
)
def test_streaming_equals_batch(seed: int, n: int, cutoff: float, uniform: bool) -> None:
    rng = np.random.default_rng(seed)
    dt = np.full(n, 1e-3) if uniform else rng.uniform(5e-4, 2e-3, n)
    t = np.cumsum(dt)
    x = rng.normal(size=(n, 2))
    batch = lowpass_batch(x, t, cutoff)
    deriv = filtered_derivative_batch(x, t, cutoff)
    f, d = LowPass(cutoff), FilteredDerivative(cutoff)
    for k in range(n):
        step = 1e-3 if k == 0 else t[k] - t[k - 1]
        np.testing.assert_allclose(f.update(x[k], step), batch[k], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(d.update(x[k], step), deriv[k], rtol=1e-7, atol=1e-9)


def test_gain_and_phase_at_cutoff() -> None:
    t = np.arange(0, 4, 1e-4)
    x = np.sin(2 * np.pi * 8.0 * t)
    y = lowpass_batch(x, t, 8.0)[len(t) // 2 :]
    assert abs(np.sqrt(2 * np.mean(y**2)) - 1 / np.sqrt(2)) < 0.01


def test_filtered_derivative_of_a_ramp_tends_to_its_slope() -> None:
    t = np.arange(0, 1, 1e-3)
    d = filtered_derivative_batch(3.0 * t, t, 8.0)
    assert abs(d[-1] - 3.0) < 1e-6


def test_reset_forgets_state() -> None:
    f = LowPass(8.0)
    f.update(np.array([1.0]), 1e-3)
    f.update(np.array([5.0]), 1e-3)
    f.reset()
    assert f.update(np.array([2.0]), 1e-3)[0] == 2.0


def test_bad_time_is_reported_with_its_row() -> None:
    with pytest.raises(DataError, match="sample 2"):
        lowpass_batch(np.zeros(4), np.array([0.0, 1.0, 1.0, 2.0]), 8.0)
