"""The adaptation worker: batches equal the per-sample reference, the free-motion gate, threads."""

import dataclasses
import math

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError
from teleop_force.friction.model_file import friction_from_dict
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.service.adaptation import (
    AdaptationGate,
    AdaptationWorker,
    OnlineAdaptation,
    free_mask,
)
from teleop_force.service.adaptation_state import AdaptationState
from tests.service.adaptation_cases import shipped_cv_model, wn_estimator

THRESHOLD_N = 0.5


@pytest.fixture(scope="module")
def base():
    """The shipped model with its wavelet network's coupled-CV fallback as the friction."""
    return shipped_cv_model()


def simulated_stream(seed: int, n: int = 4000, restart: int = 2600):
    """Jittered 1 kHz samples of a moving arm with friction-like torques, a contact (2 N,
    samples 900-1199), one NaN force (sample 2000) and a stream restart (time from 0 again)."""
    rng = np.random.default_rng(seed)
    dt = 1e-3 * (1.0 + 0.05 * rng.standard_normal(n)).clip(0.5, 1.5)
    t = np.cumsum(dt)
    if restart < n:
        t[restart:] -= t[restart] - 0.001
    phase = rng.uniform(0, 2 * np.pi, 3)
    w = np.array([3.1, 2.3, 4.2])
    q = 0.3 * np.sin(np.outer(t, w) + phase) + np.array([0.0, 0.4, -0.3])
    qd = 0.3 * w * np.cos(np.outer(t, w) + phase)
    tau = 0.02 * np.sign(qd) + 0.01 * qd + 0.002 * rng.standard_normal((n, 3))
    tau += np.array([0.0, 0.05, 0.02])
    force = 0.1 * rng.standard_normal((n, 3))
    if n > 2000:
        force[900:1200] = [2.0, 0.0, 0.5]
        force[2000] = math.nan
    return t, q, tau, force, restart


@pytest.mark.parametrize(("on_fallback", "sticking"), [(False, False), (True, False), (True, True)])
def test_batches_equal_the_per_sample_reference_with_the_gate_and_a_restart(
    base, on_fallback, sticking
):
    """The worker's batches give the per-sample reference's network (a sticking fallback too)."""
    if sticking:
        fallback = friction_from_dict(base.friction.to_dict())
        fallback.set_sticking(0.002)
        base = dataclasses.replace(base, friction=fallback)
    t, q, tau, force, restart = simulated_stream(19)
    guard = 0.3
    contact = ~(np.linalg.norm(force, axis=1) < THRESHOLD_N)
    starts = np.zeros(t.size, dtype=bool)
    starts[[0, restart]] = True
    mask = free_mask(t, contact, starts, guard)
    assert 0 < mask.sum() < t.size  # the gate keeps some samples out
    stream = np.cumsum(starts)
    expected_mask = np.array(
        [
            not np.any(contact & (stream == stream[k]) & (np.abs(t - t[k]) <= guard))
            for k in range(t.size)
        ]
    )  # brute force: no contact of the same stream within the guard, either side
    np.testing.assert_array_equal(mask, expected_mask)
    assert not mask[900:1200].any() and not mask[2000] and mask[restart]

    reference_estimator = wn_estimator(base, on_fallback)
    reference = OnlineAdaptation(reference_estimator)
    for k in range(t.size):
        if k == restart:
            reference.reset()
        reference.update(t[k], q[k], tau[k], free=bool(mask[k]))

    estimator = wn_estimator(base, on_fallback)
    worker = AdaptationWorker(estimator, AdaptationGate(THRESHOLD_N, guard))
    rng = np.random.default_rng(5)
    k = 0
    while k < t.size:
        stop = min(t.size, k + int(rng.integers(1, 120)))
        for i in range(k, stop):
            if i == restart:
                worker.reset()
            worker.submit(float(t[i]), tuple(q[i]), tuple(tau[i]), list(force[i]))
        worker.drain()
        if rng.random() < 0.5:
            worker.apply()
        k = stop
    worker.drain(final=True)
    worker.apply()

    assert worker.samples == reference.samples == int(mask.sum())
    assert worker.skipped_contact == reference.skipped == int((~mask).sum())
    expected = reference_estimator.model.friction
    got = estimator.model.friction
    assert isinstance(expected, WaveletNetwork) and isinstance(got, WaveletNetwork)
    assert worker.adapter.included.sum() > 0  # the structure changed: snapshots carry it
    np.testing.assert_array_equal(got.active_global_indices(), expected.active_global_indices())
    assert np.abs(expected.parameters).max() > 1e-3  # it learnt something
    np.testing.assert_allclose(got.parameters, expected.parameters, rtol=0, atol=1e-9)
    assert got.coverage is not None and expected.coverage is not None
    for j in range(3):
        np.testing.assert_array_equal(got.coverage.counts(j), expected.coverage.counts(j))
    # the estimator runs what was installed
    qd = np.array([[0.5, -0.2, 0.3]])
    np.testing.assert_allclose(got.torque(qd), expected.torque(qd), rtol=0, atol=1e-9)


