"""The residual loop from a model in hand (``residual DATA --model MODEL``)."""

import json
from pathlib import Path

import numpy as np
import pytest

from teleop_force.cli.main import main
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.pipeline import evaluate_model, identify_model
from teleop_force.io.interchange_csv import Recording, write_interchange_csv
from teleop_force.residual.from_model import trace_from_model
from teleop_force.residual.options import ResidualOptions
from teleop_force.robots.registry import resolve_robot


def _sweep(seed: int, cable: float = 0.0, viscous: float = 0.003) -> Recording:
    """A one-joint sweep forward and back, twice; ``cable``: an angle-dependent torque."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 48.0, 0.005)
    phase = np.mod(t, 24.0)
    q = np.where(phase < 12, -1.4 + 0.4 * phase, -1.4 + 0.4 * (24 - phase))
    q = q + 0.05 * np.sin(0.7 * t + seed)  # not exactly periodic: each sweep its own path
    qd = np.gradient(q, t)
    tau = 0.02 * np.sign(qd) + viscous * qd + 0.01 + cable * np.sin(1.3 * q)
    tau = tau + rng.normal(0, 0.001, t.size)
    return Recording(t, q[:, None], tau[:, None])


@pytest.fixture(scope="module")
def model() -> DynamicModel:
    """A friction-only model of the clean sweep (seed 0)."""
    fitted, _ = identify_model([_sweep(0)], resolve_robot("none", 1), "cv", offsets=True)
    return fitted


def test_an_angle_dependent_torque_missing_from_the_model_is_named(model: DynamicModel) -> None:
    report = trace_from_model([_sweep(1, cable=0.04)], model, model_path="given.json")
    assert report.effects, "the cable torque was not found"
    first = report.effects[0]
    assert first.spec.joint == 0 and "q1" in first.spec.depends_on()
    assert report.after[0] < 0.5 * report.before[0]
    payload = report.to_json()
    assert payload["baseline_model"] == "given.json"
    assert payload["effects"][0]["joint"] == 1
    # the model's own parameters are kept; the effect is added to them
    extended = report.model
    np.testing.assert_array_equal(extended.offsets_nm, model.offsets_nm)
    np.testing.assert_array_equal(extended.friction.parameters, model.friction.parameters)
    assert len(extended.effects) == len(model.effects) + len(report.effects)
    # and on a third recording of the same arm, the extended model is better than the given
    test = [_sweep(2, cable=0.04)]
    given_rms = evaluate_model(model, test)["relative_rms"][0]
    extended_rms = evaluate_model(extended, test)["relative_rms"][0]
    assert extended_rms < 0.5 * given_rms


def test_data_the_model_explains_adds_nothing(model: DynamicModel) -> None:
    report = trace_from_model([_sweep(3)], model)
    assert report.to_json()["effects"] == []
    np.testing.assert_allclose(report.after, report.before)
    assert report.model is model


def test_a_changed_friction_is_named_friction_not_a_pose(model: DynamicModel) -> None:
    report = trace_from_model([_sweep(4, viscous=0.02)], model)
    effects = report.to_json()["effects"]
    assert effects, "the viscous change was not found"
    assert effects[0]["depends_on"] == ["qd1"]
    assert all("q1" not in e["depends_on"] for e in effects)


def test_residual_cli_with_a_model_writes_the_extended_model(tmp_path: Path, capsys) -> None:
    given = tmp_path / "given.json"
    data = tmp_path / "today.csv"
    assert main(["identify", str(_csv(tmp_path / "train.csv", _sweep(0))), "--robot", "none",
                 "--friction", "cv", "-o", str(given)]) == 0  # fmt: skip
    write_interchange_csv(data, _sweep(1, cable=0.04))
    out = tmp_path / "out"
    assert main(["residual", str(data), "--model", str(given), "--json", "-o", str(out)]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["baseline_model"] == str(given.resolve())
    assert payload["effects"] and payload["effects"][0]["joint"] == 1
    assert payload["after"][0] < payload["before"][0]
    extended = DynamicModel.load(out / "model.json")
    assert len(extended.effects) == len(payload["effects"])
    # --friction belongs to a fit from scratch: refused with a model
    code = main(["residual", str(data), "--model", str(given), "--friction", "cv"])
    assert code == 2


def _csv(path: Path, recording: Recording) -> Path:
    write_interchange_csv(path, recording)
    return path


def test_defaults_are_the_robots_best_baseline() -> None:
    mtm = ResidualOptions().for_robot("dvrk-mtm", has_rigid_body=True)
    assert (mtm.friction, mtm.offsets) == ("model-cv", True)
    omni = ResidualOptions().for_robot("omni", has_rigid_body=True)
    assert (omni.friction, omni.offsets) == ("wn", False)
    none = ResidualOptions().for_robot("none", has_rigid_body=False)
    assert none.offsets is True
    chosen = ResidualOptions(friction="cv", offsets=False).for_robot("dvrk-mtm", True)
    assert (chosen.friction, chosen.offsets) == ("cv", False)


def test_a_tip_mass_changes_the_base_parameters_within_the_payload_directions() -> None:
    from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
    from teleop_force.residual.payload import payload_directions
    from teleop_force.robots.omni import omni_description
    from teleop_force.simulation.payload import with_tip_payload

    description = omni_description()
    base = RigidBodyRegressor(description).find_base_parameters()
    directions = payload_directions(base, description)
    assert directions is not None
    np.testing.assert_allclose(directions.T @ directions, np.eye(directions.shape[1]), atol=1e-12)
    stiffness = np.zeros(len(description.springs))
    loaded = with_tip_payload(description, 0.1)
    change = base.project(
        full_parameters(loaded, stiffness) - full_parameters(description, stiffness)
    )
    assert np.linalg.norm(change) > 1e-4  # the mass shows in the base parameters
    np.testing.assert_allclose(directions @ (directions.T @ change), change, atol=1e-10)
    assert payload_directions(None, resolve_robot("none", 2)) is None


@pytest.mark.slow
@pytest.mark.parametrize("family", ["one", "two"])
def test_a_tip_mass_is_named_a_payload_on_both_plant_families(family: str) -> None:
    from teleop_force.reports.blind_tests import run_payload_case

    case = run_payload_case(family, duration_s=30.0, log=lambda _: None)
    assert case.passed, case.found
    payload = case.found[0]
    assert payload["joints"] == [1, 2, 3] and payload["depends_on"] == ["q1", "q2", "q3"]
    # the extended model is better on a third session with the mass than the given one
    assert case.test_after[1] < 0.5 * case.test_before[1]
