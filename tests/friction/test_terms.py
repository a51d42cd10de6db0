"""Each friction term has one definition: the batch methods and the one-sample (streaming)
calls agree to 1e-9 absolute on seeded random states, and both equal a NumPy reference."""

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from teleop_force.estimation.kernels import ModelTerms
from teleop_force.friction import terms
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.coverage import CoverageMap
from teleop_force.friction.model_coordinates import ModelCoordinateFriction
from teleop_force.friction.wavelet_network import (
    WaveletJointSpec,
    WaveletNetwork,
    mexican_hat,
    psi_block,
    wavelet_amplitude,
)
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig

#: The compiled terms against numpy's: ``.ci/run`` runs this module again as on another host.
pytestmark = pytest.mark.float_sensitive

ATOL = 1e-9


def _velocities(seed: int, n: int = 400, joints: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    qd = rng.normal(0.0, 1.0, size=(n, joints))
    qd[:10, 1] = qd[:10, 2]  # zero relative velocity
    qd[10:20, 0] = 0.0  # zero velocity
    return qd


def _one_sample(friction, qd: np.ndarray) -> np.ndarray:
    """Torque sample by sample through the term table, as the streaming estimator."""
    rows, reach = friction.term_table()
    out = np.zeros(qd.shape)
    for k in range(qd.shape[0]):
        terms.linear_friction_torque_into(qd[k], rows, reach, friction.parameters, out[k])
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coulomb_viscous_batch_streaming_and_reference_agree(seed):
    rng = np.random.default_rng(seed)
    qd = _velocities(seed)
    model = CoulombViscous(3, rng.normal(size=6))
    p = model.parameters.reshape(3, 2)
    reference = np.sign(qd) * p[:, 0] + qd * p[:, 1]
    np.testing.assert_allclose(model.torque(qd), reference, rtol=0, atol=1e-15)
    np.testing.assert_allclose(_one_sample(model, qd), model.torque(qd), rtol=0, atol=ATOL)
    np.testing.assert_allclose(model.torque(qd[3]), reference[3], atol=1e-15)
    for j in range(3):
        np.testing.assert_array_equal(
            model.basis(j, qd), np.stack((np.sign(qd[:, j]), qd[:, j]), 1)
        )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coupled_coulomb_viscous_batch_streaming_and_reference_agree(seed):
    rng = np.random.default_rng(seed)
    qd = _velocities(seed)
    model = CoupledCoulombViscous(3, ((0,), (1, 2), (1, 2)), rng.normal(size=10))
    rel = qd[:, 1] - qd[:, 2]
    reference_basis = [
        np.stack((np.sign(qd[:, 0]), qd[:, 0]), 1),
        np.stack((np.sign(qd[:, 1]), qd[:, 1], np.sign(rel), rel), 1),
        np.stack((np.sign(qd[:, 2]), qd[:, 2], np.sign(rel), rel), 1),
    ]
    reference = np.column_stack([reference_basis[j] @ model.joint_parameters(j) for j in range(3)])
    for j in range(3):
        np.testing.assert_array_equal(model.basis(j, qd), reference_basis[j])
    np.testing.assert_allclose(model.torque(qd), reference, rtol=0, atol=1e-14)
    np.testing.assert_allclose(_one_sample(model, qd), model.torque(qd), rtol=0, atol=ATOL)


def test_model_coordinate_friction_batch_streaming_and_reference_agree():
    rng = np.random.default_rng(4)
    coupling = np.array([[1.0, 0, 0], [0, 1, 0], [0, -1, 1], [0, 0.6697, 1]])
    model = ModelCoordinateFriction(coupling, rng.normal(size=8))
    qd = _velocities(4)
    w = qd @ model.axes.T
    p = model.parameters.reshape(model.n_axes, 2)
    reference = (np.sign(w) * p[:, 0] + w * p[:, 1]) @ model.axes
    np.testing.assert_allclose(model.torque(qd), reference, rtol=0, atol=1e-13)
    np.testing.assert_allclose(_one_sample(model, qd), model.torque(qd), rtol=0, atol=ATOL)


def test_sign_is_numpy_sign():
    values = np.array([-2.0, -0.0, 0.0, 1e-300, 3.0, np.inf, -np.inf])
    np.testing.assert_array_equal([terms.sign(v) for v in values], np.sign(values))
    assert np.isnan(terms.sign(np.nan))


def test_mexican_hat_single_definition_against_numpy():
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 3.0, size=(1000, 2))
    r2 = np.sum(x * x, axis=1)
    reference = (1.0 - r2) * np.exp(-0.5 * r2)
    np.testing.assert_allclose(mexican_hat(x), reference, rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(
        [terms.mexican_hat_r2(v, 2.0) for v in r2[:50]], 2.0 * reference[:50], rtol=1e-14
    )
    assert terms.mexican_hat_r2(0.0, 1.0) == 1.0 and terms.mexican_hat_r2(1.0, 1.0) == 0.0
    centre = rng.integers(-6, 7, size=(40, 2)).astype(float)
    inv = 2.0 ** rng.integers(0, 4, 40).astype(float)
    amp = inv.copy()
    block = psi_block(x[:100], centre, inv, amp)
    ref = np.stack([amp[p] * (1 - (s := np.sum((x[:100] * inv[p] - centre[p]) ** 2, 1)))
                    * np.exp(-0.5 * s) for p in range(40)], axis=1)  # fmt: skip
    np.testing.assert_allclose(block, ref, rtol=1e-13, atol=1e-15)


def _network(seed: int, on_fallback: bool = False) -> WaveletNetwork:
    specs = [
        WaveletJointSpec((0,), (-2.0,), (2.0,), -3, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-2.0, -2.0), (2.0, 2.0), -2, 0, 1e-4, 2e-4),
        WaveletJointSpec((1, 2), (-2.0, -2.0), (2.0, 2.0), -2, 0, 1e-4, 2e-4),
    ]
    fallback = CoupledCoulombViscous(3, ((0,), (1, 2), (1, 2)), np.linspace(0.01, 0.05, 10))
    net = WaveletNetwork(3, specs, fallback=fallback, on_fallback=on_fallback)
    rng = np.random.default_rng(seed)
    for j in range(3):
        sl = net.pool.joint_slice(j)
        idx = rng.choice(np.arange(sl.start, sl.stop), size=min(60, sl.stop - sl.start),
                         replace=False)  # fmt: skip
        net.set_structure(j, idx, rng.normal(0.0, 1e-2, idx.size))
    shared = net.active_global_indices(1)[:5]  # joint 3 shares some of joint 2's wavelets
    joint3 = np.union1d(net.active_global_indices(2), shared + net.pool.joint_offsets[2]
                        - net.pool.joint_offsets[1])  # fmt: skip
    net.set_structure(2, joint3, rng.normal(0.0, 1e-2, joint3.size))
    assert net.coverage is not None
    net.coverage.add(rng.uniform(-1.0, 1.0, size=(20_000, 3)))
    return net


