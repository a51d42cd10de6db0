"""The batch fit's fast path (compiled kernel, truncation, row stride, threads) against a
straightforward NumPy reference computed on the same small problems."""

import math

import numba
import numpy as np
import pytest
from numba.core import caching

from teleop_force.compiled import njit_cached
from teleop_force.friction import kernels
from teleop_force.friction.adaptation import LyapunovAdapter
from teleop_force.friction.batch_fit import (
    filtered_basis_normal_equations,
    fit_batch,
    wavelet_scores,
    wavelet_scores_of_targets,
)
from teleop_force.friction.kernels import FilteredWavelets
from teleop_force.friction.wavelet_network import WaveletJointSpec, WaveletNetwork
from teleop_force.identification.wavelet_training import batch_row_stride
from teleop_force.lowpass import lowpass_batch

CUTOFF_HZ = 8.0


def reference_psi(x: np.ndarray, centre_scaled: np.ndarray, inv_scale: np.ndarray,
                  amplitude: np.ndarray) -> np.ndarray:  # fmt: skip
    """amp (1 - r2) exp(-r2 / 2), one wavelet at a time, no truncation."""
    out = np.empty((x.shape[0], inv_scale.size))
    for k in range(inv_scale.size):
        r2 = np.sum((x * inv_scale[k] - centre_scaled[k]) ** 2, axis=1)
        out[:, k] = amplitude[k] * (1.0 - r2) * np.exp(-0.5 * r2)
    return out


def random_wavelets(rng: np.random.Generator, p: int, d: int) -> tuple[np.ndarray, ...]:
    m = rng.integers(-4, 1, p)
    centre = rng.integers(-12, 13, (p, d)).astype(float)
    centre[: p // 4] = centre[p // 2 : p // 2 + p // 4]  # shared lines and duplicates
    return centre, 2.0 ** (-m.astype(float)), 2.0 ** (-d * m / 2.0)


def wandering_velocities(rng: np.random.Generator, n: int, d: int) -> np.ndarray:
    """Slow random walks that visit wavelets and leave them far behind (r2 >> 80)."""
    return np.cumsum(rng.normal(0.0, 0.03, (n, d)), axis=0) + rng.uniform(-2, 2, d)


@pytest.mark.parametrize("d", [1, 2, 3])
@pytest.mark.parametrize("stride", [1, 3, 10])
def test_filtered_rows_equal_the_reference(d, stride):
    rng = np.random.default_rng(10 * d + stride)
    centre, inv, amp = random_wavelets(rng, 120, d)
    n = 4000
    t = np.arange(n) / 1000.0
    x = wandering_velocities(rng, n, d)
    reference = lowpass_batch(reference_psi(x, centre, inv, amp), t, CUTOFF_HZ)
    a = np.full(n, math.exp(-2.0 * math.pi * CUTOFF_HZ / 1000.0))
    a[0] = 0.0
    wavelets = FilteredWavelets(centre, inv, amp)
    chunks = []
    for start in range(0, n, 700):  # chunks carry the filter state over
        stop = min(start + 700, n)
        keep = np.arange(start + (-start) % stride, stop, stride) - start
        chunks.append(wavelets.rows(x[start:stop], a[start:stop], keep))
    rows = np.concatenate(chunks)[:, np.argsort(wavelets.order)]
    scale = np.abs(reference).max()
    np.testing.assert_allclose(rows, reference[::stride], rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(wavelets.state, reference[-1], rtol=0, atol=1e-13 * scale)
    # the truncation was exercised: some wavelets were far from some samples
    assert np.any(np.abs(reference) < 1e-16 * scale)


def test_normal_equations_equal_the_reference_on_irregular_time():
    net = WaveletNetwork(3, [
        WaveletJointSpec((0,), (-1.5,), (1.5,), -3, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -3, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -3, 0, 1e-4, 2e-4),
    ])  # fmt: skip
    rng = np.random.default_rng(5)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 5000))
    qd = np.clip(wandering_velocities(rng, t.size, 3), -1.6, 1.6)
    target = rng.normal(size=(t.size, 2))
    for joint in (0, 1):
        sl = net.pool.joint_slice(joint)
        pool_size = sl.stop - sl.start
        idx = sl.start + np.sort(rng.choice(pool_size, min(80, pool_size), replace=False))
        for stride in (1, 3):
            g, b, yy, rows = filtered_basis_normal_equations(
                net, joint, idx, t, qd, target, CUTOFF_HZ, row_stride=stride, chunk_samples=777
            )
            x = qd[:, list(net.specs[joint].inputs)]
            pool = net.pool
            d = net.specs[joint].d
            psi = reference_psi(x, pool.centre_scaled[idx, :d], pool.inv_scale[idx],
                                pool.amplitude[idx])  # fmt: skip
            basis_l = lowpass_batch(psi, t, CUTOFF_HZ)[::stride]
            gram = basis_l.T @ basis_l
            np.testing.assert_allclose(g, gram, rtol=0, atol=1e-12 * np.abs(gram).max())
            rhs = basis_l.T @ target[::stride]
            np.testing.assert_allclose(b, rhs, rtol=0, atol=1e-12 * np.abs(rhs).max())
            np.testing.assert_allclose(yy, np.sum(target[::stride] ** 2, axis=0), rtol=1e-12)
            assert rows == len(range(0, t.size, stride))


