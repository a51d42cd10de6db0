# ruff: noqa: E501  (TOML and URDF data literals)
import json
import textwrap
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import DataError, ModelError
from teleop_force.robots.description import Robot
from teleop_force.robots.file import load_robot_description
from teleop_force.robots.registry import resolve_robot

DH_TOML = """
format = "teleop-force-robot"
version = 1
name = "three-link"
joint_names = ["yaw", "pitch", "elbow"]
gravity_mps2 = [0.0, -9.81, 0.0]
coupling = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]
rotor_inertia_kgm2 = [1e-4, 2e-4, 3e-4]
friction_inputs = [[1], [2, 3], [2, 3]]
q_min_rad = [-1.0, 0.0, -0.8]
q_max_rad = [1.0, 1.7, 1.2]
springs = [{ joint = 2, rest_angle_rad = 1.5 }]

[dh]
tip_offset_m = [0.0, 0.0, 0.05]
rows = [
  { alpha_rad = 1.5707963267948966, a_m = 0.0, d_m = 0.1, mass_kg = 0.3 },
  { alpha_rad = 0.0, a_m = 0.2, d_m = 0.0, theta_offset_rad = 0.3, mass_kg = 0.2, com_m = [-0.1, 0, 0] },
  { alpha_rad = 0.0, a_m = 0.15, d_m = 0.0, mass_kg = 0.1, inertia_kgm2 = [[1e-4, 0, 0], [0, 1e-4, 0], [0, 0, 1e-4]] },
]
"""

