import numpy as np
import pytest

from teleop_force.errors import DataError
from teleop_force.identification.least_squares import least_squares, relative_rms


def test_least_squares_recovers_parameters_with_honest_deviations() -> None:
    rng = np.random.default_rng(0)
    theta = np.array([1.0, -2.0, 0.5])
    y = rng.normal(size=(5000, 2, 3))
    noise = np.array([0.01, 0.1])
    tau = np.einsum("kjp,p->kj", y, theta) + rng.normal(size=(5000, 2)) * noise
    fit = least_squares(y, tau, ["a", "b", "c"])
    z = (fit.parameters - theta) / fit.standard_deviations
    assert np.all(np.abs(z) < 5)
    assert np.all(fit.standard_deviations < 1e-3)
    assert fit.condition_number < 2
    assert fit.relative_rms.shape == (2,)
    assert "a1" in fit.table()


def test_least_squares_rejects_nan_and_too_few_samples() -> None:
    y = np.ones((2, 1, 3))
    with pytest.raises(DataError):
        least_squares(y, np.ones((2, 1)), ["a", "b", "c"])
    y = np.ones((10, 1, 1))
    tau = np.ones((10, 1))
    tau[3] = np.nan
    with pytest.raises(DataError):
        least_squares(y, tau, ["a"])


def test_relative_rms() -> None:
    x = np.array([[1.0], [-1.0]])
    np.testing.assert_allclose(relative_rms(x, 0.9 * x), [0.1])
