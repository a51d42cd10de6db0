import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.friction.adaptation import LyapunovAdapter
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.lowpass import lowpass_batch
from tests.friction.wavelet_cases import FS_HZ, exciting_velocities, fixed_network, small_specs


def filtered_plant(truth: WaveletNetwork, t: np.ndarray, qd: np.ndarray) -> tuple:
    """p_L, u_L of the filtered dynamics d/dt p_L = u_L - Psi_L c* (Euler, eps = 0)."""
    friction_l = lowpass_batch(truth.torque(qd), t, 8.0)
    u_l = 0.05 * np.sin(2 * np.pi * 0.3 * t)[:, None] * np.array([1.0, -0.5, 0.8])
    dt = np.diff(t)[:, None]
    p_l = np.zeros_like(qd)
    p_l[1:] = np.cumsum(dt * (u_l[:-1] - friction_l[:-1]), axis=0)
    return p_l, u_l


def test_adaptation_converges_to_true_coefficients():
    truth = fixed_network(seed=1)
    t, qd = exciting_velocities(40.0)
    p_l, u_l = filtered_plant(truth, t, qd)
    net = fixed_network(seed=1)
    net.parameters = np.zeros(net.parameters.size)
    # the 1-D network's Gram matrix is ill-conditioned (eigenvalues 0.004..0.6): lower gain
    adapter = LyapunovAdapter(net, gamma=(1.0, 5.0, 5.0), inertia_kgm2=1e-3, update_structure=False)
    result = adapter.run(t, qd, p_l, u_l)
    scale = np.abs(truth.parameters).max()
    assert np.abs(net.joint_parameters(0) - truth.joint_parameters(0)).max() < 1e-2 * scale
    for j in (1, 2):
        assert np.abs(net.joint_parameters(j) - truth.joint_parameters(j)).max() < 1e-4 * scale
    assert np.all(result.final_error_rms < 0.02 * result.error_rms)
    assert result.final_sizes == truth.parameter_counts()


def test_lyapunov_sign_reduces_error_from_any_start():
    truth = fixed_network(seed=5)
    t, qd = exciting_velocities(10.0, seed=5)
    p_l, u_l = filtered_plant(truth, t, qd)
    net = fixed_network(seed=5)
    start = np.random.default_rng(9).normal(0.0, 0.02, net.parameters.size)
    net.parameters = start
    LyapunovAdapter(net, gamma=(1.0, 5.0, 5.0), inertia_kgm2=1e-3, update_structure=False).run(
        t, qd, p_l, u_l
    )
    for j in range(3):
        sl = net.joint_slice(j)
        before = np.linalg.norm(start[sl] - truth.joint_parameters(j))
        assert np.linalg.norm(net.joint_parameters(j) - truth.joint_parameters(j)) < 0.5 * before


def test_run_equals_step_by_step_including_structure_changes():
    truth = fixed_network(seed=2)
    t, qd = exciting_velocities(1.5, seed=2)
    p_l, u_l = filtered_plant(truth, t, qd)
    kwargs = {"gamma": 2.0, "inertia_kgm2": 1e-3, "removal_time_s": 0.02}
    net_a = WaveletNetwork(3, small_specs())
    result = LyapunovAdapter(net_a, **kwargs).run(t, qd, p_l, u_l)
    assert np.all(result.included > 0) and np.sum(result.excluded) > 0
    net_b = WaveletNetwork(3, small_specs())
    adapter_b = LyapunovAdapter(net_b, **kwargs)
    errors = np.array([adapter_b.step(qd[k], p_l[k], u_l[k], 1.0 / FS_HZ) for k in range(t.size)])
    np.testing.assert_allclose(errors, result.prediction_error, rtol=1e-6, atol=1e-15)
    np.testing.assert_array_equal(net_a.active_global_indices(), net_b.active_global_indices())
    np.testing.assert_allclose(net_a.parameters, net_b.parameters, rtol=1e-6, atol=1e-15)


@settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    bound=st.floats(1e-4, 5e-2),
    seed=st.integers(0, 2**31 - 1),
    gain=st.floats(0.1, 10.0),
)
def test_projection_keeps_coefficients_inside_the_ball(bound, seed, gain):
    rng = np.random.default_rng(seed)
    net = fixed_network(seed % 97)
    scale = rng.uniform(0.1, 3.0)
    net.parameters = net.parameters * scale
    truth_scale = rng.uniform(1.0, 30.0)
    truth = fixed_network(seed % 97)
    truth.parameters = truth.parameters * truth_scale
    t, qd = exciting_velocities(0.25, seed=seed % 13)
    p_l, u_l = filtered_plant(truth, t, qd)
    adapter = LyapunovAdapter(net, gamma=gain, inertia_kgm2=1e-3, bound_B=bound)
    for k in range(t.size):
        adapter.step(qd[k], p_l[k], u_l[k], 1.0 / FS_HZ)
        for j in range(3):  # a start outside the ball is projected at the first step
            assert np.linalg.norm(net.joint_parameters(j)) <= bound * (1.0 + 1e-12)
    # block processing honours the bound too
    result = adapter.run(t, qd, p_l, u_l)
    assert result.samples == t.size
    assert all(np.linalg.norm(net.joint_parameters(j)) <= bound * (1 + 1e-12) for j in range(3))


def zero_error_step(adapter: LyapunovAdapter, n_steps: int) -> None:
    """Steps at rest (qd far from every wavelet: Psi = 0) so coefficients do not adapt."""
    for _ in range(n_steps):
        adapter.step(np.full(3, 50.0), np.zeros(3), np.zeros(3), 1e-3)


def test_inclusion_when_coefficient_exceeds_mu():
    net = WaveletNetwork(3, small_specs())
    adapter = LyapunovAdapter(net, gamma=1.0, structure_interval=10)
    seed = net.active_global_indices(1)[0]
    zero_error_step(adapter, 10)
    assert net.parameter_counts() == (2, 4, 4)
    net.set_coefficients_at([seed], [2.0 * net.specs[1].mu])
    zero_error_step(adapter, 10)
    neighbours = net.pool.neighbours([seed])
    assert np.all(net.is_active(neighbours))
    new = neighbours[~np.isin(neighbours, net.pool.seeds)]
    np.testing.assert_array_equal(net.coefficients_at(new), 0.0)
    assert adapter.included[1] == new.size
    assert net.parameter_counts()[0] == 2 and net.parameter_counts()[2] == 4


def test_exclusion_is_gradual_and_only_when_decreasing():
    net = WaveletNetwork(3, small_specs())
    adapter = LyapunovAdapter(net, gamma=1.0, structure_interval=10, removal_time_s=0.05)
    theta = net.specs[0].theta
    seed = net.active_global_indices(0)[0]
    (victim,) = net.activate(net.pool.neighbours([seed])[:1])
    net.set_coefficients_at([victim], [0.5 * theta])
    zero_error_step(adapter, 10)  # first check: |c| < theta but not decreasing
    zero_error_step(adapter, 10)
    assert victim not in adapter.decaying_indices()
    net.set_coefficients_at([victim], [0.4 * theta])  # now decreasing
    zero_error_step(adapter, 10)
    assert victim in adapter.decaying_indices()
    values = []
    for _ in range(60):
        zero_error_step(adapter, 1)
        values.append(net.coefficients_at([victim])[0])
    values = np.array(values)
    assert not net.is_active([victim])[0]
    assert values[-1] == 0.0
    live = values[values > 0]
    assert live.size >= 40  # ~50 ms of decay, not a jump
    assert np.all(np.diff(live) < 0) and np.all(live[1:] / live[:-1] > 0.85)
    assert live[-1] < 0.01 * 0.4 * theta  # the final cut is < 1 % of the value
    assert adapter.excluded[0] == 1
    # seeds are kept even when small and decreasing
    net.set_coefficients_at([seed], [0.5 * theta])
    zero_error_step(adapter, 10)
    net.set_coefficients_at([seed], [0.1 * theta])
    zero_error_step(adapter, 100)
    assert net.is_active([seed])[0]


@pytest.mark.parametrize(
    "kwargs",
    [{"A_diag": 1.0}, {"gamma": (1.0, 2.0)}, {"bound_B": -1.0}, {"structure_interval": 0}],
)
def test_adapter_configuration_errors(kwargs):
    with pytest.raises(ConfigurationError):
        LyapunovAdapter(WaveletNetwork(3, small_specs()), **kwargs)


def test_adapter_data_errors():
    adapter = LyapunovAdapter(WaveletNetwork(3, small_specs()))
    t = np.arange(10) / FS_HZ
    with pytest.raises(DataError):
        adapter.run(t, np.zeros((10, 2)), np.zeros((10, 3)), np.zeros((10, 3)))
    with pytest.raises(DataError):
        adapter.step(np.zeros(3), np.zeros(3), np.zeros(3), 0.0)
