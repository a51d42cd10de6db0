"""Each effect term has one definition: every shape x modulation x variable kind, batch
(BasisSpec.basis, FoundEffect.torque) against one sample at a time (the streaming call) and
against a NumPy reference of the formulas, on seeded random states."""

import itertools
import json

import numpy as np
import pytest

from teleop_force.errors import ModelError
from teleop_force.identification.effect_terms import (
    SHAPE_CODES,
    EffectModulation,
    EffectShape,
    EffectVariable,
    VariableKind,
    add_effects_torque_into,
    shape_basis_into,
)
from teleop_force.identification.effects import (
    BasisSpec,
    FoundEffect,
    effect_from_dict,
    effects_table,
    variable_values,
)

ATOL = 1e-9
VARIABLES = ["t", "q2", "q1-q3", "qd3", "tau2"]
SHAPE_ARGS = {
    "constant": {},
    "linear": {},
    "abs": {},
    "smooth": {"lo": -1.5, "hi": 1.0, "count": 4},
    "periodic": {"frequency": 1.7, "harmonics": 2},
    "stribeck": {"scales": (0.05, 0.3, 1.0)},
}


def _state(seed: int, n: int = 200):
    rng = np.random.default_rng(seed)
    t = 10.0 + np.sort(rng.uniform(0.0, 5.0, n))
    q, qd, tau = (rng.normal(0.0, 1.0, size=(n, 3)) for _ in range(3))
    qd[:5] = 0.0
    return t, q, qd, tau


def _reference_basis(spec: BasisSpec, t, q, qd, tau) -> np.ndarray:
    """The NumPy formulas the compiled terms replaced."""
    var = spec.variable
    x = {
        "t": t - t[0], "q2": q[:, 1], "q1-q3": q[:, 0] - q[:, 2], "qd3": qd[:, 2],
        "tau2": tau[:, 1],
    }[var]  # fmt: skip
    if spec.shape == "constant":
        phi = np.ones((q.shape[0], 1))
    elif spec.shape == "linear":
        phi = x[:, None]
    elif spec.shape == "abs":
        phi = np.abs(x)[:, None]
    elif spec.shape == "smooth":
        centres = np.linspace(spec.lo, spec.hi, spec.count)
        width = (spec.hi - spec.lo) / (spec.count - 1)
        phi = np.exp(-0.5 * ((x[:, None] - centres[None, :]) / width) ** 2)
    elif spec.shape == "periodic":
        k = np.arange(1, spec.harmonics + 1) * spec.frequency
        phi = np.concatenate((np.sin(x[:, None] * k), np.cos(x[:, None] * k)), axis=1)
    else:
        phi = np.exp(-((x[:, None] / np.asarray(spec.scales)[None, :]) ** 2))
    s = np.sign(qd[:, spec.joint])[:, None]
    if spec.modulation == "sign":
        phi = phi * s
    elif spec.modulation == "positive":
        phi = phi * (qd[:, spec.joint] > 0)[:, None]
    elif spec.modulation == "both":
        phi = np.concatenate((phi, phi * s), axis=1)
    return phi


CASES = list(itertools.product(SHAPE_ARGS, EffectModulation, VARIABLES))


@pytest.mark.parametrize(("shape", "modulation", "variable"), CASES)
def test_effect_batch_streaming_and_reference_agree(shape, modulation, variable):
    seed = CASES.index((shape, modulation, variable))
    t, q, qd, tau = _state(seed)
    spec = BasisSpec(seed % 3, variable, shape, modulation, **SHAPE_ARGS[shape])
    basis = spec.basis(t, q, qd, tau)
    np.testing.assert_allclose(basis, _reference_basis(spec, t, q, qd, tau), rtol=1e-12,
                               atol=1e-14)  # fmt: skip
    coefficients = np.random.default_rng(seed).normal(size=spec.size)
    reach = np.array([0.0, 0.0, 0.0])
    reach[spec.joint] = 1.0
    reach[(spec.joint + 1) % 3] = -0.6697
    effect = FoundEffect(spec, coefficients, reach=reach)
    batch = effect.torque(t, q, qd, tau)
    np.testing.assert_allclose(batch, (basis @ coefficients)[:, None] * reach, rtol=0, atol=1e-12)
    table = effects_table([effect], 3)
    streamed = np.zeros(q.shape)
    for k in range(q.shape[0]):
        add_effects_torque_into(table.codes, table.floats, t[k] - t[0], q[k], qd[k], tau[k],
                                1.0, table.work, streamed[k])  # fmt: skip
    np.testing.assert_allclose(streamed, batch, rtol=0, atol=ATOL)


