import math
import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.friction import batch_fit
from teleop_force.friction.batch_fit import filtered_basis_normal_equations, fit_batch
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.lowpass import lowpass_batch
from tests.friction.wavelet_cases import exciting_velocities, fixed_network, small_specs


def test_batch_fit_recovers_known_network():
    truth = fixed_network(seed=4, per_joint=8)
    t, qd = exciting_velocities(60.0, seed=4)
    target_l = lowpass_batch(truth.torque(qd), t, 8.0)
    net = fixed_network(seed=11, per_joint=8)
    result = fit_batch(net, t, qd, target_l, wavelets="active", ridge=0.0, prune_tol_nm=0.0)
    np.testing.assert_allclose(net.parameters, truth.parameters, rtol=1e-6, atol=1e-9)
    assert np.all(result.relative_rms < 1e-6)
    assert net.fallback is not None
    assert net.coverage.total_samples(0) == np.count_nonzero(np.abs(qd[:, 0]) < 1.5)


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_batch_fit_runs_blas_on_one_thread_and_restores_the_count(monkeypatch):
    """The groups' threads see one BLAS thread (OpenBLAS busy-waits); the count comes back."""
    seen: list[tuple[str, list[int]]] = []
    original = batch_fit.filtered_basis_normal_equations

    def recording(*args, **kwargs):
        seen.append((threading.current_thread().name, _blas_threads()))
        return original(*args, **kwargs)

    monkeypatch.setattr(batch_fit, "filtered_basis_normal_equations", recording)
    truth = fixed_network(seed=4, per_joint=8)
    t, qd = exciting_velocities(5.0, seed=4)
    target_l = lowpass_batch(truth.torque(qd), t, 8.0)
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and all(count == 2 for count in before), "NumPy's BLAS should be seen"
        fit_batch(fixed_network(seed=11, per_joint=8), t, qd, target_l, wavelets="active")
        assert _blas_threads() == before
    assert len(seen) == 2  # the two pool geometries, each in its own worker thread
    assert all(
        name.startswith("fit_batch") and counts == [1] * len(before) for name, counts in seen
    )


def test_batch_fit_over_visited_pool_explains_the_target():
    truth = fixed_network(seed=6, per_joint=8)
    t, qd = exciting_velocities(30.0, seed=6)
    target_l = lowpass_batch(truth.torque(qd), t, 8.0)
    net = WaveletNetwork(3, small_specs())
    result = fit_batch(net, t, qd, target_l, max_wavelets_per_joint=120)
    assert all(0 < s <= 120 for s in result.sizes)
    assert np.all(result.relative_rms < 0.01)
    check = lowpass_batch(net.torque(qd), t, 8.0)
    rel = np.sqrt(np.mean((check - target_l) ** 2, 0) / np.mean(target_l**2, 0))
    np.testing.assert_allclose(rel, result.relative_rms, rtol=1e-3, atol=1e-6)


def test_normal_equations_match_lowpass_batch_on_irregular_time():
    net = fixed_network(seed=3)
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 3000))
    qd = rng.uniform(-1.0, 1.0, (t.size, 3))
    idx = net.active_global_indices(1)
    target = rng.normal(size=(t.size, 2))
    g, b, yy, rows = filtered_basis_normal_equations(
        net, 1, idx, t, qd, target, 8.0, row_stride=3, chunk_samples=700
    )
    basis_l = lowpass_batch(net.basis_at(1, qd, idx), t, 8.0)[::3]
    np.testing.assert_allclose(g, basis_l.T @ basis_l, rtol=1e-10)
    np.testing.assert_allclose(b, basis_l.T @ target[::3], rtol=1e-10)
    np.testing.assert_allclose(yy, np.sum(target[::3] ** 2, axis=0))
    assert rows == math.ceil(t.size / 3)


@pytest.mark.parametrize(
    ("change", "error"),
    [
        ({"qd": np.zeros((10, 2))}, DataError),
        ({"target_L": np.full((10, 3), np.nan)}, DataError),
        ({"wavelets": "all"}, ConfigurationError),
        ({"ridge": -1.0}, ConfigurationError),
        ({"row_stride": 0}, ConfigurationError),
        ({"chunk_samples": 0}, ConfigurationError),
    ],
)
def test_batch_fit_errors(change, error):
    net = WaveletNetwork(3, small_specs())
    t, qd = exciting_velocities(0.01)
    kwargs = {"t_s": t, "qd": qd, "target_L": np.zeros_like(qd)} | change
    with pytest.raises(error):
        fit_batch(net, **kwargs)
