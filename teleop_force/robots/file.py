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

Link masses, centres of mass and inertias (DH rows, or the URDF's) are nominal values only:
identification finds the base parameters. Every problem raises
:class:`~teleop_force.errors.ModelError` (or :class:`~teleop_force.errors.DataError` for an
unreadable file) naming the file and the field, never a raw pinocchio or parser exception.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numpy as np
import pinocchio as pin

from teleop_force.errors import DataError, ModelError
from teleop_force.robots.description import JointSpring, RobotDescription
from teleop_force.robots.dh import JOINT_TYPES, DHLink, DHRow, build_dh_model

FILE_FORMAT = "teleop-force-robot"
FILE_VERSION = 1
SUFFIXES = (".json", ".toml")
_TOP_KEYS = {
    "format",
    "version",
    "name",
    "joint_names",
    "gravity_mps2",
    "tip_frame",
    "coupling",
    "rotor_inertia_kgm2",
    "friction_inputs",
    "q_min_rad",
    "q_max_rad",
    "springs",
    "urdf",
    "dh",
}
_DH_ROW_KEYS = {
    "alpha_rad",
    "a_m",
    "d_m",
    "theta_offset_rad",
    "type",
    "mass_kg",
    "com_m",
    "inertia_kgm2",
}
T = TypeVar("T")


def _digits(value: int) -> int:
    """Decimal digits of an int (without building its string, limited to 4300 digits)."""
    return len(str(abs(value))) if abs(value) < 10**4000 else int(abs(value).bit_length() * 0.30103)


def _shown(value: object) -> str:
    """``repr`` of a field's value, short (a huge int or long string cannot flood the message)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        return f"an integer of {_digits(value)} digits"
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def looks_like_robot_file(name: str) -> bool:
    """Whether a ``--robot`` value names a description file rather than a built-in robot."""
    return Path(name).suffix.lower() in SUFFIXES


class _Fields:
    """Typed access to a parsed file, raising ModelError that names the file and field."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def error(self, field: str, problem: str) -> ModelError:
        return ModelError(f"{self.path}: field {field!r}: {problem}")

    def number(self, value: object, field: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(field, f"expected a number, got {_shown(value)}")
        try:
            out = float(value)  # an int beyond float64 overflows here
        except OverflowError:
            # only an int overflows float()
            problem = f"must be finite, got an integer of {_digits(cast(int, value))} digits"
            raise self.error(field, problem) from None
        if not math.isfinite(out):
            raise self.error(field, f"must be finite, got {value!r}")
        return out

    def vector(self, value: object, field: str, size: int | None = None) -> np.ndarray:
        if not isinstance(value, list):
            raise self.error(field, f"expected a list of numbers, got {_shown(value)}")
        out = np.array([self.number(v, f"{field}[{i}]") for i, v in enumerate(value)], dtype=float)
        if size is not None and out.size != size:
            raise self.error(field, f"expected {size} numbers, got {out.size}")
        return out

    def matrix(self, value: object, field: str, rows: int, cols: int) -> np.ndarray:
        if not isinstance(value, list) or len(value) != rows:
            raise self.error(field, f"expected {rows} rows of {cols} numbers")
        return np.stack([self.vector(r, f"{field}[{i}]", cols) for i, r in enumerate(value)])

    def string(self, value: object, field: str) -> str:
        if not isinstance(value, str) or not value:
            raise self.error(field, f"expected a non-empty string, got {_shown(value)}")
        return value

    def table(self, value: object, field: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.error(field, f"expected a table/object, got {type(value).__name__}")
        return value

    def unknown(self, data: dict[str, Any], allowed: set[str], field: str) -> None:
        extra = sorted(set(data) - allowed)
        if extra:
            where = f"{field}.{extra[0]}" if field else extra[0]
            raise self.error(where, f"unknown key (allowed: {', '.join(sorted(allowed))})")

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
    f.unknown(data, _TOP_KEYS, "")
    if data.get("format") != FILE_FORMAT:
        raise f.error("format", f"expected {FILE_FORMAT!r}, got {_shown(data.get('format'))}")
    if data.get("version") != FILE_VERSION:
        raise f.error("version", f"expected {FILE_VERSION}, got {_shown(data.get('version'))}")
    if "name" not in data:
        raise f.error("name", "missing")
    f.string(data["name"], "name")
    gravity = f.vector(data.get("gravity_mps2", [0.0, 0.0, -9.81]), "gravity_mps2", 3)
    has_urdf, has_dh = "urdf" in data, "dh" in data
    if has_urdf == has_dh:
        raise f.error("urdf" if has_urdf else "dh", "give exactly one of 'urdf' and 'dh'")
    tip = f.string(data["tip_frame"], "tip_frame") if "tip_frame" in data else None
    if has_urdf:
        model = _urdf_model(f, f.table(data["urdf"], "urdf"), gravity)
        if tip is None:
            raise f.error("tip_frame", "missing (name a frame of the URDF)")
    else:
        model = _dh_model(f, f.table(data["dh"], "dh"), gravity, tip or "tip")
        tip = tip or "tip"
    if not model.existFrame(tip):
        names = sorted({fr.name for fr in model.frames})
        raise f.error("tip_frame", f"no frame {tip!r} in the model (frames: {', '.join(names)})")
    n = model.nv
    coupling = f.matrix(data["coupling"], "coupling", n, n) if "coupling" in data else np.eye(n)
    if abs(np.linalg.det(coupling)) < 1e-9:
        raise f.error("coupling", "the coupling matrix is singular")
    rotor = f.vector(data.get("rotor_inertia_kgm2", [0.0] * n), "rotor_inertia_kgm2", n)
    if np.any(rotor < 0):
        raise f.error("rotor_inertia_kgm2", "rotor inertias must be >= 0")
    q_min = (
        f.vector(data["q_min_rad"], "q_min_rad", n) if "q_min_rad" in data else np.full(n, -np.pi)
    )
    q_max = (
        f.vector(data["q_max_rad"], "q_max_rad", n) if "q_max_rad" in data else np.full(n, np.pi)
    )
    if np.any(q_min >= q_max):
        j = int(np.argmax(q_min >= q_max))
        raise f.error("q_max_rad", f"joint {j + 1}: q_max_rad must exceed q_min_rad")
    return f.guard(
        "description",
        lambda: RobotDescription(
            name=str(path.resolve()),
            model=model,
            n_joints=n,
            coupling=coupling,
            tip_frame=tip,
            rotor_inertia_kgm2=rotor,
            springs=_springs(f, data.get("springs", []), n),
            friction_inputs=_friction_inputs(f, data.get("friction_inputs"), n),
            q_min_rad=q_min,
            q_max_rad=q_max,
            joint_names=_joint_names(f, data.get("joint_names"), n),
        ),
    )


def _joint_index(f: _Fields, value: object, field: str, n: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= n:
        raise f.error(field, f"expected a joint number 1..{n}, got {_shown(value)}")
    return value - 1


def _springs(f: _Fields, value: object, n: int) -> tuple[JointSpring, ...]:
    if not isinstance(value, list):
        raise f.error("springs", "expected a list of {joint, rest_angle_rad}")
    out = []
    for i, item in enumerate(value):
        entry = f.table(item, f"springs[{i}]")
        f.unknown(entry, {"joint", "rest_angle_rad"}, f"springs[{i}]")
        joint = _joint_index(f, entry.get("joint"), f"springs[{i}].joint", n)
        rest = f.number(entry.get("rest_angle_rad", 0.0), f"springs[{i}].rest_angle_rad")
        out.append(JointSpring(joint=joint, rest_angle_rad=rest))
    return tuple(out)


def _friction_inputs(f: _Fields, value: object, n: int) -> tuple[tuple[int, ...], ...]:
    if value is None:
        return tuple((j,) for j in range(n))
    if not isinstance(value, list) or len(value) != n:
        raise f.error("friction_inputs", f"expected {n} lists of joint numbers")
    out = []
    for j, entry in enumerate(value):
        field = f"friction_inputs[{j}]"
        if not isinstance(entry, list) or not entry:
            raise f.error(field, "expected a non-empty list of joint numbers")
        joints = tuple(_joint_index(f, v, field, n) for v in entry)
        if j not in joints:
            raise f.error(field, f"joint {j + 1}'s friction must depend on its own velocity")
        out.append(joints)
    return tuple(out)


def _joint_names(f: _Fields, value: object, n: int) -> tuple[str, ...]:
    if value is None:
        return ()
    if not isinstance(value, list) or len(value) != n:
        raise f.error("joint_names", f"expected {n} names")
    return tuple(f.string(v, f"joint_names[{i}]") for i, v in enumerate(value))


def _link_builder(mass: float, com: np.ndarray, inertia: np.ndarray) -> Callable[[], DHLink]:
    def build() -> DHLink:
        return DHLink(
            mass,
            (float(com[0]), float(com[1]), float(com[2])),
            tuple((float(r[0]), float(r[1]), float(r[2])) for r in inertia),
        )

    return build


def _dh_model(f: _Fields, dh: dict[str, Any], gravity: np.ndarray, tip: str) -> pin.Model:
    f.unknown(dh, {"rows", "tip_offset_m", "convention"}, "dh")
    convention = dh.get("convention", "standard")
    if convention != "standard":
        raise f.error("dh.convention", f"only 'standard' DH is supported, got {_shown(convention)}")
    rows_value = dh.get("rows")
    if not isinstance(rows_value, list) or not rows_value:
        raise f.error("dh.rows", "expected a non-empty list of rows")
    rows = []
    for i, item in enumerate(rows_value):
        field = f"dh.rows[{i}]"
        row = f.table(item, field)
        f.unknown(row, _DH_ROW_KEYS, field)
        for key in ("alpha_rad", "a_m", "d_m"):
            if key not in row:
                raise f.error(f"{field}.{key}", "missing")
        joint_type = row.get("type", "revolute")
        if joint_type not in JOINT_TYPES:
            raise f.error(
                f"{field}.type",
                f"expected one of {', '.join(JOINT_TYPES)}, got {_shown(joint_type)}",
            )
        mass = f.number(row.get("mass_kg", 0.0), f"{field}.mass_kg")
        com = f.vector(row.get("com_m", [0.0, 0.0, 0.0]), f"{field}.com_m", 3)
        inertia = f.matrix(row.get("inertia_kgm2", [[0.0] * 3] * 3), f"{field}.inertia_kgm2", 3, 3)
        link = f.guard(field, _link_builder(mass, com, inertia))
        rows.append(
            DHRow(
                f.number(row["alpha_rad"], f"{field}.alpha_rad"),
                f.number(row["a_m"], f"{field}.a_m"),
                f.number(row["d_m"], f"{field}.d_m"),
                f.number(row.get("theta_offset_rad", 0.0), f"{field}.theta_offset_rad"),
                joint_type,
                link,
            )
        )
    tip_offset = f.vector(dh.get("tip_offset_m", [0.0, 0.0, 0.0]), "dh.tip_offset_m", 3)
    return f.guard("dh", lambda: build_dh_model(rows, tuple(gravity), tuple(tip_offset), tip))


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


def _urdf_model(f: _Fields, urdf: dict[str, Any], gravity: np.ndarray) -> pin.Model:
    f.unknown(urdf, {"path", "joints", "locked"}, "urdf")
    if "path" not in urdf:
        raise f.error("urdf.path", "missing")
    urdf_path = Path(f.string(urdf["path"], "urdf.path"))
    if not urdf_path.is_absolute():
        urdf_path = f.path.parent / urdf_path
    if not urdf_path.is_file():
        raise f.error("urdf.path", f"no such file {urdf_path}")
    full = f.guard("urdf.path", lambda: _build_urdf(urdf_path))
    names = list(full.names)[1:]
    wanted_value = urdf.get("joints")
    if wanted_value is None:
        wanted = names
    elif not isinstance(wanted_value, list) or not wanted_value:
        raise f.error("urdf.joints", "expected a non-empty list of joint names")
    else:
        wanted = [f.string(v, f"urdf.joints[{i}]") for i, v in enumerate(wanted_value)]
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
    locked_value = f.table(urdf.get("locked", {}), "urdf.locked")
    q_ref = pin.neutral(full)
    for name, value in locked_value.items():
        if name not in names:
            raise f.error(f"urdf.locked.{name}", f"no joint {name!r} in {urdf_path.name}")
        if name in wanted:
            raise f.error(f"urdf.locked.{name}", "a joint cannot be both used and locked")
        joint = full.joints[full.getJointId(name)]
        if joint.nq != 1:
            raise f.error(f"urdf.locked.{name}", "only 1-DOF joints can be locked at a value")
        q_ref[joint.idx_q] = f.number(value, f"urdf.locked.{name}")
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
