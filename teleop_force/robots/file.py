"""Robot description files: any serial arm from a URDF or a DH table, with joint coupling.

A description file is JSON (``.json``) or TOML (``.toml``) with the same keys. Joint numbers
are 1-based, angles in rad, lengths in m; every key but ``format``, ``name`` and one of
``urdf`` / ``dh`` is optional::

    format = "teleop-force-robot"          # required, and version = 1
    version = 1
    name = "my-arm"
    joint_names = ["yaw", "pitch", "elbow"]   # for tables and reports (motor joints)
    gravity_mps2 = [0.0, 0.0, -9.81]          # in the base frame (default -9.81 z)
    tip_frame = "tip"                         # frame where contact forces act
    coupling = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]   # T: q_model = T q_motor (default I)
    rotor_inertia_kgm2 = [0.0, 0.0, 0.0]      # nominal, motor coordinates (default 0)
    friction_inputs = [[1], [2, 3], [2, 3]]   # motor velocities each joint's friction sees
    q_min_rad = [-1.0, 0.0, -0.8]             # reachable range, motor coordinates
    q_max_rad = [1.0, 1.75, 1.25]
    springs = [{ joint = 2, rest_angle_rad = 1.5708 }]   # stiffness is identified

    [urdf]                        # either this ...
    path = "arm.urdf"             # relative to the description file
    joints = ["j1", "j2", "j3"]   # model coordinates, in chain order; others are locked
    locked = { slider = 0.0 }     # values of locked joints (default 0)

    [dh]                          # ... or this: standard DH, one row per joint
    tip_offset_m = [0.0, 0.0, 0.1]   # tip in the last DH frame
    rows = [                      # one inline table per line (TOML 1.0)
      { alpha_rad = 1.5708, a_m = 0.0, d_m = 0.1, theta_offset_rad = 0.0, mass_kg = 1.0 },
      { alpha_rad = 0.0, a_m = 0.2, d_m = 0.0, type = "revolute", com_m = [-0.1, 0, 0] },
      { alpha_rad = 0, a_m = 0.2, d_m = 0, inertia_kgm2 = [[1e-3,0,0], [0,1e-3,0], [0,0,1e-3]] },
    ]

    [driver]                      # optional: the driver's JointState conventions
    name = "my-driver"            # (robots/driver_interface.py, docs/real_robot.md)
    base_frame = "base"
    rate_hz = 500.0
    publishes_velocity = false
    effort_unit = "mN m"          # or "N m"
    position_coupling = [[1, 0, 0], [0, 1, 0], [0, 1, 1]]   # default I
    positions = [{ joint = "waist", sign = -1 }, { joint = "shoulder" }, { joint = "elbow" }]
    efforts = [{ joint = "waist" }, { joint = "shoulder" }, { joint = "elbow" }]

A driver's table may also stand alone in a file with ``format = "teleop-force-driver"`` and
``version = 1`` (:func:`load_driver_interface` reads either).

Link masses, centres of mass and inertias (DH rows, or the URDF's) are nominal values only:
identification finds the base parameters. The keys' types, defaults and sizes are the schema
of :mod:`teleop_force.robots.file_schema`; what depends on the built model (joint count,
frame and joint names) is checked here. Every problem raises
:class:`~teleop_force.errors.ModelError` (or :class:`~teleop_force.errors.DataError` for an
unreadable file) naming the file and the field, never a raw pinocchio or parser exception.
"""

from __future__ import annotations

import json
import os
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pinocchio as pin

from teleop_force.errors import DataError, ModelError, ModelFileError
from teleop_force.robots.description import JointSpring, RobotDescription
from teleop_force.robots.dh import DHLink, DHRow, build_dh_model
from teleop_force.robots.driver_interface import (
    DriverFieldError,
    DriverInterface,
    EffortEntry,
    PositionEntry,
)
from teleop_force.robots.file_schema import (
    DhSection,
    DriverFile,
    DriverSection,
    Matrix3,
    RobotFile,
    Spring,
    UrdfSection,
    Vector3,
)
from teleop_force.schema import Finite, read_entry, shown

SUFFIXES = (".json", ".toml")
#: ``format`` of a stand-alone driver file (``version = 1``, one ``[driver]`` table).
DRIVER_FORMAT = "teleop-force-driver"
T = TypeVar("T")


def looks_like_robot_file(name: str) -> bool:
    """Whether a ``--robot`` value names a description file rather than a built-in robot."""
    return Path(name).suffix.lower() in SUFFIXES


