import argparse
import dataclasses
import json

import numpy as np
import pytest

from teleop_force.errors import ConfigurationError, ModelFileError
from teleop_force.estimation.batch import BatchEstimator
from teleop_force.estimation.estimator import (
    ForceEstimator,
    estimator_from_args,
    estimator_metadata,
    with_estimator,
    with_recorded_estimator,
)
from teleop_force.estimation.flags import (
    add_estimator_arguments,
    forwarded_estimator_arguments,
    given_estimator_flags,
)
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.identification.dynamic_model import DynamicModel
from teleop_force.identification.filtered_regressor import FilterConfig, filter_signals
from teleop_force.identification.regressor import RigidBodyRegressor, full_parameters
from teleop_force.robots.omni import SPRING_STIFFNESS_NM_PER_RAD, omni_description

#: The paper's filtered dynamics without a dead band: what identification's batch form computes.
PAPER_FILTER = FilterConfig(estimator="filter", standstill_band_rad_s=0.0)


def _model() -> DynamicModel:
    description = omni_description()
    regressor = RigidBodyRegressor(description)
    base = regressor.find_base_parameters()
    beta = base.project(full_parameters(description, [SPRING_STIFFNESS_NM_PER_RAD]))
    friction = CoupledCoulombViscous(
        3,
        description.friction_inputs,
        np.array([0.02, 0.002, 0.02, 0.01, 0.003, 0.004, 0.01, 0.002, 0.018, 0.005]),
    )
    return DynamicModel("omni", 3, PAPER_FILTER, base, beta, 0 * beta, friction, np.zeros(3))


def _motion(n: int = 1500):
    t = np.arange(n) * 1e-3
    q = np.column_stack(
        [0.3 * np.sin(2 * t), 0.8 + 0.4 * np.sin(3 * t), 0.2 + 0.5 * np.cos(1.5 * t)]
    )
    q = np.round(q / 4e-4) * 4e-4
    tau = np.column_stack([0.05 * np.sin(5 * t), 0.2 + 0.05 * np.cos(t), 0.01 * np.sin(7 * t)])
    return t, q, tau


def test_streaming_estimate_equals_batch_model_torque() -> None:
    model = _model()
    t, q, tau = _motion()
    signals = filter_signals(
        t, q, tau, RigidBodyRegressor(model.description()), model.base, model.filter_config
    )
    batch = model.predict_filtered_torque(signals, tau)
    estimator = ForceEstimator(model)
    streamed = np.array(
        [estimator.update(t[k], q[k], tau[k]).tau_model_filtered_nm for k in range(t.size)]
    )
    np.testing.assert_allclose(streamed, batch, atol=1e-9)
    ext = np.array([0.0])
    estimator.reset()
    first = estimator.update(t[0], q[0], tau[0])
    ext = first.tau_external_nm
    assert ext.shape == (3,)


def test_force_is_recovered_from_a_pure_external_torque() -> None:
    # A robot at rest whose motors push on a sensor: tau = model + J^T F.
    model = _model()
    estimator = ForceEstimator(model)
    q = np.array([0.1, 0.7, 0.3])
    force = np.array([0.2, -1.5, 0.4])
    from teleop_force.robots.description import Robot

    robot = Robot(model.description())
    k = np.array([SPRING_STIFFNESS_NM_PER_RAD])
    tau = (
        robot.gravity_torque(q)
        + robot.spring_torque(q, k)
        + robot.tip_jacobian_in_base(q).T @ force
    )
    for i in range(2000):
        est = estimator.update(i * 1e-3, q, tau)
    np.testing.assert_allclose(est.force_tip_in_base_n, force, atol=1e-6)
    assert not est.singular


def test_singular_jacobian_is_reported_not_divided() -> None:
    model = _model()
    estimator = ForceEstimator(model)
    # r = l1 cos q2 + l2 sin q3 = 0: the tip is on the yaw axis, the Jacobian loses rank.
    q = np.array([0.0, np.pi / 2, 0.0])
    est = estimator.update(0.0, q, np.zeros(3))
    assert est.singular
    assert np.all(np.isnan(est.force_tip_in_base_n))


def test_estimator_choice_round_trips_through_the_model_file(tmp_path) -> None:
    model = with_estimator(_model(), "observer", 12.5, 0.01)
    assert model.filter_config.observer and model.filter_config.observer_hz == 12.5
    path = tmp_path / "model.json"
    model.save(path)
    saved = json.loads(path.read_text())["filter"]
    assert saved["estimator"] == "observer" and saved["observer_hz"] == 12.5
    loaded = DynamicModel.load(path)
    assert loaded.filter_config == model.filter_config
    t, q, tau = _motion(400)
    np.testing.assert_array_equal(
        BatchEstimator(loaded).estimate(t, q, tau).tau_external_nm,
        BatchEstimator(model).estimate(t, q, tau).tau_external_nm,
    )


