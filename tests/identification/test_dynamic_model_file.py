"""Bad model files give a ModelFileError naming the file and the field, at load time.

Findings M1-M5 of the fuzzing (docs/reliability.md): a model file that is not UTF-8, numbers
beyond float64, indices outside what they index and NaN / infinite parameters used to pass
``DynamicModel.load`` (or leak a raw UnicodeDecodeError / OverflowError) and fail later in
the estimator (IndexError, NameError in the generated code, or every estimate NaN).
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from teleop_force.errors import ModelFileError, TeleopForceError
from teleop_force.estimation.estimator import ForceEstimator
from teleop_force.friction.coverage import CoverageMap
from teleop_force.friction.wavelet_network import WaveletNetwork, WaveletPool, omni_wavelet_specs
from teleop_force.identification.dynamic_model import DynamicModel
from tests.fuzz.targets import model_seed_dicts

#: The fuzzing's seeds: the shipped model, a WN model with its fallback, a ``none`` model.
SEEDS = dict(zip(("cv", "wn", "none"), model_seed_dicts(), strict=True))
HUGE = 10**400  # an integer JSON can hold and float64 cannot


def _write(tmp_path: Path, data: dict, name: str = "model.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))  # NaN and Infinity are written as JSON5 tokens
    return path


def _changed(seed: str, change) -> dict:
    data = copy.deepcopy(SEEDS[seed])
    change(data)
    return data


def _refused(tmp_path: Path, data: dict, field: str) -> ModelFileError:
    """Load ``data`` from a file: must be a ModelFileError naming the file and ``field``."""
    path = _write(tmp_path, data)
    with pytest.raises(ModelFileError) as info:
        DynamicModel.load(path)
    message = str(info.value)
    assert str(path) in message, message
    assert f"column '{field}" in message, message  # the field, or a part of it
    assert len(message) < 500, message
    return info.value


def _run(model: DynamicModel) -> None:
    estimator = ForceEstimator(model)
    q = np.full(model.n_joints, 0.3)
    for k in range(3):
        estimator.update(k * 1e-3, q, np.zeros(model.n_joints))


@pytest.mark.parametrize("seed", sorted(SEEDS))
def test_valid_files_still_load_and_round_trip(tmp_path, seed):
    model = DynamicModel.load(_write(tmp_path, SEEDS[seed]))
    assert json.dumps(model.to_dict()) == json.dumps(SEEDS[seed])
    _run(model)


def test_m1_a_file_that_is_not_utf8(tmp_path):
    path = tmp_path / "model.json"
    path.write_bytes(json.dumps(SEEDS["cv"]).encode()[:100] + b"\xff\xfe" + b"}")
    with pytest.raises(ModelFileError, match="not UTF-8") as info:
        DynamicModel.load(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("text", "problem"),
    [("[" * 100_000 + "]" * 100_000, "not JSON"), ("9" * 5000, "not JSON")],
)
def test_pathological_json_is_a_model_file_error(tmp_path, text, problem):
    path = tmp_path / "model.json"
    path.write_text(text)
    with pytest.raises(ModelFileError, match=problem):
        DynamicModel.load(path)


@pytest.mark.parametrize(
    ("seed", "change", "field"),
    [
        ("cv", lambda d: d.update(n_joints=math.inf), "n_joints"),
        ("cv", lambda d: d.update(n_joints=HUGE), "n_joints"),
        ("cv", lambda d: d.update(n_joints=2**40), "n_joints"),  # would allocate 8 TB
        ("cv", lambda d: d["base"]["independent"].__setitem__(0, 10**30), "base.independent"),
        ("cv", lambda d: d["base_values"].__setitem__(2, HUGE), "base_values"),
        ("cv", lambda d: d["friction"].update(n_joints=math.inf), "friction.n_joints"),
        ("cv", lambda d: d["filter"].update(torque_lag_samples=HUGE), "filter.torque_lag_samples"),
        ("wn", lambda d: d["friction"]["joints"][0].update(m_min=HUGE), "friction.joints[0].m_min"),
        (
            "wn",
            lambda d: d["friction"]["coverage"]["grids"][0]["counts"].__setitem__(3, HUGE),
            "friction.coverage.grids[0].counts",
        ),
        (
            "wn",
            lambda d: d["friction"]["coverage"]["config"].update(cell_size_1d_rad_s=1e-300),
            "friction.coverage",
        ),
    ],
)
def test_m2_numbers_beyond_float64_or_int64(tmp_path, seed, change, field):
    _refused(tmp_path, _changed(seed, change), field)


def _wn_joint(j: int, key: str, value) -> Callable[[dict], None]:
    return lambda d: d["friction"]["joints"][j].__setitem__(key, value)


@pytest.mark.parametrize(
    ("seed", "change", "field"),
    [
        ("cv", lambda d: d["base"]["independent"].__setitem__(-1, 34), "base.independent"),
        ("cv", lambda d: d["base"]["independent"].__setitem__(0, -1), "base.independent"),
        ("cv", lambda d: d["base"]["dependent"].__setitem__(0, 1.5), "base.dependent"),
        (  # in range, but listed twice (another index is missing)
            "cv",
            lambda d: d["base"]["independent"].__setitem__(1, d["base"]["independent"][0]),
            "base.independent",
        ),
        (  # one full parameter more than the robot has
            "cv",
            lambda d: (
                d["base"]["full_names"].append("extra"),
                d["base"]["dependent"].append(len(d["base"]["full_names"]) - 1),
                [row.append(0.0) for row in d["base"]["dependency"]],
            ),
            "base.full_names",
        ),
        ("cv", lambda d: d["base"]["dependency"].pop(), "base.dependency"),
        ("cv", lambda d: d["base_values"].pop(), "base_values"),
        ("cv", lambda d: d["offsets_nm"].pop(), "offsets_nm"),
        (
            "cv",
            lambda d: d["friction"]["friction_inputs"][1].__setitem__(1, 3),
            "friction.friction_inputs[1]",
        ),
        ("wn", _wn_joint(1, "active", [[0, 99, 0]]), "friction.joints[1].active"),
        ("wn", _wn_joint(1, "active", [[0, 1, 1], [0, 1, 1]]), "friction.joints[1].active"),
        ("wn", _wn_joint(0, "coefficients", [0.0]), "friction.joints[0].coefficients"),
        ("wn", _wn_joint(2, "inputs", [1, 7]), "friction.joints[2].inputs"),
        (
            "wn",
            lambda d: d["friction"]["coverage"]["grids"][2]["inputs"].__setitem__(1, 5),
            "friction.coverage.grids[2].inputs",
        ),
        (
            "wn",
            lambda d: d["friction"]["coverage"]["grids"].pop(),
            "friction.coverage.grids",
        ),
        (
            "wn",
            lambda d: d["friction"]["fallback"]["friction_inputs"][2].__setitem__(0, 9),
            "friction.fallback.friction_inputs[2]",
        ),
    ],
)
def test_m3_indices_and_shapes_are_checked_at_load(tmp_path, seed, change, field):
    """Each of these used to load and then raise IndexError in the estimator (or be wrong)."""
    _refused(tmp_path, _changed(seed, change), field)


def test_m4_nan_spring_stiffness_is_refused_before_any_code_is_generated(tmp_path):
    from teleop_force.service.force_service import load_model

    data = _changed("cv", lambda d: d["base_values"].__setitem__(-1, math.nan))
    assert data["base"]["full_names"][-1] == "k_2"  # the spring stiffness
    error = _refused(tmp_path, data, "base_values")
    assert "nan" in str(error)
    with pytest.raises(ModelFileError, match="base_values"):  # the service's start-up load
        load_model(tmp_path / "model.json")


NON_FINITE = [math.nan, math.inf, -math.inf]


@pytest.mark.parametrize("bad", NON_FINITE, ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize(
    ("seed", "where", "field"),
    [
        ("cv", lambda d: d["base_values"], "base_values"),
        ("cv", lambda d: d["offsets_nm"], "offsets_nm"),
        ("cv", lambda d: d["base"]["dependency"][3], "base.dependency"),
        ("cv", lambda d: d["friction"]["parameters"], "friction.parameters"),
        ("none", lambda d: d["offsets_nm"], "offsets_nm"),
        (
            "wn",
            lambda d: d["friction"]["joints"][1]["coefficients"],
            "friction.joints[1].coefficients",
        ),
        (
            "wn",
            lambda d: d["friction"]["joints"][1]["x_max_rad_s"],
            "friction.joints[1].x_max_rad_s",
        ),
        ("wn", lambda d: d["friction"]["fallback"]["parameters"], "friction.fallback.parameters"),
        (
            "wn",
            lambda d: d["friction"]["coverage"]["grids"][1]["counts"],
            "friction.coverage.grids[1].counts",
        ),
    ],
)
def test_m5_non_finite_parameters_are_refused_naming_the_field(tmp_path, bad, seed, where, field):
    data = copy.deepcopy(SEEDS[seed])
    where(data)[0] = bad
    _refused(tmp_path, data, field)


@pytest.mark.parametrize("key", ["cutoff_hz", "velocity_cutoff_hz", "warmup_s"])
def test_non_finite_filter_settings_are_refused(tmp_path, key):
    _refused(
        tmp_path, _changed("cv", lambda d: d["filter"].update({key: math.inf})), f"filter.{key}"
    )


@pytest.mark.parametrize("key", ["mu", "theta", "a0"])
def test_non_finite_network_constants_are_refused(tmp_path, key):
    if key == "a0":
        data = _changed("wn", lambda d: d["friction"].update(a0=math.inf))
        _refused(tmp_path, data, "friction.a0")
    else:
        data = _changed("wn", _wn_joint(0, key, math.inf))
        _refused(tmp_path, data, "friction.joints[0]")


def test_base_std_may_be_unknown(tmp_path):
    data = _changed("cv", lambda d: d.update(base_std=[math.nan] * len(d["base_values"])))
    model = DynamicModel.load(_write(tmp_path, data))
    assert np.all(np.isnan(model.base_std))
    _run(model)


@pytest.mark.parametrize(
    "change",
    [
        _wn_joint(1, "m_min", -30),  # 2-D joint: ~10^19 wavelets
        _wn_joint(1, "m_min", -(2**40)),  # 2^40 dilations
        _wn_joint(0, "x_max_rad_s", [1e300]),
        lambda d: (  # dilations that hardly narrow: the count is bounded, not the pool
            d["friction"].update(a0=1.0 + 1e-12),
            d["friction"]["joints"][0].update(m_min=-100),
        ),
        lambda d: d["friction"]["coverage"]["config"].update(smoothing_cells=1e6),  # 90 s / grid
    ],
)
def test_a_network_too_large_to_build_is_refused_without_allocating_it(tmp_path, change):
    """A few bytes of JSON used to make the pool allocate gigabytes (or loop for hours)."""
    path = _write(tmp_path, _changed("wn", change))
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError) as info:
            DynamicModel.load(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 200e6, f"{peak / 1e6:.0f} MB"
    assert str(path) in str(info.value) and "column 'friction" in str(info.value)


def test_pool_bounds_hold_for_programmatic_networks_too():
    specs = list(omni_wavelet_specs())
    specs[1] = type(specs[1])(
        specs[1].inputs, specs[1].x_min_rad_s, specs[1].x_max_rad_s, -20, 0, 1e-5, 1e-5
    )
    with pytest.raises(TeleopForceError, match="exceed"):
        WaveletPool(specs, 3)
    coverage = CoverageMap.for_inputs([(0,), (1, 2)], [(-1,), (-1, -1)], [(1,), (1, 1)])
    with pytest.raises(TeleopForceError, match="coverage"):
        WaveletNetwork(3, omni_wavelet_specs(), coverage=coverage)  # 2 grids for 3 joints


def _leaves(value, path=()):
    """Paths of the numeric leaves of a JSON value (first and last of long lists only)."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, (*path, key))
    elif isinstance(value, list):
        picks = range(len(value)) if len(value) <= 4 else (0, len(value) - 1)
        for i in picks:
            yield from _leaves(value[i], (*path, i))
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield path