@pytest.mark.parametrize(("seed", "on_fallback"), [(0, False), (1, False), (2, True)])
def test_wavelet_network_batch_and_streaming_agree(seed, on_fallback):
    net = _network(seed, on_fallback)
    qd = np.random.default_rng(seed + 10).uniform(-2.5, 2.5, size=(300, 3))
    batch = net.torque(qd)
    assert np.abs(batch).max() > 1e-3
    np.testing.assert_allclose([net.torque_one(v) for v in qd], batch, rtol=0, atol=ATOL)
    np.testing.assert_allclose(net.torque(qd[:3]), batch[:3], rtol=0, atol=1e-14)  # pool path
    for j in range(3):
        np.testing.assert_allclose(net.basis(j, qd) @ net.joint_parameters(j), batch[:, j],
                                   atol=1e-14)  # fmt: skip
    # the estimator's one compiled call: blended by the coverage trust
    model = DynamicModel("omni", 3, FilterConfig(), None, np.zeros(0), np.zeros(0), net,
                         np.zeros(3))  # fmt: skip
    model_terms = ModelTerms(model)
    zero = [0.0] * 3
    got = [model_terms(0.0, zero, v.tolist(), zero) for v in qd]
    np.testing.assert_allclose([g[0] for g in got], net.blended_torque(qd), rtol=0, atol=ATOL)
    np.testing.assert_allclose([g[1] for g in got], net.coverage.trust(qd), rtol=0, atol=ATOL)
    if on_fallback:  # the sum, not the paper's blend
        w = net.coverage.trust(qd)
        blend = w * batch + (1.0 - w) * net.fallback.torque(qd)
        assert np.abs(net.blended_torque(qd) - blend).max() > 1e-3


