"""The batch estimator against the streaming one it replaces for recordings, and its kernels."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import DataError
from teleop_force.estimation import batch as batch_module
from teleop_force.estimation.batch import BatchEstimator, stream_times_s
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.estimation.rigid_chain import (
    chain_jacobian_batch,
    chain_tables,
    chain_terms_batch,
)
from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.wavelet_network import WaveletNetwork
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.effects import BasisSpec, FoundEffect
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.dvrk_mtm import dvrk_mtm_description
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description
from teleop_force.robots.teststand import teststand_description as stand_description
from teleop_force.simulation import palpation_protocol
from tests.estimation.network_cases import CV_PARAMETERS, random_network

#: Found effects of every variable kind, ``t`` and a load (``tau2``) among them.
EFFECTS = (
    (BasisSpec(0, "q1", "constant", "sign"), [0.004]),
    (BasisSpec(1, "q2", "periodic", frequency=2.0, harmonics=2), [1e-3, -2e-3, 5e-4, 1e-3]),
    (BasisSpec(2, "q2-q3", "smooth", lo=-1.0, hi=1.0, count=4), [1e-3, -1e-3, 2e-3, 0.0]),
    (BasisSpec(2, "qd3", "stribeck", "sign", scales=(0.05, 0.2)), [2e-3, 1e-3]),
    (BasisSpec(1, "tau2", "linear", "positive"), [0.05]),
    (BasisSpec(1, "t", "linear"), [1e-3]),
)
FIELDS = (
    "force_tip_in_base_n",
    "tau_external_nm",
    "tau_motor_filtered_nm",
    "tau_model_filtered_nm",
    "coverage_weight",
)
#: Sample indices where a new stream begins in the restart tests.
RESTARTS = (700, 1900)


def _network(seed: int = 0) -> WaveletNetwork:
    return random_network(seed, 80, 0.15)


def _friction(kind: str):
    description = omni_description()
    return {
        "cv": lambda: CoulombViscous(3, CV_PARAMETERS[[0, 1, 2, 3, 6, 7]]),
        "coupled-cv": lambda: CoupledCoulombViscous(3, description.friction_inputs, CV_PARAMETERS),
        "wn": _network,
    }[kind]()


_BASE = {}


def _omni_model(friction, effects=(), lag: int = 1, **estimator) -> DynamicModel:
    description = omni_description()
    if "omni" not in _BASE:
        _BASE["omni"] = RigidBodyRegressor(description).find_base_parameters()
    base = _BASE["omni"]
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    found = tuple(FoundEffect(spec, np.asarray(c, dtype=float)) for spec, c in effects)
    config = FilterConfig(torque_lag_samples=lag, **estimator)
    return DynamicModel("omni", 3, config, base, beta, 0 * beta, friction, np.zeros(3), found)


@pytest.fixture(scope="module")
def palpation():
    """A seeded simulated palpation (contact forces, 1 kHz), with jitter in the stamps."""
    session = palpation_protocol(3.0, seed=4)
    rng = np.random.default_rng(5)
    t = np.asarray(session.t_s) + rng.uniform(0.0, 2e-4, session.t_s.size)
    return t, np.asarray(session.q_rad), np.asarray(session.tau_nm)


def _streamed(model: DynamicModel, t, q, tau, starts=()) -> dict[str, np.ndarray]:
    """``ForceEstimator.update`` sample by sample, reset at ``starts``."""
    estimator = ForceEstimator(model)
    rows = []
    for k in range(t.size):
        if k in starts:
            estimator.reset()
        rows.append(estimator.update(t[k], q[k], tau[k]))
    out = {name: np.array([getattr(e, name) for e in rows]) for name in FIELDS}
    out["on_trained_ground"] = np.array([e.on_trained_ground for e in rows])
    out["singular"] = np.array([e.singular for e in rows])
    return out


def _assert_same(batch, streamed, atol: float = 1e-9) -> None:
    for name in FIELDS:
        b, s = getattr(batch, name), streamed[name]
        np.testing.assert_array_equal(np.isnan(b), np.isnan(s), err_msg=name)
        np.testing.assert_allclose(b, s, rtol=0.0, atol=atol, err_msg=name)
    np.testing.assert_array_equal(batch.on_trained_ground, streamed["on_trained_ground"])
    np.testing.assert_array_equal(batch.singular, streamed["singular"])


@pytest.mark.parametrize("kind", ["cv", "coupled-cv", "wn"])
def test_batch_equals_streaming_with_effects_and_restarts(palpation, kind) -> None:
    t, q, tau = palpation
    model = _omni_model(_friction(kind), EFFECTS)
    # a restart as the service makes it: time counted again from the stream's first sample
    t = t.copy()
    for start in RESTARTS:
        t[start:] = t[start:] - t[start] + 0.0
    result = BatchEstimator(model).estimate(t, q, tau, np.array(RESTARTS))
    streamed = _streamed(model, t, q, tau, RESTARTS)
    _assert_same(result, streamed)
    assert np.isfinite(result.force_tip_in_base_n).all()
    assert np.abs(result.force_tip_in_base_n).max() > 0.1  # the palpation pushes
    if kind == "wn":  # the blend is exercised: on and off the trained ground
        weight = result.coverage_weight
        assert weight.min() < 0.5 < weight.max()
        assert ((weight > 0.0) & (weight < 1.0)).any()


def test_batch_equals_streaming_without_lag(palpation) -> None:
    t, q, tau = (x[:800] for x in palpation)
    model = _omni_model(_friction("coupled-cv"), EFFECTS, lag=0)
    _assert_same(BatchEstimator(model).estimate(t, q, tau), _streamed(model, t, q, tau))


#: Estimator choices of the filter configuration: the observer, the dead band, both.
ESTIMATOR_CHOICES = {
    "observer": {"estimator": "observer", "observer_hz": 15.0},
    "band": {"standstill_band_rad_s": 0.05},
    "observer-band": {"estimator": "observer", "standstill_band_rad_s": 0.05},
}


@pytest.mark.parametrize("choice", sorted(ESTIMATOR_CHOICES))
@pytest.mark.parametrize("kind", ["cv", "coupled-cv", "wn"])
def test_batch_equals_streaming_for_the_observer_and_the_band(palpation, kind, choice) -> None:
    t, q, tau = (x[:2500].copy() for x in palpation)
    model = _omni_model(_friction(kind), EFFECTS, **ESTIMATOR_CHOICES[choice])
    starts = (900,)
    t[900:] = t[900:] - t[900]
    result = BatchEstimator(model).estimate(t, q, tau, np.array(starts))
    _assert_same(result, _streamed(model, t, q, tau, starts))
    default = BatchEstimator(_omni_model(_friction(kind), EFFECTS)).estimate(
        t, q, tau, np.array(starts)
    )
    # the choice changes the estimates (the band only where every joint is slow)
    assert not np.allclose(result.tau_external_nm, default.tau_external_nm, atol=1e-6)
    np.testing.assert_array_equal(result.tau_motor_filtered_nm, default.tau_motor_filtered_nm)


@pytest.mark.parametrize("stages", [1, 2])
def test_batch_equals_streaming_for_either_observer_prefilter(palpation, stages) -> None:
    """The observer's pre-filter, one stage or two in cascade: batch = streaming to 1e-9."""
    t, q, tau = (x[:1500].copy() for x in palpation)
    choice = {"estimator": "observer", "observer_prefilter_stages": stages}
    model = _omni_model(_friction("coupled-cv"), EFFECTS, **choice)
    starts = (700,)
    t[700:] = t[700:] - t[700]
    result = BatchEstimator(model).estimate(t, q, tau, np.array(starts))
    _assert_same(result, _streamed(model, t, q, tau, starts))
    other = {**choice, "observer_prefilter_stages": 3 - stages}
    different = BatchEstimator(_omni_model(_friction("coupled-cv"), EFFECTS, **other))
    changed = different.estimate(t, q, tau, np.array(starts))
    assert not np.allclose(changed.tau_motor_filtered_nm, result.tau_motor_filtered_nm, atol=1e-6)