def _set(data, path, value):
    for key in path[:-1]:
        data = data[key]
    data[path[-1]] = value


@pytest.mark.parametrize("seed", sorted(SEEDS))
def test_every_number_of_a_model_file_replaced_by_a_bad_one(tmp_path, seed):
    """Each numeric leaf set to NaN, inf, 10**400, -1, 10**6: refused naming the file and
    field, or a model whose estimator runs without anything but a TeleopForceError.
    """
    outcomes = {"refused": 0, "accepted": 0}
    for path in _leaves(SEEDS[seed]):
        for bad in (math.nan, math.inf, HUGE, -1, 10**6):
            data = copy.deepcopy(SEEDS[seed])
            _set(data, path, bad)
            file = _write(tmp_path, data)
            try:
                model = DynamicModel.load(file)
            except ModelFileError as exc:
                assert str(file) in str(exc) and "column '" in str(exc), (path, bad, str(exc))
                outcomes["refused"] += 1
                continue
            outcomes["accepted"] += 1
            if path[0] not in ("base_std", "notes"):  # free to be unknown / free-form
                assert isinstance(bad, int) and abs(bad) < 10**30, (path, bad)  # finite only
            with contextlib.suppress(TeleopForceError):
                _run(model)
    assert outcomes["refused"] > 0 and outcomes["accepted"] > 0, outcomes


