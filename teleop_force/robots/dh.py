"""Standard Denavit-Hartenberg tables as pinocchio models.

Row ``i`` (1-based) of a standard DH table gives the transform from frame ``i-1`` to frame
``i``::

    A_i(q_i) = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)

with ``theta_i = q_i + theta_offset_i`` for a revolute joint and ``d_i = q_i + d_offset_i``
for a prismatic one. Since ``Rz`` and ``Tz`` commute, ``A_i(q) = J(q) X_i`` with the joint
motion ``J(q)`` (``Rz(q)`` or ``Tz(q)``) first and the fixed part
``X_i = Rz(theta_offset_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` after it. In pinocchio, joint ``i`` is
therefore an ``RZ`` (or ``PZ``) joint placed at ``X_{i-1}`` in its parent (``X_0`` is the base
placement), and link ``i``'s inertia, given in DH frame ``i``, hangs from it at ``X_i``. Frame
``dh_i`` marks DH frame ``i``; the tip frame sits at a fixed offset in the last DH frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from teleop_force.errors import ModelError

JOINT_TYPES = ("revolute", "prismatic")


def _rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = translation
    return out


@dataclass(frozen=True)
class DHLink:
    """Nominal inertia of one link, expressed in its DH frame.

    Attributes:
        mass_kg: Mass (>= 0; 0 for a massless link).
        com_m: Centre of mass in the link's DH frame.
        inertia_kgm2: Rotational inertia about the centre of mass (3 x 3, symmetric).

    """

    mass_kg: float = 0.0
    com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia_kgm2: tuple[tuple[float, float, float], ...] = (
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
        (0.0, 0.0, 0.0),
    )

    def __post_init__(self) -> None:
        if not np.isfinite(self.mass_kg) or self.mass_kg < 0:
            raise ModelError(f"link mass_kg must be finite and >= 0, got {self.mass_kg}")
        com = np.asarray(self.com_m, dtype=float)
        if com.shape != (3,) or not np.all(np.isfinite(com)):
            raise ModelError(f"link com_m must be 3 finite numbers, got {self.com_m}")
        inertia = np.asarray(self.inertia_kgm2, dtype=float)
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
            raise ModelError("link inertia_kgm2 must be a finite 3 x 3 matrix")
        if not np.allclose(inertia, inertia.T, atol=1e-12):
            raise ModelError("link inertia_kgm2 must be symmetric")
        object.__setattr__(self, "com_m", tuple(float(x) for x in com))
        object.__setattr__(self, "inertia_kgm2", tuple(tuple(float(x) for x in r) for r in inertia))

    def to_pinocchio(self) -> pin.Inertia:
        """Return the link's spatial inertia about its DH frame origin."""
        return pin.Inertia(
            float(self.mass_kg), np.asarray(self.com_m), np.asarray(self.inertia_kgm2)
        )


@dataclass(frozen=True)
class DHRow:
    """One row of a standard DH table.

    Attributes:
        alpha_rad: Twist about the new x axis.
        a_m: Length along the new x axis.
        d_m: Offset along the previous z axis (the joint variable adds to it when prismatic).
        theta_offset_rad: Angle about the previous z axis (the joint variable adds to it
            when revolute).
        joint_type: ``revolute`` or ``prismatic``.
        link: Nominal inertia of the link this joint moves.

    """

    alpha_rad: float
    a_m: float
    d_m: float
    theta_offset_rad: float = 0.0
    joint_type: str = "revolute"
    link: DHLink = field(default_factory=DHLink)

    def __post_init__(self) -> None:
        values = (self.alpha_rad, self.a_m, self.d_m, self.theta_offset_rad)
        if not all(np.isfinite(v) for v in values):
            raise ModelError(f"DH row values must be finite, got {values}")
        if self.joint_type not in JOINT_TYPES:
            raise ModelError(
                f"DH joint type must be one of {', '.join(JOINT_TYPES)}, got {self.joint_type!r}"
            )

    def fixed_transform(self) -> np.ndarray:
        """``X = Rz(theta_offset) Tz(d) Tx(a) Rx(alpha)``: the row at joint value 0 (4 x 4)."""
        rz = _rot_z(self.theta_offset_rad)
        translation = np.array([0.0, 0.0, self.d_m]) + rz @ np.array([self.a_m, 0.0, 0.0])
        return _homogeneous(rz @ _rot_x(self.alpha_rad), translation)

    def transform(self, q: float) -> np.ndarray:
        """``A(q) = Rz(theta) Tz(d) Tx(a) Rx(alpha)`` with the joint value added (4 x 4)."""
        theta = self.theta_offset_rad + (q if self.joint_type == "revolute" else 0.0)
        d = self.d_m + (q if self.joint_type == "prismatic" else 0.0)
        return (
            _homogeneous(_rot_z(theta), np.zeros(3))
            @ _homogeneous(np.eye(3), np.array([0.0, 0.0, d]))
            @ _homogeneous(np.eye(3), np.array([self.a_m, 0.0, 0.0]))
            @ _homogeneous(_rot_x(self.alpha_rad), np.zeros(3))
        )


