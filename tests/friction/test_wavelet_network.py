import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import ConfigurationError, ModelError, ModelFileError
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.model_file import friction_from_dict
from teleop_force.friction.wavelet_network import (
    WaveletJointSpec,
    WaveletNetwork,
    mexican_hat,
    omni_wavelet_specs,
    wavelet,
)


def omni_net(limit: float = 2.0) -> WaveletNetwork:
    return WaveletNetwork(3, omni_wavelet_specs(limit, limit))


def test_mexican_hat_values():
    assert mexican_hat(np.array([0.0])) == pytest.approx(1.0)
    assert mexican_hat(np.array([1.0])) == pytest.approx(0.0)
    assert mexican_hat(np.array([2.0])) == pytest.approx(-3.0 * np.exp(-2.0))
    # d-dimensional: a function of the norm only
    assert mexican_hat(np.array([0.6, 0.8])) == pytest.approx(0.0)
    assert mexican_hat(np.array([3.0, 4.0])) == pytest.approx(mexican_hat(np.array([5.0])))


def test_wavelet_dilation_and_translation():
    # psi_{m,n}(x) = 2^(-dm/2) psi(2^-m x - n): centre 2^m n, peak 2^(-dm/2)
    assert wavelet(np.array([0.75]), -2, [3]) == pytest.approx(2.0)
    assert wavelet(np.array([0.5, -0.5]), -1, [1, -1]) == pytest.approx(2.0)
    assert wavelet(np.array([0.25]), -2, [0]) == pytest.approx(2.0 * mexican_hat(np.array([1.0])))


