"""Friction in model coordinates: ``tau_f = T^T f(T qd)``, its model file, and the MTM data."""

from __future__ import annotations

import contextlib
import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from teleop_force.errors import ModelError, ModelFileError, TeleopForceError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.coulomb_viscous import CoulombViscous
from teleop_force.friction.model_coordinates import ModelCoordinateFriction, distinct_axes
from teleop_force.friction.model_file import friction_from_dict
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.robots.dvrk_mtm import dvrk_mtm_description, mtm_model_coupling
from tests.fuzz.targets import model_seed_dicts
from tests.shared_data import require

#: A 3-joint chain whose last two model joints are relative angles (square, not identity).
RELATIVE = np.array([[1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [0.0, -1.0, 1.0]])


def _random_model(coupling: np.ndarray, seed: int = 0) -> ModelCoordinateFriction:
    model = ModelCoordinateFriction(coupling)
    model.parameters = np.random.default_rng(seed).normal(size=model.parameters.size)
    return model


def _velocities(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(50, n))


def test_torque_is_the_model_friction_through_the_coupling_transpose():
    coupling = np.random.default_rng(2).normal(size=(5, 3))  # no two rows parallel
    model = _random_model(coupling)
    assert model.axis_rows == (0, 1, 2, 3, 4)
    qd = _velocities(3)
    w = qd @ coupling.T
    p = model.parameters.reshape(5, 2)
    expected = (np.sign(w) * p[:, 0] + w * p[:, 1]) @ coupling  # rows: (T^T f(T qd))^T
    np.testing.assert_allclose(model.torque(qd), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.torque(qd[3]), expected[3], rtol=0, atol=1e-12)


def test_mtm_parallel_rows_share_one_law_and_the_torque_is_t_transpose_f():
    coupling = mtm_model_coupling()
    model = _random_model(coupling)
    # the parallelogram's top link (row 9: qd2 - qd3) turns with the elbow (row 3: qd3 - qd2)
    assert model.axis_rows == (0, 1, 2, 3, 4, 5, 6, 7)
    assert model.n_axes == 8 and model.parameters.size == 16
    qd = _velocities(7)
    f_model = np.zeros((qd.shape[0], coupling.shape[0]))
    w = qd @ model.axes.T
    p = model.parameters.reshape(model.n_axes, 2)
    f_model[:, list(model.axis_rows)] = np.sign(w) * p[:, 0] + w * p[:, 1]  # f(T qd) per axis
    np.testing.assert_allclose(model.torque(qd), f_model @ coupling, rtol=0, atol=1e-12)
    # a law on the top link instead is the same torque: Coulomb and viscous are odd
    top_first = ModelCoordinateFriction(coupling[[0, 1, 8, 3, 4, 5, 6, 7]], model.parameters)
    np.testing.assert_allclose(top_first.torque(qd), model.torque(qd), rtol=0, atol=1e-12)


def test_regressor_times_parameters_is_the_torque():
    for coupling in (RELATIVE, mtm_model_coupling()):
        model = _random_model(coupling)
        qd = _velocities(coupling.shape[1])
        regressor = model.regressor(qd)
        assert regressor.shape == (qd.shape[0], coupling.shape[1], model.parameters.size)
        np.testing.assert_allclose(
            regressor @ model.parameters, model.torque(qd), rtol=0, atol=1e-12
        )


def test_regressor_columns_are_the_terms_basis_through_the_coupling():
    model = _random_model(mtm_model_coupling())
    qd = _velocities(7)
    qd[:5, 2] = qd[:5, 1]  # the elbow axis at rest
    w = qd @ model.axes.T
    regressor = model.regressor(qd)
    for a in range(model.n_axes):
        columns = np.stack((np.sign(w[:, a]), w[:, a]), axis=1)  # [sgn w_a, w_a]
        for j in range(model.n_joints):
            got = regressor[:, j, model.axis_slice(a)]
            np.testing.assert_allclose(got, model.axes[a, j] * columns, rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(regressor[:5, :, model.axis_slice(2)], 0.0)
    with pytest.raises(ModelError, match="expected 7 velocities"):
        model.regressor(qd[:, :6])


def test_identity_coupling_is_the_plain_coulomb_viscous_model():
    model = _random_model(np.eye(4))
    plain = CoulombViscous(4, model.parameters)
    qd = _velocities(4)
    np.testing.assert_allclose(model.torque(qd), plain.torque(qd), rtol=0, atol=1e-15)
    np.testing.assert_allclose(model.regressor(qd), plain.regressor(qd), rtol=0, atol=1e-15)
    assert model.all_parameter_names()[:2] == ["a_c,m1", "a_v,m1"]


def test_names_follow_the_model_joints_and_the_joints_they_act_on():
    model = ModelCoordinateFriction(RELATIVE)
    assert model.all_parameter_names() == [
        "a_c,m1",
        "a_v,m1",
        "a_c,m2",
        "a_v,m2",
        "a_c,m3",
        "a_v,m3",
    ]
    assert model.parameter_names(1) == ["a_c,m2", "a_v,m2", "a_c,m3", "a_v,m3"]
    assert model.axis_slice(2) == slice(4, 6)


def test_distinct_axes_skip_zero_and_parallel_rows():
    coupling = np.array([[1.0, 2.0], [0.0, 0.0], [-2.0, -4.0], [0.0, 1.0], [1.0, 2.0 + 1e-3]])
    assert distinct_axes(coupling) == (0, 3, 4)


def test_the_per_joint_interface_refuses_instead_of_answering_wrong():
    model = ModelCoordinateFriction(RELATIVE)
    assert not model.block_diagonal
    for call in (
        lambda: model.basis(0, _velocities(3)),
        lambda: model.joint_slice(0),
        lambda: model.joint_parameters(1),
    ):
        with pytest.raises(ModelError, match="through the coupling"):
            call()


@pytest.mark.parametrize(
    "coupling",
    [np.ones((3, 2)), np.eye(3)[:2], np.array([[1.0, math.nan], [0.0, 1.0]]), np.zeros(3)],
)
def test_bad_couplings_are_model_errors(coupling):
    with pytest.raises(ModelError):
        ModelCoordinateFriction(coupling)


def test_round_trip_through_the_model_file(tmp_path: Path):
    seed = copy.deepcopy(model_seed_dicts()[2])  # a ``none`` model of 3 joints
    friction = _random_model(RELATIVE)
    seed["friction"] = friction.to_dict()
    path = tmp_path / "model.json"
    path.write_text(json.dumps(seed))
    model = DynamicModel.load(path)
    assert isinstance(model.friction, ModelCoordinateFriction)
    assert json.dumps(model.to_dict()) == json.dumps(seed)
    qd = _velocities(3)
    np.testing.assert_array_equal(model.friction.torque(qd), friction.torque(qd))
    assert friction_from_dict(json.loads(json.dumps(friction.to_dict()))).axis_rows == (0, 1, 2)
    estimator = ForceEstimator(model)  # the streaming estimator evaluates it too
    for k in range(3):
        estimator.update(k * 1e-3, np.full(3, 0.1 * k), np.zeros(3))


def _friction_dict() -> dict:
    return _random_model(RELATIVE).to_dict()


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d.pop("coupling"), "coupling"),
        (lambda d: d.pop("parameters"), "parameters"),
        (lambda d: d.update(n_joints=True), "n_joints"),
        (lambda d: d.update(n_joints=4), "coupling"),
        (lambda d: d.update(coupling="eye"), "coupling"),
        (lambda d: d.update(coupling=[[1.0, 0.0], [0.0, 1.0]]), "coupling"),
        (lambda d: d.update(coupling=[[1.0, 0.0, 0.0]] * 3), "coupling"),
        (lambda d: d["coupling"][1].__setitem__(0, math.nan), "coupling"),
        (lambda d: d["coupling"][1].__setitem__(0, 10**400), "coupling"),
        (lambda d: d.update(coupling=[[1.0, 0.0, 0.0]] * 2000), "coupling"),
        (lambda d: d.update(parameters=d["parameters"][:-1]), "parameters"),
        (lambda d: d.update(parameters=[d["parameters"]]), "parameters"),
        (lambda d: d["parameters"].__setitem__(2, math.inf), "parameters"),
        (lambda d: d["parameters"].__setitem__(2, "x"), "parameters"),
    ],
)
def test_bad_friction_entries_are_refused_naming_the_field(tmp_path: Path, change, field):
    data = _friction_dict()
    change(data)
    with pytest.raises(ModelFileError) as info:
        ModelCoordinateFriction.from_dict(data)
    assert info.value.column.split("[")[0] == field, str(info.value)  # or an element of it
    seed = copy.deepcopy(model_seed_dicts()[2])
    seed["friction"] = data
    path = tmp_path / "model.json"
    path.write_text(json.dumps(seed))
    with pytest.raises(ModelFileError) as info:
        DynamicModel.load(path)
    assert str(path) in str(info.value) and f"column 'friction.{field}" in str(info.value)