class _Fields:
    """The file being read: ModelError naming the file and a field."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def error(self, field: str, problem: str) -> ModelError:
        return ModelError(f"{self.path}: field {field!r}: {problem}")

    def guard(self, field: str, build: Callable[[], T]) -> T:
        """Run ``build``; turn any ModelError or pinocchio failure into one naming ``field``."""
        try:
            return build()
        except ModelError as exc:
            raise self.error(field, str(exc)) from None
        except (RuntimeError, ValueError, TypeError, IndexError) as exc:
            raise self.error(
                field, f"pinocchio: {str(exc).strip() or type(exc).__name__}"
            ) from None


def _parse(path: Path) -> dict[str, Any]:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise DataError(
            f"cannot read robot description: {exc.strerror or exc}", path=path
        ) from None
    suffix = path.suffix.lower()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise DataError("robot description is not UTF-8 text", path=path) from None
    try:
        data = json.loads(text) if suffix == ".json" else tomllib.loads(text)
    except json.JSONDecodeError as exc:
        raise DataError(f"not valid JSON: {exc.msg}", path=path, row=exc.lineno) from None
    except tomllib.TOMLDecodeError as exc:
        raise DataError(f"not valid TOML: {exc}", path=path) from None
    except (ValueError, RecursionError) as exc:  # an int of > 4300 digits, deep nesting
        kind = "JSON" if suffix == ".json" else "TOML"
        raise DataError(f"not valid {kind}: {str(exc)[:120]}", path=path) from None
    if not isinstance(data, dict):
        raise DataError("a robot description must be a JSON object", path=path)
    return data


def load_robot_description(path: str | os.PathLike[str]) -> RobotDescription:
    """Read a robot description file (see the module docstring).

    The description's ``name`` is the file's absolute path, so a model identified with it
    (``teleop-force identify --robot arm.toml``) finds it again when evaluated.

    Raises:
        DataError: the file cannot be read or parsed.
        ModelError: a field is missing or wrong (the message names the file and the field).

    """
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise DataError(f"robot description must be {' or '.join(SUFFIXES)}", path=path)
    if not path.is_file():
        raise DataError("no such robot description file", path=path)
    data = _parse(path)
    f = _Fields(path)
    if ("urdf" in data) == ("dh" in data):
        raise f.error("urdf" if "urdf" in data else "dh", "give exactly one of 'urdf' and 'dh'")
    try:
        spec = read_entry(data, RobotFile)
    except ModelFileError as exc:
        raise f.error(exc.column or "description", exc.problem) from None
    gravity = np.array(spec.gravity_mps2)
    if spec.urdf is not None:
        model = _urdf_model(f, spec.urdf, gravity)
        if spec.tip_frame is None:
            raise f.error("tip_frame", "missing (name a frame of the URDF)")
    elif spec.dh is not None:
        model = _dh_model(f, spec.dh, gravity, spec.tip_frame or "tip")
    else:  # checked before reading: exactly one is given
        raise f.error("dh", "give exactly one of 'urdf' and 'dh'")
    tip = spec.tip_frame or "tip"
    if not model.existFrame(tip):
        names = sorted({fr.name for fr in model.frames})
        raise f.error("tip_frame", f"no frame {tip!r} in the model (frames: {', '.join(names)})")
    n = model.nv
    coupling = _sized(f, spec.coupling, "coupling", np.eye(n))
    if abs(np.linalg.det(coupling)) < 1e-9:
        raise f.error("coupling", "the coupling matrix is singular")
    rotor = _sized(f, spec.rotor_inertia_kgm2, "rotor_inertia_kgm2", np.zeros(n))
    if np.any(rotor < 0):
        raise f.error("rotor_inertia_kgm2", "rotor inertias must be >= 0")
    q_min = _sized(f, spec.q_min_rad, "q_min_rad", np.full(n, -np.pi))
    q_max = _sized(f, spec.q_max_rad, "q_max_rad", np.full(n, np.pi))
    if np.any(q_min >= q_max):
        j = int(np.argmax(q_min >= q_max))
        raise f.error("q_max_rad", f"joint {j + 1}: q_max_rad must exceed q_min_rad")
    names = spec.joint_names or []
    springs = _springs(f, spec.springs, n)
    friction_inputs = _friction_inputs(f, spec.friction_inputs, n)
    if spec.joint_names is not None and len(names) != n:
        raise f.error("joint_names", f"expected {n} names, got {len(names)}")
    return f.guard(
        "description",
        lambda: RobotDescription(
            name=str(path.resolve()),
            model=model,
            n_joints=n,
            coupling=coupling,
            tip_frame=tip,
            rotor_inertia_kgm2=rotor,
            springs=springs,
            friction_inputs=friction_inputs,
            q_min_rad=q_min,
            q_max_rad=q_max,
            joint_names=tuple(names),
        ),
    )


def load_driver_interface(path: str | os.PathLike[str]) -> DriverInterface:
    """Read the ``[driver]`` table of a robot description or a stand-alone driver file.

    Raises:
        DataError: the file cannot be read or parsed.
        ModelError: the table is missing or a field is wrong (the message names the file
            and the field, ``driver.positions[0].sign``).

    """
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise DataError(f"driver description must be {' or '.join(SUFFIXES)}", path=path)
    if not path.is_file():
        raise DataError("no such driver description file", path=path)
    data = _parse(path)
    f = _Fields(path)
    if data.get("format") == DRIVER_FORMAT:
        return driver_interface_from_document(data, path)
    if data.get("format") != "teleop-force-robot":
        raise f.error("format", "expected 'teleop-force-driver' or 'teleop-force-robot'")
    if "driver" not in data:
        raise f.error("driver", "missing: the robot description has no [driver] table")
    try:
        section = read_entry(data["driver"], DriverSection)
    except ModelFileError as exc:
        column = f"driver.{exc.column}" if exc.column else "driver"
        raise f.error(column, exc.problem) from None
    return driver_interface_from_section(f, section)


def driver_interface_from_document(data: object, source: str | os.PathLike[str]) -> DriverInterface:
    """Build the interface of a parsed stand-alone driver file (``teleop-force-driver``).

    ``source`` names where ``data`` came from in errors (a file, a recording's metadata).

    Raises:
        ModelError: a field is wrong (named, ``driver.positions[0].sign``).

    """
    f = _Fields(Path(source))
    try:
        section = read_entry(data, DriverFile).driver
    except ModelFileError as exc:
        raise f.error(exc.column or "driver", exc.problem) from None
    return driver_interface_from_section(f, section)


def driver_document(interface: DriverInterface) -> dict[str, Any]:
    """Return ``interface`` as a stand-alone driver file's content (JSON-able).

    :func:`driver_interface_from_document` reads it back to an equal interface.
    """
    return {
        "format": DRIVER_FORMAT,
        "version": 1,
        "driver": {
            "name": interface.name,
            "base_frame": interface.base_frame,
            "rate_hz": float(interface.rate_hz),
            "publishes_velocity": bool(interface.publishes_velocity),
            "effort_unit": interface.effort_unit,
            "positions": [
                {"joint": p.joint, "sign": p.sign, "offset_rad": p.offset_rad, "scale": p.scale}
                for p in interface.positions
            ],
            "efforts": [{"joint": e.joint, "sign": e.sign} for e in interface.efforts],
            "position_coupling": interface.coupling_p.tolist(),
            "effort_coupling": interface.coupling_e.tolist(),
            "base_rotation": interface.rotation.tolist(),
        },
    }


def driver_interface_from_section(f: _Fields, section: DriverSection) -> DriverInterface:
    """Build the :class:`DriverInterface` of a read ``[driver]`` table (errors name it)."""
    try:
        return DriverInterface(
            name=section.name,
            base_frame=section.base_frame,
            rate_hz=section.rate_hz,
            publishes_velocity=section.publishes_velocity,
            positions=tuple(
                PositionEntry(p.joint, p.sign, p.offset_rad, p.scale) for p in section.positions
            ),
            efforts=tuple(EffortEntry(e.joint, e.sign) for e in section.efforts),
            effort_unit=section.effort_unit,
            position_coupling=_ragged(f, section.position_coupling, "driver.position_coupling"),
            effort_coupling=_ragged(f, section.effort_coupling, "driver.effort_coupling"),
            base_rotation=_ragged(f, section.base_rotation, "driver.base_rotation"),
        )
    except DriverFieldError as exc:
        raise f.error(f"driver.{exc.field}", exc.problem) from None


def _ragged(f: _Fields, rows: list[list[float]] | None, field: str) -> np.ndarray | None:
    if rows is None:
        return None
    if len({len(r) for r in rows}) > 1 or not rows:
        raise f.error(field, f"expected rows of equal length, got {shown(rows)}")
    return np.array(rows, dtype=float)


def _sized(f: _Fields, values: list[Any] | None, field: str, default: np.ndarray) -> np.ndarray:
    """``values`` as an array shaped like ``default`` (given when None); ModelError if not."""
    if values is None:
        return default
    try:
        out = np.array(values, dtype=float)
    except ValueError:  # ragged rows
        out = np.zeros(0)
    if out.shape != default.shape:
        rows, *cols = default.shape
        wanted = f"{rows} rows of {cols[0]} numbers" if cols else f"{rows} numbers"
        raise f.error(field, f"expected {wanted}, got {shown(values)}")
    return out


def _joint_index(f: _Fields, value: int, field: str, n: int) -> int:
    if not 1 <= value <= n:
        raise f.error(field, f"expected a joint number 1..{n}, got {shown(value)}")
    return value - 1


def _springs(f: _Fields, springs: list[Spring], n: int) -> tuple[JointSpring, ...]:
    return tuple(
        JointSpring(_joint_index(f, s.joint, f"springs[{i}].joint", n), s.rest_angle_rad)
        for i, s in enumerate(springs)
    )


def _friction_inputs(
    f: _Fields, value: list[list[int]] | None, n: int
) -> tuple[tuple[int, ...], ...]:
    if value is None:
        return tuple((j,) for j in range(n))
    if len(value) != n:
        raise f.error("friction_inputs", f"expected {n} lists of joint numbers, got {len(value)}")
    out = []
    for j, entry in enumerate(value):
        field = f"friction_inputs[{j}]"
        joints = tuple(_joint_index(f, v, field, n) for v in entry)
        if j not in joints:
            raise f.error(field, f"joint {j + 1}'s friction must depend on its own velocity")
        out.append(joints)
    return tuple(out)


def _link_builder(mass: float, com: Vector3, inertia: Matrix3) -> Callable[[], DHLink]:
    return lambda: DHLink(mass, com, inertia)


def _dh_model(f: _Fields, dh: DhSection, gravity: np.ndarray, tip: str) -> pin.Model:
    rows = []
    for i, row in enumerate(dh.rows):
        link = f.guard(f"dh.rows[{i}]", _link_builder(row.mass_kg, row.com_m, row.inertia_kgm2))
        rows.append(DHRow(row.alpha_rad, row.a_m, row.d_m, row.theta_offset_rad, row.type, link))
    return f.guard("dh", lambda: build_dh_model(rows, tuple(gravity), dh.tip_offset_m, tip))


def _build_urdf(path: Path) -> pin.Model:
    """Parse a URDF with pinocchio, capturing what urdfdom prints on stderr into the error."""
    with tempfile.TemporaryFile(mode="w+b") as captured:
        saved = os.dup(2)
        try:
            os.dup2(captured.fileno(), 2)
            try:
                return pin.buildModelFromUrdf(str(path))
            finally:
                os.dup2(saved, 2)
        except (RuntimeError, ValueError) as exc:
            captured.seek(0)
            detail = " ".join(captured.read().decode("utf-8", "replace").split())
            raise ModelError(f"{str(exc).strip()} {detail}".strip()) from None
        finally:
            os.close(saved)


def _urdf_model(f: _Fields, urdf: UrdfSection, gravity: np.ndarray) -> pin.Model:
    urdf_path = Path(urdf.path)
    if not urdf_path.is_absolute():
        urdf_path = f.path.parent / urdf_path
    if not urdf_path.is_file():
        raise f.error("urdf.path", f"no such file {urdf_path}")
    full = f.guard("urdf.path", lambda: _build_urdf(urdf_path))
    names = list(full.names)[1:]
    wanted = names if urdf.joints is None else urdf.joints
    for i, name in enumerate(wanted):
        if name not in names:
            raise f.error(
                f"urdf.joints[{i}]",
                f"no joint {name!r} in {urdf_path.name} (joints: {', '.join(names)})",
            )
    order = [names.index(w) for w in wanted]
    if order != sorted(order) or len(set(order)) != len(order):
        raise f.error(
            "urdf.joints",
            f"list each joint once, in chain order: {', '.join(n for n in names if n in wanted)}",
        )
    q_ref = pin.neutral(full)
    for name, value in urdf.locked.items():
        if name not in names:
            raise f.error(f"urdf.locked.{name}", f"no joint {name!r} in {urdf_path.name}")
        if name in wanted:
            raise f.error(f"urdf.locked.{name}", "a joint cannot be both used and locked")
        joint = full.joints[full.getJointId(name)]
        if joint.nq != 1:
            raise f.error(f"urdf.locked.{name}", "only 1-DOF joints can be locked at a value")
        try:
            q_ref[joint.idx_q] = read_entry(value, Finite)
        except ModelFileError as exc:
            raise f.error(f"urdf.locked.{name}", exc.problem) from None
    for i, name in enumerate(wanted):
        joint = full.joints[full.getJointId(name)]
        if joint.nq != 1 or joint.nv != 1:
            raise f.error(
                f"urdf.joints[{i}]",
                f"joint {name!r} has nq={joint.nq}, nv={joint.nv}: only revolute (with limits) "
                "or prismatic joints can be model coordinates",
            )
    lock_ids = [full.getJointId(n) for n in names if n not in wanted]
    model = f.guard("urdf.joints", lambda: pin.buildReducedModel(full, lock_ids, q_ref))
    model.gravity = pin.Motion(gravity, np.zeros(3))
    return model