def dh_forward_kinematics(
    rows: Sequence[DHRow], q: np.ndarray, base: np.ndarray | None = None
) -> np.ndarray:
    """Pose of the last DH frame in the base frame: ``base A_1(q_1) ... A_n(q_n)`` (4 x 4)."""
    q = np.asarray(q, dtype=float).reshape(-1)
    if q.shape != (len(rows),):
        raise ModelError(f"need {len(rows)} joint values, got {q.shape}")
    pose = np.eye(4) if base is None else np.asarray(base, dtype=float)
    for row, value in zip(rows, q, strict=True):
        pose = pose @ row.transform(float(value))
    return pose


def _se3(matrix: np.ndarray) -> pin.SE3:
    return pin.SE3(matrix[:3, :3].copy(), matrix[:3, 3].copy())


def build_dh_model(
    rows: Sequence[DHRow],
    gravity_mps2: Sequence[float] = (0.0, 0.0, -9.81),
    tip_offset_m: Sequence[float] = (0.0, 0.0, 0.0),
    tip_frame: str = "tip",
    joint_names: Sequence[str] | None = None,
    base: np.ndarray | None = None,
    name: str = "dh_robot",
) -> pin.Model:
    """Build the pinocchio model of a standard DH chain (model coordinates = DH joint values).

    Args:
        rows: The DH table, one row per joint, base to tip.
        gravity_mps2: Gravity vector in the base frame.
        tip_offset_m: Tip position in the last DH frame.
        tip_frame: Name of the tip frame.
        joint_names: Pinocchio joint names (default ``joint_1``...).
        base: Pose of DH frame 0 in the base frame (4 x 4, default identity).
        name: Model name.

    """
    if not rows:
        raise ModelError("a DH table needs at least one row")
    default_names = [f"joint_{i + 1}" for i in range(len(rows))]
    names = list(joint_names) if joint_names is not None else default_names
    if len(names) != len(rows) or len(set(names)) != len(names):
        raise ModelError(f"need {len(rows)} distinct joint names, got {names}")
    gravity = np.asarray(gravity_mps2, dtype=float)
    if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
        raise ModelError(f"gravity must be 3 finite numbers, got {gravity_mps2}")
    tip = np.asarray(tip_offset_m, dtype=float)
    if tip.shape != (3,) or not np.all(np.isfinite(tip)):
        raise ModelError(f"tip offset must be 3 finite numbers, got {tip_offset_m}")
    base_pose = np.eye(4) if base is None else np.asarray(base, dtype=float)
    if base_pose.shape != (4, 4):
        raise ModelError("base pose must be 4 x 4")
    reserved = {f"dh_{i + 1}" for i in range(len(rows))}
    if tip_frame in reserved or tip_frame in names:
        raise ModelError(f"tip frame name {tip_frame!r} clashes with a joint or DH frame name")
    model = pin.Model()
    model.name = name
    model.gravity = pin.Motion(gravity, np.zeros(3))
    parent = 0
    placement = base_pose
    for i, (row, joint_name) in enumerate(zip(rows, names, strict=True)):
        joint = pin.JointModelRZ() if row.joint_type == "revolute" else pin.JointModelPZ()
        joint_id = model.addJoint(parent, joint, _se3(placement), joint_name)
        fixed = row.fixed_transform()
        model.appendBodyToJoint(joint_id, row.link.to_pinocchio(), _se3(fixed))
        model.addFrame(pin.Frame(f"dh_{i + 1}", joint_id, _se3(fixed), pin.FrameType.OP_FRAME))
        parent = joint_id
        placement = fixed
    tip_pose = placement @ _homogeneous(np.eye(3), tip)
    model.addFrame(pin.Frame(tip_frame, parent, _se3(tip_pose), pin.FrameType.OP_FRAME))
    return model