@settings(max_examples=25, deadline=None)
@given(
    joint=st.integers(0, 2),
    seed=st.integers(0, 2**31 - 1),
    n_samples=st.integers(1, 40),
)
def test_vectorised_basis_matches_naive_loop(joint, seed, n_samples):
    net = omni_net()
    rng = np.random.default_rng(seed)
    sl = net.pool.joint_slice(joint)
    idx = rng.choice(np.arange(sl.start, sl.stop), size=25, replace=False)
    qd = rng.uniform(-2.5, 2.5, size=(n_samples, 3))
    spec = net.specs[joint]
    naive = np.array(
        [
            [
                wavelet(q[list(spec.inputs)], int(net.pool.m[k]), net.pool.n[k, : spec.d])
                for k in idx
            ]
            for q in qd
        ]
    )
    np.testing.assert_allclose(net.basis_at(joint, qd, idx), naive, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(net.pool.evaluate(qd, idx), naive, rtol=1e-12, atol=1e-12)


def test_pool_covers_region_with_one_ring():
    spec = WaveletJointSpec((0,), (-1.0,), (1.0,), -2, 0, 1e-5, 2e-5)
    net = WaveletNetwork(1, [spec])
    pool = net.pool
    for m, step in ((0, 1.0), (-1, 0.5), (-2, 0.25)):
        centres = np.sort(pool.centre[pool.m == m, 0])
        np.testing.assert_allclose(centres, np.arange(-1.0 - step, 1.0 + 1.5 * step, step))
    no_ring = WaveletNetwork(1, [spec], edge_ring=False).pool
    assert no_ring.size == pool.size - 6


def test_seeds_one_per_orthant_on_coarsest_dilation():
    net = omni_net()
    assert net.parameter_counts() == (2, 4, 4)
    for j in range(3):
        idx = net.active_global_indices(j)
        spec = net.specs[j]
        assert np.all(net.pool.m[idx] == spec.m_max)
        signs = {tuple(np.sign(net.pool.n[k, : spec.d])) for k in idx}
        assert len(signs) == 2**spec.d and all(0 not in s for s in signs)


def test_neighbours_across_dilations():
    spec = WaveletJointSpec((0, 1), (-3.0, -3.0), (3.0, 3.0), -3, 0, 1e-5, 2e-5)
    net = WaveletNetwork(2, [spec, spec])
    pool = net.pool

    def labels(m, n):
        k = pool.index_of(0, np.array([m]), np.array([n]))
        return {(int(pool.m[i]), *map(int, pool.n[i, :2])) for i in pool.neighbours(k)}

    even = labels(-1, [2, 0])
    same = {(-1, 2 + a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)} - {(-1, 2, 0)}
    finer = {(-2, 4 + a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)}
    coarser = {(0, 1 + a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)}
    assert even == same | finer | coarser
    odd = labels(-1, [1, 1])
    assert {k for k in odd if k[0] == 0} == {(0, a, b) for a in (0, 1) for b in (0, 1)}
    assert len(odd) == 8 + 9 + 4
    # never crosses into another joint's pool
    k = pool.index_of(0, np.array([0]), np.array([[1, 1]]))
    assert np.all(pool.joint[pool.neighbours(k)] == 0)


def test_parameters_follow_the_active_set():
    net = omni_net()
    assert net.parameters.size == 10
    with pytest.raises(ValueError):
        net.parameters[0] = 1.0  # read-only view: write through set_joint_parameters
    with pytest.raises(ModelError):
        net.parameters = np.zeros(3)
    net.set_joint_parameters(1, [1.0, 2.0, 3.0, 4.0])
    new = net.activate(net.pool.neighbours(net.active_global_indices(1)[:1]))
    assert net.parameter_counts()[1] == 4 + new.size
    assert np.count_nonzero(net.joint_parameters(1)) == 4
    assert len(net.parameter_names(1)) == net.parameter_counts()[1]
    assert net.joint_slice(2).start == 2 + 4 + new.size
    net.deactivate(new)
    np.testing.assert_array_equal(net.joint_parameters(1), [1.0, 2.0, 3.0, 4.0])


def random_structure(net: WaveletNetwork, per_joint: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for j in range(net.n_joints):
        sl = net.pool.joint_slice(j)
        idx = rng.choice(np.arange(sl.start, sl.stop), size=per_joint, replace=False)
        net.set_structure(j, idx, rng.normal(0.0, 1e-3, per_joint))


def test_torque_batch_single_and_basis_agree():
    net = omni_net()
    random_structure(net, 60)
    qd = np.random.default_rng(1).uniform(-2.0, 2.0, size=(3000, 3))
    batch = net.torque(qd)
    for j in range(3):
        np.testing.assert_allclose(
            batch[:, j], net.basis(j, qd) @ net.joint_parameters(j), atol=1e-15
        )
    for k in (0, 17, 2999):
        np.testing.assert_allclose(net.torque(qd[k]), batch[k], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(net.torque(qd[:3]), batch[:3], rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("on_fallback", [False, True])
def test_to_dict_round_trip_is_identical(on_fallback):
    net = WaveletNetwork(3, omni_wavelet_specs(2.0, 2.0), on_fallback=on_fallback)
    random_structure(net, 40, seed=3)
    net.fallback = CoupledCoulombViscous(3, ((0,), (1, 2), (1, 2)), np.arange(10) * 1e-3)
    net.coverage.add(np.random.default_rng(2).uniform(-1.0, 1.0, size=(500, 3)))
    data = json.loads(json.dumps(net.to_dict()))
    again = friction_from_dict(data)
    assert isinstance(again, WaveletNetwork)
    assert again.parameter_counts() == net.parameter_counts()
    np.testing.assert_array_equal(again.parameters, net.parameters)
    np.testing.assert_array_equal(again.active_global_indices(), net.active_global_indices())
    qd = np.random.default_rng(4).uniform(-2.0, 2.0, size=(200, 3))
    np.testing.assert_array_equal(again.torque(qd), net.torque(qd))
    np.testing.assert_array_equal(again.blended_torque(qd), net.blended_torque(qd))
    assert again.on_fallback is on_fallback
    assert again.to_dict() == data


def test_from_dict_rejects_bad_files():
    data = omni_net().to_dict()
    data["joints"][0]["active"] = [[0, 99]]
    with pytest.raises(ModelFileError):
        WaveletNetwork.from_dict(data)
    with pytest.raises(ModelFileError):
        WaveletNetwork.from_dict({"kind": "wn"})
    on_nothing = omni_net().to_dict() | {"on_fallback": True}  # and no fallback
    with pytest.raises(ModelFileError, match="fallback"):
        WaveletNetwork.from_dict(on_nothing)


def test_files_from_before_the_option_hold_the_papers_network():
    data = omni_net().to_dict()
    del data["on_fallback"]
    assert WaveletNetwork.from_dict(data).on_fallback is False


@pytest.mark.parametrize(
    "kwargs",
    [
        {"inputs": ()},
        {"x_min_rad_s": (1.0,)},
        {"m_min": 1},
        {"mu": 0.0},
        {"x_max_rad_s": (float("nan"),)},
    ],
)
def test_spec_validation(kwargs):
    base = {
        "inputs": (0,),
        "x_min_rad_s": (-1.0,),
        "x_max_rad_s": (1.0,),
        "m_min": -2,
        "m_max": 0,
        "mu": 1e-5,
        "theta": 2e-5,
    }
    base.update(kwargs)
    with pytest.raises(ConfigurationError):
        WaveletJointSpec(**base)


def test_network_needs_one_spec_per_joint():
    with pytest.raises(ModelError):
        WaveletNetwork(3, omni_wavelet_specs()[:2])