def test_a_model_file_without_the_choice_reads_as_the_filter(tmp_path) -> None:
    model = _model()
    data = model.to_dict()
    for key in ("estimator", "observer_hz", "standstill_band_rad_s"):
        del data["filter"][key]
    loaded = DynamicModel.from_dict(data)
    assert loaded.filter_config == FilterConfig(
        estimator="filter", observer_hz=8.0, standstill_band_rad_s=0.0
    )
    assert loaded.filter_config.estimator == "filter"
    assert loaded.filter_config.standstill_band_rad_s == 0.0


def test_a_model_file_without_the_observer_prefilter_runs_the_observer_on_lv() -> None:
    """Files from before the observer's own pre-filter: their observer ran on ``L_v``."""
    model = with_estimator(_model(), "observer", 24.0, observer_prefilter_stages=2)
    data = model.to_dict()
    assert data["filter"]["observer_prefilter_stages"] == 2  # written by this version
    for key in ("observer_prefilter_hz", "observer_prefilter_stages"):
        del data["filter"][key]
    config = DynamicModel.from_dict(data).filter_config
    assert config.observer_prefilter_hz is None  # follows L_v
    assert config.estimator_prefilter == (model.filter_config.velocity_cutoff_hz, 1)
    faster = dataclasses.replace(config, velocity_cutoff_hz=35.0)
    assert faster.estimator_prefilter == (35.0, 1)


def test_a_model_file_without_the_output_filter_has_none() -> None:
    """Files from before the observer's output Butterworth: their estimates had none."""
    model = with_estimator(_model(), "observer", 400.0, observer_output_hz=40.0)
    data = model.to_dict()
    assert data["filter"]["observer_output_hz"] == 40.0  # written by this version
    del data["filter"]["observer_output_hz"]
    config = DynamicModel.from_dict(data).filter_config
    assert config.observer_output_hz == 0.0 and config.estimator_output_hz == 0.0
    # recorded before the field: replayed without it, whatever the model says
    metadata = {"model": "m.json", **estimator_metadata(model)}
    assert with_recorded_estimator(_model(), metadata).filter_config.observer_output_hz == 40.0
    del metadata["observer_output_hz"]
    assert with_recorded_estimator(model, metadata).filter_config.observer_output_hz == 0.0
    none = with_estimator(model, observer_output_hz=0.0)
    assert estimator_metadata(none)["observer_output_hz"] == "0.0"
    assert with_estimator(model, "filter").filter_config.estimator_output_hz == 0.0


@pytest.mark.parametrize(
    ("key", "value"), [("estimator", "kalman"), ("observer_hz", 0.0), ("observer_hz", -1.0),
                       ("standstill_band_rad_s", -0.01), ("observer_prefilter_hz", 0.0),
                       ("observer_prefilter_stages", 3), ("observer_output_hz", -5.0)],
)  # fmt: skip
def test_a_bad_choice_in_the_model_file_is_named(key, value) -> None:
    data = _model().to_dict()
    data["filter"][key] = value
    with pytest.raises(ModelFileError, match=key):
        DynamicModel.from_dict(data, "model.json")


def test_with_estimator_overrides_only_what_is_given() -> None:
    model = _model()
    assert with_estimator(model) is model
    assert with_estimator(model, "filter", FilterConfig.observer_hz) is model
    observer = with_estimator(model, "observer")
    assert observer.filter_config.observer_hz == model.filter_config.observer_hz
    assert observer.filter_config.cutoff_hz == model.filter_config.cutoff_hz
    assert observer.friction is model.friction
    with pytest.raises(ConfigurationError, match="estimator"):
        with_estimator(model, "kalman")