def _reference_density(coverage: CoverageMap, qd: np.ndarray, joint: int) -> np.ndarray:
    """The scipy formulation the compiled grid density replaced."""
    inputs, lo, cell, _ = coverage.grid_geometry(joint)
    coords = (qd[:, inputs] - lo) / cell - 0.5
    coords = np.where(np.isfinite(coords), coords, -1e9)
    values = map_coordinates(coverage.density_grid(joint), coords.T, order=1,
                             mode="grid-constant", cval=0.0)  # fmt: skip
    return np.maximum(values, 0.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_coverage_trust_inside_outside_and_at_the_edges(seed):
    inputs = ((0,), (1, 2), (0, 1, 2))
    lo = ((-2.0,), (-2.0, -1.5), (-1.0, -1.0, -1.0))
    hi = ((2.0,), (2.0, 1.5), (1.0, 1.0, 1.0))
    coverage = CoverageMap(inputs, lo, hi)
    rng = np.random.default_rng(seed)
    coverage.add(rng.normal(0.0, 0.9, size=(60_000, 3)))
    points = rng.uniform(-2.6, 2.6, size=(2000, 3))
    cells = [coverage.grid_geometry(j)[2] for j in range(3)]
    # on the bounds, half a cell inside (the outermost centres), one cell outside, corners
    edges = []
    for j, (lo_j, hi_j) in enumerate(zip(lo, hi, strict=True)):
        for offset in (0.0, 0.5, -0.5, -1.0, -1.5, 1e-12):
            p = np.zeros(3)
            p[list(inputs[j])] = np.asarray(lo_j) - offset * cells[j]
            edges.append(p.copy())
            p[list(inputs[j])] = np.asarray(hi_j) + offset * cells[j]
            edges.append(p.copy())
    points = np.vstack([points, edges, [[np.nan, 0.0, 0.0], [np.inf, -np.inf, 1e300]]])
    trust = coverage.trust(points)
    for j in range(3):
        density = coverage.density(points, j)
        np.testing.assert_allclose(density, _reference_density(coverage, points, j),
                                   rtol=1e-12, atol=1e-9)  # fmt: skip
        config = coverage.config
        ramp = (density - config.untrained_density) / (
            config.trained_density - config.untrained_density
        )
        s = np.clip(ramp, 0.0, 1.0)
        np.testing.assert_allclose(trust[:, j], s * s * (3 - 2 * s), atol=1e-15)
    assert 0.1 < np.mean(trust == 1.0) < 0.9 and np.mean(trust == 0.0) > 0.05
    # one sample at a time through the grid table of the streaming estimator
    net = WaveletNetwork(3, [WaveletJointSpec(s, lo_j, hi_j, -1, 0, 1e-4, 2e-4)
                             for s, lo_j, hi_j in zip(inputs, lo, hi, strict=True)],
                         fallback=CoupledCoulombViscous(3, ((0,), (1,), (2,))),
                         coverage=coverage)  # fmt: skip
    model = DynamicModel("omni", 3, FilterConfig(), None, np.zeros(0), np.zeros(0), net,
                         np.zeros(3))  # fmt: skip
    model_terms = ModelTerms(model)
    zero = [0.0] * 3
    finite = points[:-2]
    got = np.array([model_terms(0.0, zero, p.tolist(), zero)[1] for p in finite])
    np.testing.assert_allclose(got, trust[:-2], rtol=0, atol=ATOL)


def test_coverage_trust_values_is_the_scalar_ramp_over_an_array():
    rng = np.random.default_rng(6)
    density = np.concatenate([rng.uniform(-5.0, 30.0, 500), [1.0, 20.0, np.nan, np.inf]])
    got = terms.coverage_trust_values(density, 1.0, 20.0)
    np.testing.assert_array_equal(got, [terms.coverage_trust(v, 1.0, 20.0) for v in density])
    s = np.clip((density - 1.0) / 19.0, 0.0, 1.0)
    np.testing.assert_allclose(got, s * s * (3.0 - 2.0 * s), rtol=0, atol=1e-15)
    assert got[500] == 0.0 and got[501] == 1.0 and np.isnan(got[502]) and got[503] == 1.0


def test_wavelet_amplitude_of_ints_and_arrays_agree():
    d = np.array([1, 2, 2, 3], dtype=np.int64)
    m = np.array([-5, 0, 3, -2], dtype=np.int64)
    for a0 in (2.0, 1.7):
        arrays = wavelet_amplitude(a0, d, m)
        scalars = [wavelet_amplitude(a0, int(di), int(mi)) for di, mi in zip(d, m, strict=True)]
        np.testing.assert_array_equal(arrays, scalars)
        np.testing.assert_allclose(arrays, a0 ** (-d * m / 2.0), rtol=1e-15)
    assert wavelet_amplitude(2.0, 2, -3) == 8.0