@pytest.mark.parametrize("output_hz", [0.0, 40.0])
def test_batch_equals_streaming_with_or_without_the_output_filter(palpation, output_hz) -> None:
    """The observer's output Butterworth, restarting with each stream: batch = streaming."""
    t, q, tau = (x[:1500].copy() for x in palpation)
    choice = {"estimator": "observer", "observer_hz": 400.0, "observer_output_hz": output_hz}
    model = _omni_model(_friction("coupled-cv"), EFFECTS, **choice)
    starts = (700,)
    t[700:] = t[700:] - t[700]
    result = BatchEstimator(model).estimate(t, q, tau, np.array(starts))
    _assert_same(result, _streamed(model, t, q, tau, starts))
    other = {**choice, "observer_output_hz": 40.0 if output_hz == 0.0 else 0.0}
    changed = BatchEstimator(_omni_model(_friction("coupled-cv"), EFFECTS, **other)).estimate(
        t, q, tau, np.array(starts)
    )
    assert not np.allclose(changed.tau_external_nm, result.tau_external_nm, atol=1e-4)


@pytest.mark.parametrize("lag", [0, 1])
def test_observer_batch_equals_streaming_for_both_lags(palpation, lag) -> None:
    t, q, tau = (x[:800] for x in palpation)
    model = _omni_model(_friction("coupled-cv"), EFFECTS, lag=lag, estimator="observer")
    result = BatchEstimator(model).estimate(t, q, tau)
    _assert_same(result, _streamed(model, t, q, tau))
    np.testing.assert_allclose(
        result.tau_model_filtered_nm + result.tau_external_nm, result.tau_motor_filtered_nm,
        rtol=0.0, atol=1e-15,
    )  # fmt: skip