def test_a_network_on_its_fallback_adapts_to_what_the_coupled_cv_leaves(base):
    """Same stream, same gains: the network on the CV learns the remainder, not the friction."""
    t, q, tau, _, _ = simulated_stream(23, n=3000, restart=3000)
    learnt = {}
    for on_fallback in (False, True):
        estimator = wn_estimator(base, on_fallback)
        reference = OnlineAdaptation(estimator)
        for k in range(t.size):
            reference.update(t[k], q[k], tau[k])
        network = estimator.model.friction
        assert isinstance(network, WaveletNetwork) and network.on_fallback is on_fallback
        qd = np.gradient(q, t, axis=0)[500:]
        learnt[on_fallback] = network.torque(qd)
    # the network on the CV heads for the other's function minus the CV (3 s: not converged;
    # without the CV in its target the two would learn the same, a gap of 0)
    cv = base.friction.torque(qd)
    gap = learnt[False] - learnt[True]
    assert np.sqrt(np.mean((gap - cv) ** 2)) < 0.7 * np.sqrt(np.mean(cv**2))


def test_the_gate_holds_samples_back_until_their_guard_has_passed(base):
    estimator = wn_estimator(base)
    worker = AdaptationWorker(estimator, AdaptationGate(THRESHOLD_N, 0.3))
    q = (0.0, 0.4, -0.3)
    tau = (0.0, 0.05, 0.02)
    free = [0.0, 0.0, 0.0]
    for k in range(200):
        worker.submit(0.001 * (k + 1), q, tau, free)
    worker.drain()
    assert worker.samples == 0 and worker.stats()["pending"] == 200  # 0.2 s < guard
    for k in range(200, 400):
        worker.submit(0.001 * (k + 1), q, tau, free)
    worker.drain()
    assert worker.samples == 100  # the first 0.1 s have 0.3 s of free motion after them
    worker.submit(0.4005, q, tau, [0.0, 0.6, 0.0])  # contact: the 0.3 s before it are out
    worker.drain()
    stats = worker.stats()
    assert stats["samples"] == 100 and stats["skipped_contact"] == 301
    assert stats["pending"] == 0 and stats["dropped"] == 0


def test_the_gate_parameters_are_checked():
    with pytest.raises(ConfigurationError):
        AdaptationGate(force_threshold_n=0.0)
    with pytest.raises(ConfigurationError):
        AdaptationGate(guard_s=-1.0)
    with pytest.raises(ConfigurationError):
        AdaptationGate(guard_s=math.nan)


def test_the_worker_thread_adapts_and_stops_with_the_switch(base):
    estimator = wn_estimator(base)
    network = estimator.model.friction
    assert isinstance(network, WaveletNetwork)
    before = network.parameters.copy()
    state = AdaptationState(estimator, AdaptationGate(THRESHOLD_N, 0.05))
    state.switch(True, estimator)
    worker = state.adaptation
    assert worker is not None and worker.running
    t, q, tau, _, _ = simulated_stream(3, n=600, restart=600)
    for k in range(t.size):
        worker.submit(float(t[k]), tuple(q[k]), tuple(tau[k]), (0.0, 0.0, 0.0))
    state.switch(False, estimator)  # flushes the queue and installs the result
    assert not worker.running and not state.enabled
    stats = state.to_dict()
    assert stats["samples"] == 600 and stats["skipped_contact"] == 0 and stats["errors"] == 0
    assert stats["publications"] >= 1 and stats["pending"] == 0
    after = network.parameters
    assert after.size != before.size or not np.array_equal(after, before)
    state.switch(True, estimator)
    assert state.adaptation is worker and worker.running  # kept while the model runs
    state.follow(wn_estimator(base))
    assert not worker.running and state.adaptation is not worker
    assert state.adaptation is not None and state.adaptation.running
    state.close()
    assert not state.adaptation.running and not state.enabled


def test_a_failing_batch_is_counted_and_the_worker_goes_on(base):
    estimator = wn_estimator(base)
    worker = AdaptationWorker(estimator, AdaptationGate(THRESHOLD_N, 0.0))
    q, tau, free = (0.0, 0.4, -0.3), (0.0, 0.05, 0.02), (0.0, 0.0, 0.0)
    worker.submit(0.001, q, tau, free)
    worker.submit(0.002, q[:2], tau, free)  # two angles: the batch cannot be computed
    worker._drain_guarded(final=True)
    stats = worker.stats()
    assert stats["errors"] == 1 and "ValueError" in stats["last_error"]
    for k in range(3, 50):
        worker.submit(0.001 * k, q, tau, free)
    worker._drain_guarded(final=True)
    stats = worker.stats()
    assert stats["errors"] == 1 and stats["samples"] == 47 and stats["pending"] == 0


def test_a_sticking_fallback_changes_what_the_network_on_it_learns(base):
    """The target is what the CV with its state leaves: not the sliding CV's remainder."""
    t, q, tau, _, _ = simulated_stream(23, n=3000, restart=3000)
    fallback = friction_from_dict(base.friction.to_dict())
    fallback.set_sticking(0.02)
    learnt = []
    for model in (base, dataclasses.replace(base, friction=fallback)):
        estimator = wn_estimator(model, on_fallback=True)
        assert AdaptationState(estimator).note == ""  # available with the state too
        reference = OnlineAdaptation(estimator)
        for k in range(t.size):
            reference.update(t[k], q[k], tau[k])
        qd = np.gradient(q, t, axis=0)[500:]
        learnt.append(estimator.model.friction.torque(qd))
    assert np.sqrt(np.mean((learnt[0] - learnt[1]) ** 2)) > 1e-3