def test_fit_batch_equals_a_straightforward_ridge_solve():
    """The whole batch fit (threads, shared Gram of joints 2/3) against NumPy on its candidates."""
    rng = np.random.default_rng(7)
    specs = [
        WaveletJointSpec((0,), (-1.5,), (1.5,), -2, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -2, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -2, 0, 1e-4, 2e-4),
    ]
    n = 6000
    t = np.arange(n) / 1000.0
    qd = np.clip(wandering_velocities(rng, n, 3) * 0.7, -1.5, 1.5)
    target = lowpass_batch(np.tanh(3 * qd) * [0.05, 0.03, -0.02] + 0.01 * qd**2, t, CUTOFF_HZ)
    net = WaveletNetwork(3, specs)
    ridge = 1e-6
    result = fit_batch(net, t, qd, target, ridge=ridge, prune_tol_nm=0.0, row_stride=3,
                       min_visits=20, max_wavelets_per_joint=40, fit_fallback=False)  # fmt: skip
    assert result.candidates == result.sizes
    for joint in range(3):
        idx = net.active_global_indices(joint)
        d = specs[joint].d
        x = qd[:, list(specs[joint].inputs)]
        pool = net.pool
        psi = reference_psi(x, pool.centre_scaled[idx, :d], pool.inv_scale[idx],
                            pool.amplitude[idx])  # fmt: skip
        basis_l = lowpass_batch(psi, t, CUTOFF_HZ)[::3]
        gram = basis_l.T @ basis_l
        reg = gram + ridge * np.mean(np.diag(gram)) * np.eye(idx.size)
        coef = np.linalg.solve(reg, basis_l.T @ target[::3, joint])
        np.testing.assert_allclose(net.joint_parameters(joint), coef, rtol=1e-7,
                                   atol=1e-9 * np.abs(coef).max())  # fmt: skip


def test_scores_of_several_targets_are_the_single_scores_bit_for_bit():
    net = WaveletNetwork(3, [WaveletJointSpec((0, 1), (-1.0, -1.0), (1.0, 1.0), -2, 0, 1, 1)] * 3)
    rng = np.random.default_rng(3)
    qd = rng.uniform(-1.1, 1.1, (3000, 3))
    targets = rng.normal(size=(3000, 2))
    together = wavelet_scores_of_targets(net, 1, qd, targets)
    for c in range(2):
        assert np.array_equal(together[c], wavelet_scores(net, 1, qd, targets[:, c]))
    targets[5, 1] = np.nan  # different samples count for each target: one at a time
    together = wavelet_scores_of_targets(net, 1, qd, targets)
    for c in range(2):
        assert np.array_equal(together[c], wavelet_scores(net, 1, qd, targets[:, c]))