class _SmoothCoulomb(FrictionModel):
    """A friction without a term encoding: the estimators evaluate it by its batch methods."""

    kind = "smooth-coulomb-test"

    def parameter_counts(self) -> tuple[int, ...]:
        return (1,) * self.n_joints

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        return np.tanh(np.atleast_2d(np.asarray(qd, dtype=float))[:, joint : joint + 1] / 0.02)

    def parameter_names(self, joint: int) -> list[str]:
        return [f"a_{joint + 1}"]

    def to_dict(self) -> dict:
        return {"kind": self.kind, "parameters": self.parameters.tolist()}


@pytest.mark.parametrize("choice", [None, "observer-band"])
def test_friction_without_a_term_encoding(palpation, choice) -> None:
    t, q, tau = (x[:1200] for x in palpation)
    friction = _SmoothCoulomb(3, np.array([0.02, 0.015, 0.01]))
    model = _omni_model(friction, EFFECTS, **ESTIMATOR_CHOICES.get(choice, {}))
    result = BatchEstimator(model).estimate(t, q, tau, np.array([500]))
    _assert_same(result, _streamed(model, t, q, tau, (500,)))


def test_a_restart_starts_from_scratch(palpation) -> None:
    t, q, tau = (x[:600] for x in palpation)
    model = _omni_model(_friction("cv"), EFFECTS)
    estimator = BatchEstimator(model)
    whole = estimator.estimate(t, q, tau, np.array([300]))
    alone = estimator.estimate(t[300:], q[300:], tau[300:])
    for name in (*FIELDS, "singular"):
        np.testing.assert_array_equal(getattr(whole, name)[300:], getattr(alone, name))
    joined = estimator.estimate(t, q, tau)
    assert not np.array_equal(joined.tau_model_filtered_nm[300:], alone.tau_model_filtered_nm)
    tail = whole.rows(slice(300, None))  # the rows of the second stream, every field alike
    assert len(tail) == 300
    for field in dataclasses.fields(whole):
        np.testing.assert_array_equal(getattr(tail, field.name), getattr(alone, field.name))


def test_singular_poses_are_flagged_as_the_streaming_estimator_does() -> None:
    model = _omni_model(_friction("coupled-cv"))
    n = 400
    t = np.arange(n) * 1e-3
    # through the yaw-axis singularity (tip on the axis at q2 = pi/2, q3 = 0) and back
    q = np.column_stack(
        [0.1 * np.sin(t), np.pi / 2 + 0.05 * np.cos(np.pi * t / t[-1]), 0.02 * np.sin(3 * t)]
    )
    q[150:170] = [0.0, np.pi / 2, 0.0]
    tau = np.column_stack([0.01 * np.sin(5 * t), 0.1 + 0.0 * t, 0.01 * np.cos(2 * t)])
    result = BatchEstimator(model).estimate(t, q, tau)
    _assert_same(result, _streamed(model, t, q, tau))
    assert result.singular[150:170].all()
    assert np.isnan(result.force_tip_in_base_n[150:170]).all()
    assert not result.singular.all()


def test_stream_times_count_integer_nanoseconds_from_each_start() -> None:
    t_ns = np.array([10**18, 10**18 + 1_000_000, 10**18 + 2_000_001, 5, 1_000_005], dtype=np.int64)
    times = stream_times_s(t_ns, np.array([3]))
    expected = [0.0, 1_000_000 * 1e-9, 2_000_001 * 1e-9, 0.0, 1_000_000 * 1e-9]
    assert times.tolist() == expected


def test_bad_input_names_the_row(palpation) -> None:
    t, q, tau = (x[:50].copy() for x in palpation)
    estimator = BatchEstimator(_omni_model(_friction("cv")))
    t[20] = t[19]
    with pytest.raises(DataError, match="row 21"):
        estimator.estimate(t, q, tau)
    estimator.estimate(t, q, tau, np.array([20]))  # a new stream may start at any time
    q[7, 1] = np.nan
    with pytest.raises(DataError, match="row 8"):
        estimator.estimate(t, q, tau, np.array([20]))
    with pytest.raises(DataError):
        estimator.estimate(t, q[:, :2], tau, np.array([20]))


