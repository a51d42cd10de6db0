"""Numerical guards: singular Jacobians, untrained velocities, non-finite input, drift.

Already covered elsewhere (checked, not repeated): the exactly singular Jacobian
(``tests/estimation/test_estimator.py::test_singular_jacobian_is_reported_not_divided``), NaN / inf
in
every message field (``tests/transport/test_messages.py``), the projection ``||c_j|| <= B`` under
any
gain and a truth far outside the ball (``tests/friction/test_adaptation.py``), the blend to
the fallback at the friction level (``tests/friction/test_coverage.py``).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.errors import DataError
from teleop_force.estimation.estimator import DEFAULT_SIGMA_MIN, ForceEstimator
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.wavelet_network import WaveletNetwork, omni_wavelet_specs
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.robots.description import Robot
from teleop_force.robots.omni import omni_description
from teleop_force.ros2 import codec, topics
from teleop_force.service.adaptation import AdaptationGate, AdaptationWorker
from teleop_force.service.force_service import MAX_ABS_JOINT_VALUE, ForceService, ServiceConfig
from teleop_force.transport import messages as m
from tests.ros2_traffic import Collector, JointStatePublisher

INPUTS = ((0,), (1, 2), (1, 2))


@pytest.fixture(scope="module")
def model() -> DynamicModel:
    return DynamicModel.load(DEFAULT_MODEL_PATH)


@pytest.fixture(scope="module")
def wn_model(model) -> DynamicModel:
    """A WN friction trained on |qd| < 1 rad/s, with a coupled-CV fallback."""
    net = WaveletNetwork(3, omni_wavelet_specs(2.0, 2.0))
    rng = np.random.default_rng(0)
    for j in range(3):
        net.set_joint_parameters(j, rng.normal(0.0, 0.01, net.active_global_indices(j).size))
    net.fallback = CoupledCoulombViscous(3, INPUTS, rng.normal(0.0, 0.01, 10))
    net.coverage.add(rng.uniform(-1.0, 1.0, size=(50_000, 3)))
    return DynamicModel(
        model.robot, 3, model.filter_config, model.base, model.base_values, model.base_std,
        net, model.offsets_nm,
    )  # fmt: skip


# --------------------------------------------------------------------------- singularity


@settings(max_examples=60, deadline=None)
@given(
    eps=st.floats(0.0, 0.2),
    q1=st.floats(-1.0, 1.0),
    tau=st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3),
)
def test_near_singular_jacobians_never_blow_up(model, eps, q1, tau):
    """Approaching r = 0 (tip on the yaw axis): NaN and 'singular', or a bounded force."""
    q = np.array([q1, math.pi / 2 - eps, 0.0])
    estimator = ForceEstimator(model)
    for k in range(3):
        est = estimator.update(k * 1e-3, q, np.array(tau))
    force = est.force_tip_in_base_n
    if est.singular:
        assert np.all(np.isnan(force))
    else:
        assert np.all(np.isfinite(force))
        jac = Robot(model.description()).tip_jacobian_in_base(q)
        sigma = np.linalg.svd(jac, compute_uv=False)[-1]
        assert sigma >= DEFAULT_SIGMA_MIN * (1 - 1e-9)
        # |F| <= |tau_ext| / sigma_min: nothing was divided by a vanishing number.
        bound = np.linalg.norm(est.tau_external_nm) / DEFAULT_SIGMA_MIN
        assert np.linalg.norm(force) <= bound * (1 + 1e-9)


# --------------------------------------------------------------------------- coverage


def test_untrained_velocities_blend_to_the_fallback(model, wn_model):
    """Far outside the trained velocities the weight is 0 and the WN model equals its fallback."""
    fallback_model = DynamicModel(
        model.robot, 3, model.filter_config, model.base, model.base_values, model.base_std,
        wn_model.friction.fallback, model.offsets_nm,
    )  # fmt: skip
    wn, fb = ForceEstimator(wn_model), ForceEstimator(fallback_model)
    v = np.array([6.0, -6.0, 6.0])  # rad/s, trained only below 1
    q0 = np.array([0.0, 0.6, 0.4])
    tau = np.array([0.01, 0.15, 0.05])
    for k in range(800):
        t = k * 1e-3
        a, b = wn.update(t, q0 + v * t, tau), fb.update(t, q0 + v * t, tau)
    assert np.all(a.coverage_weight == 0.0) and not np.any(a.on_trained_ground)
    np.testing.assert_allclose(a.tau_model_filtered_nm, b.tau_model_filtered_nm, atol=1e-12)
    np.testing.assert_allclose(a.tau_external_nm, b.tau_external_nm, atol=1e-12)


# --------------------------------------------------------------------------- non-finite input


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["q", "tau", "t"])
def test_estimator_raises_data_error_on_non_finite_input_and_is_unharmed(model, bad, where):
    estimator = ForceEstimator(model)
    q, tau = np.array([0.1, 0.7, 0.3]), np.array([0.0, 0.1, 0.05])
    first = [estimator.update(k * 1e-3, q, tau).tau_model_filtered_nm for k in range(5)]
    args = {"t": 5e-3, "q": q.copy(), "tau": tau.copy()}
    if where == "t":
        args["t"] = bad
    else:
        args[where][1] = bad
    with pytest.raises(DataError, match="non-finite"):
        estimator.update(args["t"], args["q"], args["tau"])
    after = estimator.update(5e-3, q, tau)  # the bad sample left no trace
    reference = ForceEstimator(model)
    for k in range(5):
        reference.update(k * 1e-3, q, tau)
    expected = reference.update(5e-3, q, tau)
    assert first and np.array_equal(after.tau_model_filtered_nm, expected.tau_model_filtered_nm)


@contextlib.contextmanager
def _live_service(
    session: zenoh.Session, model: DynamicModel, device: str
) -> Iterator[tuple[ForceService, list[m.ForceEstimateMessage], Any]]:
    """A service on a loopback peer session, the estimates it publishes, a joint-state publisher."""
    service = ForceService(session, model, ServiceConfig(device=device)).start()
    collector = Collector(session, device, topics.ESTIMATED_CF)
    pub = JointStatePublisher(session, device)
    try:
        yield service, collector.messages, pub
    finally:
        collector.close()
        pub.close()
        service.close()


def non_finite_joint_state(t_ns: int, value: float) -> bytes:
    """A CDR JointState whose second angle is ``value`` (the message value would refuse it)."""
    names = topics.OMNI_MODEL_JOINT_NAMES
    return codec.encode_joint_state_parts(t_ns, names, "", (0.1, value, 0.3), (0.0,) * 3,
                                          (0.0,) * 3)  # fmt: skip


@pytest.mark.zenoh
def test_service_drops_non_finite_and_implausible_joint_states_and_keeps_running(
    zenoh_session, model
):
    device = "guard_test"
    t0 = 1_700_000_000_000_000_000
    sent_bad = 0
    with _live_service(zenoh_session, model, device) as (service, got, pub):
        for k in range(300):
            t_ns = t0 + k * 1_000_000
            if k % 50 == 25:
                for value in (math.nan, math.inf, -math.inf, 1e300, -2e6):
                    pub.send_raw(non_finite_joint_state(t_ns, value), 10_000 + sent_bad)
                    sent_bad += 1
            q = (0.1, 0.7 + 1e-4 * k, 0.3)
            pub.send(m.JointState(k, t_ns, q, (0.0,) * 3, (0.0, 0.1, 0.05)))
        deadline = time.monotonic() + 20
        while len(got) < 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        # An estimate that cannot be computed is counted, and the stream restarts cleanly.
        original = service.estimator.step
        calls = {"n": 0}

        def failing_once(*args):
            calls["n"] += 1
            if calls["n"] == 1:
                raise DataError("simulated non-finite result")
            return original(*args)

        service.estimator.step = failing_once
        for k in range(300, 400):
            q = (0.1, 0.7 + 1e-4 * k, 0.3)
            pub.send(m.JointState(k, t0 + k * 1_000_000, q, (0.0,) * 3, (0.0, 0.1, 0.05)))
        while len(got) < 399 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = service.stats()
    assert stats["malformed"]["by_key"] == {topics.topic_name(device, topics.MEASURED_JS): sent_bad}
    assert stats["joint_states"]["received"] == 400 and stats["joint_states"]["lost"] == 0
    assert stats["estimates"]["errors"] == 1 and stats["estimates"]["published"] == 399
    assert len(got) == 399 and all(np.all(np.isfinite(e.tau_ext_nm)) for e in got)


@pytest.mark.zenoh
def test_a_spike_up_to_the_plausibility_bound_leaves_the_filters_finite(zenoh_session, model):
    """1e6 (the bound) in one angle: estimated, and every later estimate is finite.

    Beyond the bound (1e300 overflows the filter states for good, found while fuzzing) the
    joint state is dropped as malformed, see the test above.
    """
    device = "spike_test"
    t0 = 1_700_000_000_000_000_000
    with _live_service(zenoh_session, model, device) as (service, got, pub):
        for k in range(300):
            q = (0.1, MAX_ABS_JOINT_VALUE if k == 100 else 0.7, 0.3)
            pub.send(m.JointState(k, t0 + k * 1_000_000, q, (0.0,) * 3, (0.0, 0.1, 0.05)))
        deadline = time.monotonic() + 20
        while len(got) < 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        stats = service.stats()
    assert stats["estimates"]["errors"] == 0 and stats["estimates"]["published"] == 300
    assert all(np.all(np.isfinite(e.tau_ext_nm)) for e in got[101:])
    np.testing.assert_allclose(
        got[-1].tau_motor_filtered_nm, got[99].tau_motor_filtered_nm, atol=0.05
    )


# --------------------------------------------------------------------------- adaptation drift


def test_online_adaptation_under_drift_stays_inside_the_ball(wn_model):
    """A friction that drifts far from the model: coefficients stay finite and ||c_j|| <= B."""
    network = WaveletNetwork.from_dict(wn_model.friction.to_dict())
    model = DynamicModel(
        wn_model.robot, 3, wn_model.filter_config, wn_model.base, wn_model.base_values,
        wn_model.base_std, network, wn_model.offsets_nm,
    )  # fmt: skip
    estimator = ForceEstimator(model)
    # what the service runs: the worker, every sample declared free (no force) so all adapt
    worker = AdaptationWorker(estimator, AdaptationGate(guard_s=0.0))
    bound = np.asarray(worker.adapter.config.bound_b)
    description = omni_description()
    mid = 0.5 * (description.q_min_rad + description.q_max_rad)
    for k in range(3000):
        t = k * 1e-3
        q = mid + 0.3 * np.sin([3 * t, 2 * t, 4 * t])
        drift = 1.0 + 20.0 * t  # the unmodelled torque grows without bound
        tau = drift * np.sign(np.cos([3 * t, 2 * t, 4 * t])) * np.array([0.05, 0.1, 0.05])
        worker.submit(t, tuple(q), tuple(tau), [0.0, 0.0, 0.0])
        estimator.update(t, q, tau)
        if k % 50 == 49:
            worker.drain()
            worker.apply()
    worker.drain(final=True)
    worker.apply()
    assert worker.samples == 3000
    for j in range(3):
        c = network.joint_parameters(j)
        assert np.all(np.isfinite(c))
        assert np.linalg.norm(c) <= bound[j] * (1 + 1e-12)
