"""RIHS01 hashes against rosidl's own: the ROS wheels' JSON files and rosidl's generator."""

import contextlib
import io
import json
import re
import sys
from pathlib import Path

import pytest

from teleop_force.ros2 import interfaces as i

SHARE = Path(sys.prefix) / "share"


def wheel_hash(ros_type: str) -> str:
    package, _, name = ros_type.split("/")
    data = json.loads((SHARE / package / "msg" / f"{name}.json").read_text())
    return data["type_hashes"][0]["hash_string"]


@pytest.mark.parametrize("ros_type", [i.JOINT_STATE, i.WRENCH_STAMPED])
def test_standard_hashes_equal_the_wheels_type_hashes(ros_type):
    assert i.type_hash(ros_type) == wheel_hash(ros_type)
    assert re.fullmatch(r"RIHS01_[0-9a-f]{64}", i.type_hash(ros_type))


def test_project_hashes_equal_rosidl_generator_type_description(tmp_path):
    from rosidl_adapter.msg import convert_msg_to_idl
    from rosidl_generator_type_description import generate_type_hash

    idl_dir = tmp_path / i.INTERFACE_PACKAGE / "msg"
    idl_dir.mkdir(parents=True)
    tuples = []
    with contextlib.redirect_stdout(io.StringIO()):  # the adapter prints what it writes
        for ros_type in i.PROJECT_TYPES:
            msg = Path("msg") / i.msg_file(ros_type).name
            idl = convert_msg_to_idl(i.INTERFACE_DIR, i.INTERFACE_PACKAGE, msg, idl_dir)
            tuples.append(f"{idl_dir.parent}:msg/{idl.name}")
    args = {
        "package_name": i.INTERFACE_PACKAGE,
        "output_dir": str(tmp_path / "out"),
        "idl_tuples": tuples,
        "include_paths": [f"{p}:{SHARE / p}" for p in ("std_msgs", "builtin_interfaces")],
    }
    (tmp_path / "args.json").write_text(json.dumps(args))
    rosidl = {}
    for path in generate_type_hash(str(tmp_path / "args.json")):
        for entry in json.loads(Path(path).read_text())["type_hashes"]:
            rosidl[entry["type_name"]] = entry["hash_string"]
    assert set(i.PROJECT_TYPES) <= rosidl.keys()
    for ros_type in i.PROJECT_TYPES:
        assert i.type_hash(ros_type) == rosidl[ros_type], ros_type


def test_the_colcon_package_lists_every_msg_file():
    cmake = (i.INTERFACE_DIR / "CMakeLists.txt").read_text()
    listed = set(re.findall(r'"msg/(\w+)\.msg"', cmake))
    on_disk = {p.stem for p in (i.INTERFACE_DIR / "msg").glob("*.msg")}
    assert listed == on_disk == {t.rsplit("/", 1)[1] for t in i.PROJECT_TYPES}
    assert f"<name>{i.INTERFACE_PACKAGE}</name>" in (i.INTERFACE_DIR / "package.xml").read_text()


def test_schema_text_carries_dependencies_and_constants():
    text = i.schema_text(i.STATUS)
    assert text.startswith("uint8 STARTING=0\n")
    assert "MSG: std_msgs/Header" in text and "MSG: builtin_interfaces/Time" in text