def test_pinocchio_path_for_joints_the_chain_does_not_encode(palpation, monkeypatch) -> None:
    t, q, tau = (x[:300] for x in palpation)
    model = _omni_model(_friction("coupled-cv"), EFFECTS)
    monkeypatch.setattr(batch_module, "chain_tables", lambda *args: None)
    result = BatchEstimator(model).estimate(t, q, tau)
    _assert_same(result, _streamed(model, t, q, tau))


def _mtm_model() -> DynamicModel:
    description = dvrk_mtm_description()
    base = RigidBodyRegressor(description).find_base_parameters(n_states=60)
    rng = np.random.default_rng(3)
    full = full_parameters(description, np.zeros(len(description.springs)))
    beta = base.project(full)
    friction = CoulombViscous(7, rng.uniform(0.001, 0.02, 14))
    return DynamicModel("dvrk-mtm", 7, FilterConfig(), base, beta, 0 * beta, friction, np.zeros(7))


def test_closed_chain_robot_with_seven_joints() -> None:
    """The dVRK MTM: a coupling T (9 x 7) and a least-squares force (n != 3)."""
    model = _mtm_model()
    rng = np.random.default_rng(8)
    n = 500
    t = np.arange(n) * 1e-3
    phase = rng.uniform(0, 2 * np.pi, 7)
    q = 0.4 * np.sin(3 * t[:, None] + phase) + np.linspace(-0.2, 0.3, 7)
    tau = 0.05 * np.cos(2 * t[:, None] + phase)
    result = BatchEstimator(model).estimate(t, q, tau, np.array([250]))
    _assert_same(result, _streamed(model, t, q, tau, (250,)))
    assert np.isfinite(result.force_tip_in_base_n).any()


def test_robot_without_rigid_body_has_no_force() -> None:
    friction = CoulombViscous(2, np.array([0.01, 0.002, 0.02, 0.003]))
    effects = (FoundEffect(BasisSpec(1, "q1", "constant", "sign"), np.array([0.003])),)
    model = DynamicModel(
        "none", 2, FilterConfig(), None, np.zeros(0), np.zeros(0), friction,
        np.array([0.01, -0.02]), effects,
    )  # fmt: skip
    t = np.arange(300) * 1e-3
    q = np.column_stack([np.sin(t), np.cos(2 * t)])
    tau = np.column_stack([0.1 * np.sin(4 * t), 0.05 + 0.0 * t])
    result = BatchEstimator(model).estimate(t, q, tau)
    _assert_same(result, _streamed(model, t, q, tau))
    assert np.isnan(result.force_tip_in_base_n).all() and not result.singular.any()


def _mixed_chain() -> tuple[pin.Model, str]:
    """A tree of every joint kind the chain encodes, with random inertias, and a tip frame."""
    rng = np.random.default_rng(2)
    model = pin.Model()
    joints = [
        pin.JointModelRZ(), pin.JointModelPX(), pin.JointModelRevoluteUnaligned(0.6, 0.0, 0.8),
        pin.JointModelPrismaticUnaligned(0.0, 0.6, -0.8), pin.JointModelRY(),
    ]  # fmt: skip
    parents = [0, 1, 2, 2, 4]  # a branch: joints 3 and 4 both hang from joint 2
    for i, (joint, parent) in enumerate(zip(joints, parents, strict=True)):
        placement = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(0.0, 0.2, 3))
        index = model.addJoint(parent, joint, placement, f"j{i}")
        inertia = pin.Inertia.Random()
        model.appendBodyToJoint(index, inertia, pin.SE3.Identity())
    model.addFrame(pin.Frame("tip", 5, 0, pin.SE3(np.eye(3), np.array([0.1, -0.2, 0.3])),
                             pin.FrameType.OP_FRAME))  # fmt: skip
    return model, "tip"


CHAINS = {
    "omni": lambda: (omni_description().model, omni_description().tip_frame),
    "dvrk-mtm": lambda: (dvrk_mtm_description().model, dvrk_mtm_description().tip_frame),
    "teststand": lambda: (stand_description().model, stand_description().tip_frame),
    "mixed": _mixed_chain,
}