def _with_effect(reach) -> Callable[[dict], None]:
    def change(data: dict) -> None:
        entry = {
            "kind": "basis",
            "spec": {"joint": 2, "variable": "q3", "shape": "linear"},
            "coefficients": [0.01],
        }
        if reach is not None:
            entry["reach"] = reach
        data["effects"] = [entry]

    return change


def test_an_effect_at_a_model_joint_loads_round_trips_and_runs(tmp_path):
    data = _changed("cv", _with_effect([0.0, -1.0, 1.0]))
    model = DynamicModel.load(_write(tmp_path, data))
    np.testing.assert_array_equal(model.effects[0].reach, [0.0, -1.0, 1.0])
    assert model.to_dict()["effects"][0]["reach"] == [0.0, -1.0, 1.0]
    q = np.full((1, 3), 0.5)
    np.testing.assert_allclose(model.effects_torque(np.zeros(1), q, q, q), [[0.0, -0.005, 0.005]])
    _run(model)


@pytest.mark.parametrize(
    ("reach", "field"),
    [
        ([0.0, -1.0, 1.0, 0.5], "effects[0].reach"),
        ([1.0, 2.0], "effects[0]"),
        ([0.0, math.nan, 1.0], "effects[0]"),
    ],
)
def test_a_bad_effect_reach_is_refused_naming_it(tmp_path, reach, field):
    _refused(tmp_path, _changed("cv", _with_effect(reach)), field)
