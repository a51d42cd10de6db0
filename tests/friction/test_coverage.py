import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import ConfigurationError, ModelError
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.coverage import (
    CoverageConfig,
    CoverageMap,
    density_trust,
    smoothed_density,
)
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.identification.training_trajectory import (
    VelocityRegion,
    region_coverage,
    training_trajectory,
)
from teleop_force.robots.omni import Q_MAX_RAD, Q_MIN_RAD

INPUTS = ((0,), (1, 2), (1, 2))
LO = ((-2.0,), (-2.0, -2.0), (-2.0, -2.0))
HI = ((2.0,), (2.0, 2.0), (2.0, 2.0))


def dense_training(n: int = 200_000, seed: int = 0) -> np.ndarray:
    """Velocities filling [-1, 1]^3 densely."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, 3))


def test_trust_zero_far_one_on_dense_ground():
    cov = CoverageMap(INPUTS, LO, HI)
    cov.add(dense_training())
    np.testing.assert_allclose(cov.trust(np.zeros(3)), 1.0)
    np.testing.assert_allclose(cov.trust(np.array([0.5, -0.5, 0.7])), 1.0)
    far = np.array([[1.9, 1.9, -1.9], [5.0, 5.0, 5.0], [-1.8, 1.8, 1.8]])
    np.testing.assert_allclose(cov.trust(far), 0.0)
    empty = CoverageMap(INPUTS, LO, HI)
    np.testing.assert_allclose(empty.trust(np.zeros((4, 3))), 0.0)


def test_trust_is_continuous_across_the_edge_of_training():
    cov = CoverageMap(INPUTS, LO, HI)
    cov.add(dense_training())

    def largest_jump(points: int) -> tuple[float, np.ndarray]:
        line = np.zeros((points, 3))
        line[:, 0] = np.linspace(0.0, 2.5, points)
        line[:, 1] = np.linspace(0.0, 2.5, points)
        w = cov.trust(line)
        assert np.all((w >= 0.0) & (w <= 1.0))
        return float(np.max(np.abs(np.diff(w, axis=0)))), w

    coarse, w = largest_jump(2001)
    fine, _ = largest_jump(20001)
    assert fine < 0.2 * coarse  # jumps shrink with the step: no discontinuity
    assert w[0, 0] == 1.0 and w[-1, 0] == 0.0
    assert np.any((w[:, 1] > 0.05) & (w[:, 1] < 0.95))  # a gradual ramp in between


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    extra=st.integers(1, 3000),
    centre=st.floats(-1.5, 1.5),
)
def test_trust_is_monotone_in_training_density(seed, extra, centre):
    rng = np.random.default_rng(seed)
    cov = CoverageMap(INPUTS, LO, HI)
    cov.add(rng.normal(centre, 0.3, size=(rng.integers(0, 3000), 3)))
    probe = rng.uniform(-2.5, 2.5, size=(300, 3))
    before = cov.trust(probe)
    cov.add(rng.normal(centre, 0.3, size=(extra, 3)))
    assert np.all(cov.trust(probe) >= before - 1e-12)


def test_fraction_on_trained_ground():
    cov = CoverageMap(INPUTS, LO, HI)
    cov.add(dense_training())
    inside = np.random.default_rng(1).uniform(-0.8, 0.8, size=(500, 3))
    outside = np.random.default_rng(2).uniform(1.6, 1.9, size=(500, 3))
    assert cov.fraction_on_trained_ground(inside, 1) == 1.0
    assert cov.fraction_on_trained_ground(outside, 1) == 0.0
    both = np.concatenate((inside, outside))
    assert cov.fraction_on_trained_ground(both, 0) == pytest.approx(0.5)


def test_coverage_round_trip():
    cov = CoverageMap(INPUTS, LO, HI, CoverageConfig(cells_per_axis_nd=20, trained_density=5.0))
    cov.add(dense_training(5000))
    again = CoverageMap.from_dict(json.loads(json.dumps(cov.to_dict())))
    probe = np.random.default_rng(3).uniform(-2.0, 2.0, size=(100, 3))
    np.testing.assert_array_equal(again.trust(probe), cov.trust(probe))
    assert again.grid_shape(0) == (80,) and again.grid_shape(1) == (20, 20)


def test_coverage_config_validation():
    with pytest.raises(ConfigurationError):
        CoverageConfig(untrained_density=5.0, trained_density=1.0)
    with pytest.raises(ConfigurationError):
        CoverageConfig(cell_size_1d_rad_s=0.0)


def trained_network(on_fallback: bool = False) -> WaveletNetwork:
    net = WaveletNetwork(3, omni_wavelet_specs(2.0, 2.0), on_fallback=on_fallback)
    rng = np.random.default_rng(0)
    for j in range(3):
        idx = net.active_global_indices(j)
        net.set_joint_parameters(j, rng.normal(0.0, 0.01, idx.size))
    net.fallback = CoupledCoulombViscous(3, INPUTS, rng.normal(0.0, 0.01, 10))
    net.coverage.add(dense_training())
    return net


def test_blended_torque_uses_fallback_off_ground_and_wn_on_ground():
    net = trained_network()
    off = np.array([[1.95, -1.9, 1.9], [3.0, 3.0, -3.0]])
    np.testing.assert_allclose(net.blended_torque(off), net.fallback.torque(off))
    on = np.random.default_rng(5).uniform(-0.8, 0.8, size=(50, 3))
    np.testing.assert_allclose(net.blended_torque(on), net.torque(on))
    mid = np.array([0.2, 1.2, -0.3])
    w = net.coverage_weight(mid)[0]
    expected = w * net.torque(mid) + (1 - w) * net.fallback.torque(mid)
    np.testing.assert_allclose(net.blended_torque(mid), expected)


def test_a_network_on_its_fallback_adds_to_it_where_it_was_trained():
    net = trained_network(on_fallback=True)
    off = np.array([[1.95, -1.9, 1.9], [3.0, 3.0, -3.0]])
    np.testing.assert_allclose(net.blended_torque(off), net.fallback.torque(off))
    on = np.random.default_rng(5).uniform(-0.8, 0.8, size=(50, 3))
    np.testing.assert_allclose(net.blended_torque(on), net.fallback.torque(on) + net.torque(on))
    mid = np.array([0.2, 1.2, -0.3])
    w = net.coverage_weight(mid)[0]
    assert 0.0 < w.min() < 1.0 or 0.0 < w.max() < 1.0  # partly trusted
    expected = net.fallback.torque(mid) + w * net.torque(mid)
    np.testing.assert_allclose(net.blended_torque(mid), expected)
    # what training and adaptation subtract from its target: the CV it adds to
    np.testing.assert_array_equal(net.base_torque(on), net.fallback.torque(on))
    assert net.structure == "on-cv"
    alone = trained_network()
    np.testing.assert_array_equal(alone.base_torque(on), np.zeros_like(on))
    assert alone.structure == "alone"


def test_blended_torque_needs_fallback():
    net = WaveletNetwork(3, omni_wavelet_specs())
    with pytest.raises(ModelError):
        net.blended_torque(np.zeros(3))


@pytest.mark.parametrize(
    "region",
    [
        VelocityRegion((-1.5, 1.5), (-1.5, 1.5), (-2.0, 2.0)),
        VelocityRegion((-0.5, 1.0), (0.3, 1.2), (-1.0, -0.2)),
    ],
)
def test_training_trajectory_fills_region_within_limits(region):
    traj = training_trajectory(region, 240.0)  # the paper recorded 4 minutes
    assert np.all(traj.q_rad >= Q_MIN_RAD) and np.all(traj.q_rad <= Q_MAX_RAD)
    numeric = np.gradient(traj.q_rad, traj.t_s, axis=0)
    np.testing.assert_allclose(numeric[1:-1], traj.qd_rad_s[1:-1], atol=1e-3)
    coverage = region_coverage(traj.qd_rad_s, region)
    assert coverage.qd1_fraction > 0.95 and coverage.qd23_fraction > 0.8


def test_region_coverage_counts_cells():
    region = VelocityRegion((0.0, 1.0), (0.0, 1.0), (0.0, 1.0))
    qd = np.array([[0.01, 0.01, 0.01], [0.99, 0.99, 0.99], [5.0, 5.0, 5.0]])
    cov = region_coverage(qd, region, cell_size_1d_rad_s=0.5, cells_2d=2)
    assert cov.qd1_fraction == 1.0 and cov.qd23_fraction == 0.5


def test_unreachable_region_is_a_configuration_error():
    with pytest.raises(ConfigurationError):
        VelocityRegion((1.0, 0.0), (0.0, 1.0), (0.0, 1.0))
    with pytest.raises(ConfigurationError):
        training_trajectory(VelocityRegion((-1, 1), (-1, 1), (-1, 1)), 10.0, margin_rad=2.0)


def test_trust_is_the_ramp_of_the_smoothed_counts():
    config = CoverageConfig(smoothing_cells=1.5, untrained_density=0.5, trained_density=9.0)
    cov = CoverageMap(INPUTS, LO, HI, config)
    cov.add(dense_training(20_000))
    for j in range(cov.n_joints):
        density = smoothed_density(cov.counts(j), config.smoothing_cells)
        np.testing.assert_array_equal(density, cov.density_grid(j))
        trust = density_trust(density, 0.5, 9.0)
        assert trust.shape == density.shape
        s = np.clip((density - 0.5) / 8.5, 0.0, 1.0)
        np.testing.assert_allclose(trust, s * s * (3.0 - 2.0 * s), rtol=0, atol=1e-15)
    counts = np.arange(12.0).reshape(3, 4)
    assert smoothed_density(counts, 0.0) is counts