@pytest.mark.parametrize("name", sorted(CHAINS))
def test_chain_terms_equal_pinocchio(name) -> None:
    model, tip_frame = CHAINS[name]()
    data = model.createData()
    tables = chain_tables(model, tip_frame)
    assert tables is not None
    rng = np.random.default_rng(1)
    q = rng.uniform(-2.0, 2.0, (40, model.nv))
    v = rng.normal(size=(40, model.nv))
    momentum, other = chain_terms_batch(q, v, *tables.arrays())
    jacobian = chain_jacobian_batch(
        q, *tables.arrays()[:6], tables.tip_body, tables.tip_translation, tables.tip_support
    )
    tip = model.getFrameId(tip_frame)
    for k in range(q.shape[0]):
        mass = pin.crba(model, data, q[k])
        mass = np.triu(mass) + np.triu(mass, 1).T
        coriolis = pin.computeCoriolisMatrix(model, data, q[k], v[k])
        gravity = pin.computeGeneralizedGravity(model, data, q[k])
        j6 = pin.computeFrameJacobian(model, data, q[k], tip, pin.LOCAL_WORLD_ALIGNED)
        scale = 1.0 + np.abs(mass).max() + np.abs(gravity).max()
        np.testing.assert_allclose(momentum[k], mass @ v[k], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(
            other[k], gravity - coriolis.T @ v[k], rtol=0, atol=1e-12 * scale
        )
        np.testing.assert_allclose(jacobian[k], j6[:3], rtol=0, atol=1e-12)


def test_chain_tables_refuse_joints_they_do_not_encode() -> None:
    model = pin.Model()
    model.addJoint(0, pin.JointModelSpherical(), pin.SE3.Identity(), "ball")
    assert chain_tables(model, None) is None
    model = pin.Model()
    model.addJoint(0, pin.JointModelRUBX(), pin.SE3.Identity(), "wheel")  # nq 2, nv 1
    assert chain_tables(model, None) is None


def test_estimates_are_one_row_per_sample() -> None:
    fields = {f.name: np.zeros((3, 3)) for f in dataclasses.fields(batch_module.BatchEstimates)}
    fields["t_s"] = np.zeros(3)
    fields["singular"] = np.zeros(2, dtype=bool)
    with pytest.raises(DataError, match="singular"):
        batch_module.BatchEstimates(**fields)


@pytest.mark.parametrize("choice", ["default", "observer-band"])
@pytest.mark.parametrize("kind", ["cv", "coupled-cv", "wn"])
def test_batch_equals_streaming_with_a_sticking_state(palpation, kind, choice) -> None:
    """The Coulomb terms' Dahl state (a network's fallback's, under it): batch = streaming."""
    t, q, tau = (x[:2500].copy() for x in palpation)
    friction = random_network(0, 80, 0.15, on_fallback=True) if kind == "wn" else _friction(kind)
    table = friction.fallback if isinstance(friction, WaveletNetwork) else friction
    table.set_sticking(0.002)
    estimator = ESTIMATOR_CHOICES.get(choice, {})
    model = _omni_model(friction, EFFECTS, **estimator)
    starts = (900,)
    t[900:] = t[900:] - t[900]
    result = BatchEstimator(model).estimate(t, q, tau, np.array(starts))
    _assert_same(result, _streamed(model, t, q, tau, starts))
    table.set_sticking(0.0)
    plain = BatchEstimator(_omni_model(friction, EFFECTS, **estimator)).estimate(
        t, q, tau, np.array(starts)
    )
    assert not np.allclose(result.tau_external_nm, plain.tau_external_nm, atol=1e-6)


@pytest.mark.parametrize("kind", ["cv", "coupled-cv", "wn"])
def test_batch_equals_streaming_with_the_count_observer(palpation, kind) -> None:
    t, q, tau = palpation
    model = _omni_model(
        _friction(kind), EFFECTS, estimator="observer", observer_hz=400.0,
        observer_prefilter_hz=150.0, observer_output_hz=40.0, count_observer=True,
        count_rad=(4e-4, 4e-4, 4e-4),
    )  # fmt: skip
    t = t.copy()
    for start in RESTARTS:
        t[start:] = t[start:] - t[start] + 0.0
    result = BatchEstimator(model).estimate(t, q, tau, np.array(RESTARTS))
    _assert_same(result, _streamed(model, t, q, tau, RESTARTS))
    assert np.isfinite(result.force_tip_in_base_n).all()
    # the observer's angles are not the readings: the estimate is not the one without it
    plain = dataclasses.replace(
        model, filter_config=dataclasses.replace(model.filter_config, count_observer=False)
    )
    other = BatchEstimator(plain).estimate(t, q, tau, np.array(RESTARTS))
    assert np.abs(other.force_tip_in_base_n - result.force_tip_in_base_n).max() > 1e-3