def test_all_effects_of_a_model_in_one_table():
    t, q, qd, tau = _state(99)
    rng = np.random.default_rng(99)
    effects = []
    for k, (shape, modulation, variable) in enumerate(CASES[::7]):
        spec = BasisSpec(k % 3, variable, shape, modulation, **SHAPE_ARGS[shape])
        effects.append(FoundEffect(spec, rng.normal(size=spec.size)))
    table = effects_table(effects, 3)
    streamed = np.zeros(q.shape)
    for k in range(q.shape[0]):
        add_effects_torque_into(table.codes, table.floats, t[k] - t[0], q[k], qd[k], tau[k],
                                1.0, table.work, streamed[k])  # fmt: skip
    expected = sum(e.torque(t, q, qd, tau) for e in effects)
    np.testing.assert_allclose(streamed, expected, rtol=0, atol=ATOL)


@pytest.mark.parametrize(
    ("name", "kind", "joints"),
    [("t", VariableKind.TIME, ()), ("q2", VariableKind.ANGLE, (1,)),
     ("q2-q3", VariableKind.ANGLE_DIFFERENCE, (1, 2)), ("qd1", VariableKind.VELOCITY, (0,)),
     ("tau3", VariableKind.LOAD, (2,)), ("q12", VariableKind.ANGLE, (11,))],
)  # fmt: skip
def test_effect_variable_parses_once_and_keeps_its_spelling(name, kind, joints):
    variable = EffectVariable.parse(name)
    assert variable.kind is kind and variable.joints == joints and str(variable) == name


@pytest.mark.parametrize("name", ["", "x", "q", "q0x", "qd", "q1-", "t1", "tau", "q1-qd2"])
def test_effect_variable_refuses_unknown_names(name):
    with pytest.raises(ModelError):
        EffectVariable.parse(name)
    with pytest.raises(ModelError):
        BasisSpec(0, name, "linear")


def test_variable_values_and_joint_checks():
    t, q, qd, tau = _state(3)
    np.testing.assert_array_equal(variable_values("q1-q3", t, q, qd, tau), q[:, 0] - q[:, 2])
    np.testing.assert_array_equal(variable_values("t", t, q, qd, tau), t - t[0])
    np.testing.assert_array_equal(variable_values("tau2", t, q, qd, tau), tau[:, 1])
    with pytest.raises(ModelError):
        variable_values("q4", t, q, qd, tau)
    with pytest.raises(ModelError):
        effects_table([FoundEffect(BasisSpec(0, "qd7", "linear"), np.ones(1))], 3)


def test_shapes_and_modulations_are_enums_with_the_file_strings():
    spec = BasisSpec(1, "q2-q3", "smooth", "both", -1.0, 1.0, 5)
    assert spec.shape is EffectShape.SMOOTH and spec.modulation is EffectModulation.BOTH
    assert spec.effect_variable == EffectVariable(VariableKind.ANGLE_DIFFERENCE, 1, 2)
    data = json.loads(json.dumps(FoundEffect(spec, np.arange(10.0)).to_dict()))
    assert data["spec"]["shape"] == "smooth" and data["spec"]["modulation"] == "both"
    assert data["spec"]["variable"] == "q2-q3"
    again = effect_from_dict(data)
    assert again.spec == spec and hash(again.spec) == hash(spec)
    with pytest.raises(ModelError):
        BasisSpec(0, "t", "cubic")
    with pytest.raises(ModelError):
        BasisSpec(0, "t", "linear", "negative")


def test_every_shape_has_its_own_branch_and_an_unknown_code_gives_nan():
    parameters = np.array([0.5, 1.5, 2.0])
    for shape, code in SHAPE_CODES.items():
        out = np.full(8, -7.0)
        written = shape_basis_into(code, 0.3, 2, parameters, out, 1)
        assert np.all(np.isfinite(out[1 : 1 + written])), shape
    out = np.zeros(3)
    shape_basis_into(max(SHAPE_CODES.values()) + 1, 0.3, 2, parameters, out, 0)
    assert np.isnan(out[:2]).all()