URDF = """<?xml version="1.0"?>
<robot name="arm">
  <link name="world"/>
  <joint name="slider" type="prismatic">
    <parent link="world"/><child link="base"/><axis xyz="0 0 1"/>
    <limit effort="10" lower="-1" upper="1" velocity="1"/>
  </joint>
  <link name="base"><inertial><mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="hip" type="revolute">
    <parent link="base"/><child link="thigh"/><axis xyz="0 1 0"/>
    <limit effort="10" lower="-3" upper="3" velocity="10"/>
  </joint>
  <link name="thigh"><inertial><origin xyz="0 0 -0.1"/><mass value="0.2"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0001"/></inertial></link>
  <joint name="knee" type="revolute">
    <parent link="thigh"/><child link="shin"/><origin xyz="0 0 -0.2"/><axis xyz="0 1 0"/>
    <limit effort="10" lower="-3" upper="3" velocity="10"/>
  </joint>
  <link name="shin"><inertial><origin xyz="0 0 -0.1"/><mass value="0.1"/><inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.0001"/></inertial></link>
  <joint name="ankle" type="fixed"><parent link="shin"/><child link="foot"/><origin xyz="0 0 -0.2"/></joint>
  <link name="foot"/>
  <joint name="spin" type="continuous"><parent link="shin"/><child link="wheel"/><axis xyz="0 0 1"/></joint>
  <link name="wheel"><inertial><mass value="0.01"/><inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial></link>
</robot>
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def _urdf_file(tmp_path: Path, **overrides) -> Path:
    (tmp_path / "arm.urdf").write_text(URDF)
    data = {
        "format": "teleop-force-robot",
        "version": 1,
        "name": "leg",
        "tip_frame": "foot",
        "urdf": {"path": "arm.urdf", "joints": ["hip", "knee"], "locked": {"slider": 0.2}},
    }
    data.update(overrides)
    return _write(tmp_path, "leg.json", json.dumps(data))


def test_dh_file_builds_the_described_robot(tmp_path):
    desc = load_robot_description(_write(tmp_path, "arm.toml", DH_TOML))
    assert desc.n_joints == 3
    assert desc.joint_names == ("yaw", "pitch", "elbow")
    assert desc.friction_inputs == ((0,), (1, 2), (1, 2))
    assert desc.springs[0].joint == 1 and desc.springs[0].rest_angle_rad == 1.5
    np.testing.assert_allclose(desc.coupling, [[1, 0, 0], [0, 1, 0], [0, -1, 1]])
    np.testing.assert_allclose(desc.model.gravity.linear, [0, -9.81, 0])
    robot = Robot(desc)
    # motor angles (absolute elbow) -> model angles through T
    q_motor = np.array([0.2, 0.5, 0.9])
    q_model = desc.coupling @ q_motor
    data = desc.model.createData()
    pin.framesForwardKinematics(desc.model, data, q_model)
    np.testing.assert_allclose(
        robot.tip_position_in_base(q_motor), data.oMf[desc.model.getFrameId("tip")].translation
    )
    assert desc.name == str((tmp_path / "arm.toml").resolve())


def test_json_and_toml_are_the_same_format(tmp_path):
    import tomllib

    toml_desc = load_robot_description(_write(tmp_path, "arm.toml", DH_TOML))
    json_desc = load_robot_description(
        _write(tmp_path, "arm.json", json.dumps(tomllib.loads(DH_TOML)))
    )
    q = np.array([0.1, 0.4, 0.6])
    np.testing.assert_allclose(Robot(toml_desc).mass_matrix(q), Robot(json_desc).mass_matrix(q))


def test_urdf_file_uses_the_listed_joints_and_locks_the_others(tmp_path):
    desc = load_robot_description(_urdf_file(tmp_path))
    assert desc.n_joints == 2
    assert list(desc.model.names)[1:] == ["hip", "knee"]
    robot = Robot(desc)
    # the slider is locked at 0.2: the foot hangs 0.4 m below it when straight
    np.testing.assert_allclose(
        robot.tip_position_in_base(np.zeros(2)), [0.0, 0.0, 0.2 - 0.4], atol=1e-12
    )


def test_resolve_robot_accepts_a_description_file_and_a_model_finds_it_again(tmp_path):
    path = _write(tmp_path, "arm.toml", DH_TOML)
    desc = resolve_robot(str(path))
    again = resolve_robot(desc.name)
    assert again.n_joints == 3


def test_resolve_robot_builtins():
    assert resolve_robot("dvrk-mtm").n_joints == 7
    assert resolve_robot("teststand").tip_frame == "contact"
    with pytest.raises(ModelError, match="built-in robots"):
        resolve_robot("puma")


def _dh_with(tmp_path: Path, old: str, new: str) -> Path:
    assert old in DH_TOML
    return _write(tmp_path, "bad.toml", DH_TOML.replace(old, new, 1))


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ('format = "teleop-force-robot"', 'format = "other"', "format"),
        ("version = 1", "version = 2", "version"),
        ('name = "three-link"', "", "name"),
        (
            "coupling = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]",
            "coupling = [[1, 0], [0, 1]]",
            "coupling",
        ),
        (
            "coupling = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]",
            "coupling = [[1, 0, 0], [1, 0, 0], [0, 0, 1]]",
            "coupling",
        ),
        (
            "friction_inputs = [[1], [2, 3], [2, 3]]",
            "friction_inputs = [[1], [2, 4], [2, 3]]",
            "friction_inputs[1]",
        ),
        (
            "friction_inputs = [[1], [2, 3], [2, 3]]",
            "friction_inputs = [[1], [3], [2, 3]]",
            "friction_inputs[1]",
        ),
        (
            "springs = [{ joint = 2, rest_angle_rad = 1.5 }]",
            "springs = [{ joint = 0 }]",
            "springs[0].joint",
        ),
        (
            "gravity_mps2 = [0.0, -9.81, 0.0]",
            'gravity_mps2 = [0.0, "down", 0.0]',
            "gravity_mps2[1]",
        ),
        (
            "rotor_inertia_kgm2 = [1e-4, 2e-4, 3e-4]",
            "rotor_inertia_kgm2 = [1e-4]",
            "rotor_inertia_kgm2",
        ),
        ("q_max_rad = [1.0, 1.7, 1.2]", "q_max_rad = [1.0, -1.7, 1.2]", "q_max_rad"),
        ('joint_names = ["yaw", "pitch", "elbow"]', 'joint_names = ["yaw"]', "joint_names"),
        ("a_m = 0.2,", "", "dh.rows[1].a_m"),
        ("a_m = 0.2,", 'a_m = 0.2, type = "ball",', "dh.rows[1].type"),
        ("a_m = 0.2,", "a_m = 0.2, colour = 1,", "dh.rows[1].colour"),
        ("mass_kg = 0.2", "mass_kg = -0.2", "dh.rows[1]"),
        ("[0, 0, 1e-4]]", "[0, 1, 1e-4]]", "dh.rows[2]"),
        ("tip_offset_m = [0.0, 0.0, 0.05]", 'convention = "modified"', "dh.convention"),
        ("[dh]", "speed = 1\n[dh]", "speed"),
    ],
)
def test_bad_dh_file_names_the_field(tmp_path, old, new, field):
    path = _dh_with(tmp_path, old, new)
    with pytest.raises(ModelError) as info:
        load_robot_description(path)
    message = str(info.value)
    assert str(path) in message
    assert f"'{field}'" in message


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"tip_frame": "toe"}, "tip_frame"),
        ({"urdf": {"path": "missing.urdf"}}, "urdf.path"),
        ({"urdf": {"path": "arm.urdf", "joints": ["hip", "elbow"]}}, "urdf.joints[1]"),
        ({"urdf": {"path": "arm.urdf", "joints": ["knee", "hip"]}}, "urdf.joints"),
        ({"urdf": {"path": "arm.urdf", "joints": ["hip", "spin"]}}, "urdf.joints[1]"),
        (
            {"urdf": {"path": "arm.urdf", "joints": ["hip"], "locked": {"knee": "x"}}},
            "urdf.locked.knee",
        ),
        ({"urdf": {"path": "arm.urdf"}, "dh": {"rows": []}}, "urdf"),
    ],
)
def test_bad_urdf_file_names_the_field(tmp_path, change, field):
    path = _urdf_file(tmp_path, **change)
    with pytest.raises(ModelError) as info:
        load_robot_description(path)
    assert f"'{field}'" in str(info.value)


def test_malformed_urdf_is_a_model_error_not_a_pinocchio_exception(tmp_path, capfd):
    path = _urdf_file(tmp_path)
    (tmp_path / "arm.urdf").write_text(
        URDF.replace('<limit effort="10" lower="-3" upper="3" velocity="10"/>', "", 1)
    )
    with pytest.raises(ModelError) as info:
        load_robot_description(path)
    assert "'urdf.path'" in str(info.value)
    assert "limits" in str(info.value)  # urdfdom's own explanation, captured
    assert capfd.readouterr().err == ""


@pytest.mark.parametrize(
    ("name", "text"),
    [("bad.toml", "format = \n"), ("bad.json", "{ nope"), ("bad.json", "[1, 2]")],
)
def test_unparsable_file_is_a_data_error(tmp_path, name, text):
    with pytest.raises(DataError):
        load_robot_description(_write(tmp_path, name, text))


def test_missing_file_and_wrong_suffix(tmp_path):
    with pytest.raises(DataError, match="no such"):
        load_robot_description(tmp_path / "none.toml")
    with pytest.raises(DataError):
        load_robot_description(_write(tmp_path, "arm.yaml", "x: 1"))


# Finding R1 of the fuzzing (docs/reliability.md): an integer beyond float64 anywhere a number
# is read was a raw TypeError from np.isfinite (an object array); now a ModelError naming the
# field. Integers within float64 are numbers like any other.
HUGE = "1" + "0" * 400  # 1e400: no float64


@pytest.mark.parametrize("suffix", [".toml", ".json"])
@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        (
            "gravity_mps2 = [0.0, -9.81, 0.0]",
            f"gravity_mps2 = [{HUGE}, -9.81, 0]",
            "gravity_mps2[0]",
        ),
        ("mass_kg = 0.2", f"mass_kg = -{HUGE}", "dh.rows[1].mass_kg"),
        ("q_max_rad = [1.0, 1.7, 1.2]", f"q_max_rad = [1.0, {HUGE}, 1.2]", "q_max_rad[1]"),
        ("rest_angle_rad = 1.5", f"rest_angle_rad = {HUGE}", "springs[0].rest_angle_rad"),
        ("[0, 0, 1e-4]]", f"[0, 0, {HUGE}]]", "dh.rows[2].inertia_kgm2[2][2]"),
        (
            "tip_offset_m = [0.0, 0.0, 0.05]",
            f"tip_offset_m = [0.0, 0.0, {HUGE}]",
            "dh.tip_offset_m[2]",
        ),
    ],
)
def test_integer_beyond_float64_is_a_model_error_naming_the_field(
    tmp_path, suffix, old, new, field
):
    import tomllib

    path = _dh_with(tmp_path, old, new)
    if suffix == ".json":
        data = tomllib.loads(path.read_text())
        path = _write(tmp_path, "arm.json", json.dumps(data))
    with pytest.raises(ModelError) as info:
        load_robot_description(path)
    message = str(info.value)
    assert str(path) in message
    assert f"'{field}'" in message
    assert "401 digits" in message and len(message) < 400  # not the 401 digits themselves


def test_integer_within_float64_is_read_as_a_float(tmp_path):
    path = _dh_with(
        tmp_path, "gravity_mps2 = [0.0, -9.81, 0.0]", f"gravity_mps2 = [{10**30}, -9.81, 0]"
    )
    desc = load_robot_description(path)  # was: TypeError "ufunc 'isfinite' not supported"
    assert desc.model.gravity.linear[0] == 1e30


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("deep.json", "[" * 100_000 + "]" * 100_000),  # RecursionError in json
        ("long.json", '{"version": ' + "9" * 5000 + "}"),  # ValueError: > 4300 digits
        ("long.toml", "version = " + "9" * 5000 + "\n"),
    ],
)
def test_pathological_json_and_toml_are_data_errors(tmp_path, name, text):
    path = _write(tmp_path, name, text)
    with pytest.raises(DataError) as info:
        load_robot_description(path)
    assert str(path) in str(info.value)