def test_a_model_file_entry_that_is_not_an_object_is_refused():
    with pytest.raises(ModelFileError, match="expected an object"):
        ModelCoordinateFriction.from_dict([1, 2])  # type: ignore[arg-type]


def test_every_bad_number_is_refused_or_gives_a_working_estimator(tmp_path: Path):
    seed = copy.deepcopy(model_seed_dicts()[2])
    seed["friction"] = _friction_dict()
    for row in range(3):
        for col in range(3):
            for bad in (math.nan, math.inf, 10**400, -1, 10**6, 0):
                data = copy.deepcopy(seed)
                data["friction"]["coupling"][row][col] = bad
                path = tmp_path / "model.json"
                path.write_text(json.dumps(data))
                try:
                    model = DynamicModel.load(path)
                except ModelFileError as exc:
                    # parallel rows after the change: fewer laws than parameters
                    assert "column 'friction.coupling" in str(exc) or (
                        "column 'friction.parameters" in str(exc)
                    ), str(exc)
                    continue
                assert math.isfinite(bad)
                estimator = ForceEstimator(model)
                with contextlib.suppress(TeleopForceError):
                    estimator.update(0.0, np.zeros(3), np.zeros(3))


def test_shared_mtm_data_model_coordinates_lower_joints_2_and_3(tmp_path: Path):
    """Identified on trajectory one, evaluated on trajectory two (the held-out one)."""
    from teleop_force.identification.pipeline import evaluate_model, identify_model
    from teleop_force.io.dvrk_mtm_csv import read_mtm_csv

    folder = require("dvrk_mtm")
    train = read_mtm_csv(folder / "mtm_traj_one_results.csv").recording
    test = read_mtm_csv(folder / "mtm_traj_two_results.csv").recording
    model, report = identify_model([train], dvrk_mtm_description(), "model-cv")
    assert isinstance(model.friction, ModelCoordinateFriction)
    assert report.stage_one is not None
    result = evaluate_model(model, [test])["relative_rms"]
    # measured: 11.8 / 18.3 / 25.3 %; per-motor CV 12.5 / 24.2 / 33.5 %, coupled CV j3 29.3 %
    assert result[1] < 0.20 and result[2] < 0.27, result
    path = tmp_path / "mtm.json"
    model.save(path)
    again = evaluate_model(DynamicModel.load(path), [test])["relative_rms"]
    np.testing.assert_allclose(again, result, rtol=1e-12)