def test_kernel_compiles_without_a_writable_cache(monkeypatch):
    monkeypatch.setattr(caching.CacheImpl, "_locator_classes", [])
    with pytest.raises(RuntimeError):  # what numba does when no cache location is writable
        numba.njit(cache=True)(lambda v: v + 1)

    def twice(v: float) -> float:
        return 2.0 * v

    compiled = njit_cached()(twice)
    assert compiled(2.0) == 4.0
    assert kernels.warm_up() >= 0.0


@pytest.mark.parametrize(
    ("rate_hz", "cutoff_hz", "stride"),
    [(1000.0, 8.0, 3), (500.0, 8.0, 1), (2000.0, 8.0, 5), (4000.0, 8.0, 11), (100.0, 8.0, 1)],
)
def test_batch_row_stride_is_odd_and_keeps_40_rows_per_cutoff_period(rate_hz, cutoff_hz, stride):
    assert batch_row_stride(rate_hz, cutoff_hz) == stride


def test_first_call_compiles_in_a_fresh_cache(tmp_path):
    """A fresh checkout: nothing cached, the first call compiles (and caches) the kernel."""
    import os
    import subprocess
    import sys

    code = (
        "from teleop_force.friction import kernels; s = kernels.warm_up(); "
        "print(kernels._filtered_rows.stats.cache_misses.total(), s)"
    )
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=300, check=True)  # fmt: skip
    misses, seconds = proc.stdout.split()
    assert int(misses) == 1 and float(seconds) > 0.0
    assert any(tmp_path.rglob("*.nbi"))  # and left its compiled code in the cache


@pytest.mark.parametrize("bound", [100.0, 0.02])
def test_compiled_adaptation_run_equals_the_step_by_step_recursion(bound):
    """run() (compiled) against step() (NumPy), 1-, 2- and 3-input networks, with structure
    changes and, for the small bound, the projection active."""
    specs = [
        WaveletJointSpec((0,), (-1.5,), (1.5,), -2, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-1.5, -1.5), (1.5, 1.5), -2, 0, 1e-4, 2e-4),
        WaveletJointSpec((0, 1, 2), (-1.5,) * 3, (1.5,) * 3, -1, 0, 1e-4, 2e-4),
    ]
    rng = np.random.default_rng(2)
    n = 1500
    t = np.arange(n) / 1000.0
    qd = np.clip(wandering_velocities(rng, n, 3) * 0.5, -1.4, 1.4)
    p_l = np.cumsum(rng.normal(0.0, 1e-5, (n, 3)), axis=0)
    u_l = 0.05 * np.sin(2 * np.pi * 0.7 * t)[:, None] * np.array([1.0, -0.5, 0.8])
    kwargs = {"gamma": 2.0, "inertia_kgm2": 1e-3, "removal_time_s": 0.02, "bound_B": bound}
    net_a = WaveletNetwork(3, specs)
    result = LyapunovAdapter(net_a, **kwargs).run(t, qd, p_l, u_l)
    assert np.all(result.included > 0) and np.sum(result.excluded) > 0
    net_b = WaveletNetwork(3, specs)
    adapter_b = LyapunovAdapter(net_b, **kwargs)
    errors = np.array([adapter_b.step(qd[k], p_l[k], u_l[k], 1e-3) for k in range(n)])
    np.testing.assert_allclose(errors, result.prediction_error, rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(net_a.active_global_indices(), net_b.active_global_indices())
    np.testing.assert_allclose(net_a.parameters, net_b.parameters, rtol=1e-9, atol=1e-15)
    for j in range(3):
        assert np.linalg.norm(net_a.joint_parameters(j)) <= bound * (1 + 1e-12)