def test_recording_metadata_names_the_estimator_a_replay_runs() -> None:
    chosen = with_estimator(_model(), "observer", 20.0, 0.005)
    # a pre-filter that follows L_v (as in files from before the observer had its own)
    model = dataclasses.replace(
        chosen, filter_config=dataclasses.replace(chosen.filter_config, observer_prefilter_hz=None)
    )
    metadata = {"model": "m.json", **estimator_metadata(model)}
    assert all(isinstance(v, str) for v in metadata.values())
    replayed = with_recorded_estimator(_model(), metadata).filter_config
    # the metadata holds the pre-filter's effective cutoff (L_v's here, which the model follows)
    assert replayed.estimator_prefilter == model.filter_config.estimator_prefilter
    assert dataclasses.replace(replayed, observer_prefilter_hz=None) == model.filter_config
    old = _model()
    assert with_recorded_estimator(old, {"model": "m.json"}) is old  # older recordings
    with pytest.raises(ConfigurationError, match="observer_hz"):
        with_recorded_estimator(old, {"estimator": "observer", "observer_hz": "fast"})
    # recorded before the observer had its own pre-filter: it ran on L_v, one stage
    two_stages = with_estimator(_model(), "observer", observer_prefilter_stages=2)
    before = {k: v for k, v in metadata.items() if "prefilter" not in k}
    replayed = with_recorded_estimator(two_stages, before).filter_config
    assert replayed.estimator_prefilter == (replayed.velocity_cutoff_hz, 1)
    with pytest.raises(ConfigurationError, match="observer_prefilter_stages"):
        with_recorded_estimator(old, {**metadata, "observer_prefilter_stages": "3"})


def test_estimator_flags_override_the_model() -> None:
    parser = argparse.ArgumentParser()
    add_estimator_arguments(parser)
    model = _model()
    assert estimator_from_args(model, parser.parse_args([])) is model
    args = parser.parse_args(["--estimator", "observer", "--observer-hz", "16"])
    chosen = estimator_from_args(model, args)
    prefilter = parser.parse_args(
        ["--estimator", "observer", "--observer-prefilter-hz", "30", "--observer-prefilter-stages",
         "1"]
    )  # fmt: skip
    assert estimator_from_args(model, prefilter).filter_config.estimator_prefilter == (30.0, 1)
    assert (chosen.filter_config.estimator, chosen.filter_config.observer_hz) == ("observer", 16)
    output = parser.parse_args(["--observer-output-hz", "30"])
    assert estimator_from_args(model, output).filter_config.observer_output_hz == 30.0
    none = estimator_from_args(model, parser.parse_args(["--observer-output-hz", "0"]))
    assert none.filter_config.observer_output_hz == 0.0
    with pytest.raises(SystemExit):
        parser.parse_args(["--estimator", "kalman"])


def test_estimator_flags_forwarded_to_a_child_parse_back_the_same() -> None:
    """The demo hands its estimator flags to the service's command line."""
    parser = argparse.ArgumentParser()
    add_estimator_arguments(parser)
    assert forwarded_estimator_arguments(parser.parse_args([])) == ()
    given = parser.parse_args(
        ["--estimator", "observer", "--observer-hz", "16.5", "--observer-prefilter-hz", "30",
         "--observer-prefilter-stages", "2", "--observer-output-hz", "35"]
    )  # fmt: skip
    assert given_estimator_flags(given) == {
        "estimator": "observer",
        "observer_hz": 16.5,
        "observer_prefilter_hz": 30.0,
        "observer_prefilter_stages": 2,
        "observer_output_hz": 35.0,
    }
    words = forwarded_estimator_arguments(given)
    assert "--observer-prefilter-stages" in words
    assert parser.parse_args(list(words)) == given


def test_the_count_observer_is_recorded_and_replayed() -> None:
    model = with_estimator(_model(), count_observer=True, count_rad=(4e-4, 4e-4, 5e-4))
    metadata = {"model": "m.json", **estimator_metadata(model)}
    assert metadata["count_observer"] == "1"
    replayed = with_recorded_estimator(_model(), metadata).filter_config
    assert replayed.count_observer and replayed.count_rad == (4e-4, 4e-4, 5e-4)
    # recorded before the field: on the readings, whatever the model says
    before = {k: v for k, v in metadata.items() if not k.startswith("count_")}
    assert not with_recorded_estimator(model, before).filter_config.count_observer
    with pytest.raises(ConfigurationError, match="count_observer"):
        with_recorded_estimator(model, {**metadata, "count_observer": "yes"})
    with pytest.raises(ConfigurationError, match="count_rad"):
        with_recorded_estimator(model, {**metadata, "count_rad": "4e-4 x"})


@pytest.mark.parametrize("words", [["--count-observer"], ["--no-count-observer"]])
def test_the_count_observer_switch_is_forwarded_as_given(words) -> None:
    parser = argparse.ArgumentParser()
    add_estimator_arguments(parser)
    args = parser.parse_args(words)
    assert forwarded_estimator_arguments(args) == tuple(words)
    model = with_estimator(_model(), count_rad=(4e-4, 4e-4, 4e-4))
    chosen = estimator_from_args(model, args).filter_config
    assert chosen.count_observer is (words[0] == "--count-observer")
