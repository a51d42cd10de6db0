"""Robot descriptions and rigid-body computations in motor coordinates.

A :class:`RobotDescription` is a pinocchio model in *model* coordinates plus a joint coupling
matrix ``T`` with ``q_model = T @ q_motor``. Every public quantity of :class:`Robot` (angles,
velocities, torques, matrices) is in *motor* coordinates, the ones the encoders read and the
motors drive: ``tau_motor = T.T @ tau_model`` (the virtual work of the two sides is equal).

``T`` is square for a serial chain. A closed chain (a parallelogram) is a tree with more joints
than motors: each extra joint's angle is a fixed linear combination of the motor angles, so
``T`` has one row per model joint and one column per motor (``n_model x n``, full column
rank) and the same two formulas hold, ``M_motor = T^T M T`` and so on (the closure is
satisfied by construction, the constraint forces do no work).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from teleop_force.errors import ModelError, SingularityError

#: Dynamic parameters of one link, in pinocchio's order.
LINK_PARAMETER_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


@dataclass(frozen=True)
class JointSpring:
    """A torsional spring on one motor joint: ``tau = k * (q[joint] - rest_angle_rad)``."""

    joint: int
    rest_angle_rad: float

    def __post_init__(self) -> None:
        if self.joint < 0:
            raise ModelError(f"spring joint index must be >= 0, got {self.joint}")


@dataclass(frozen=True, eq=False)
class RobotDescription:
    """Everything the project needs to know about a serial-chain robot.

    Attributes:
        name: Short name (``omni``, ``dvrk-mtm``...).
        model: Pinocchio model in model coordinates; ``None`` for a robot without rigid-body
            terms (friction and found effects only).
        n_joints: Number of actuated (motor) joints.
        coupling: ``T`` with ``q_model = T @ q_motor``: ``n x n`` for a serial chain,
            ``n_model x n`` (``n_model >= n``, full column rank) for a closed chain written as
            a tree with extra joints (``n_model = model.nv``).
        tip_frame: Name of the pinocchio frame where contact forces act.
        rotor_inertia_kgm2: Motor rotor inertias, diagonal in motor coordinates.
        springs: Torsional springs in motor coordinates (stiffness is identified).
        friction_inputs: For each joint, the motor velocities its friction depends on.
        q_min_rad, q_max_rad: Reachable joint range (motor coordinates).
        joint_names: Names used in tables and reports.

    """

    name: str
    model: pin.Model | None
    n_joints: int
    coupling: np.ndarray
    tip_frame: str | None
    rotor_inertia_kgm2: np.ndarray
    springs: tuple[JointSpring, ...] = ()
    friction_inputs: tuple[tuple[int, ...], ...] = ()
    q_min_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    q_max_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    joint_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        n = self.n_joints
        if n < 1:
            raise ModelError(f"{self.name}: a robot needs at least one joint, got {n}")
        coupling = np.asarray(self.coupling, dtype=float)
        if coupling.ndim != 2 or coupling.shape[1] != n or coupling.shape[0] < n:
            raise ModelError(f"{self.name}: coupling must be {n}x{n}, got {coupling.shape}")
        if not np.all(np.isfinite(coupling)):
            raise ModelError(f"{self.name}: coupling matrix is not finite")
        if coupling.shape[0] == n:
            if abs(np.linalg.det(coupling)) < 1e-9:
                raise ModelError(f"{self.name}: coupling matrix is singular")
        elif np.linalg.svd(coupling, compute_uv=False)[-1] < 1e-9:
            raise ModelError(f"{self.name}: coupling matrix does not have full column rank")
        object.__setattr__(self, "coupling", coupling)
        if self.model is not None and self.model.nv != coupling.shape[0]:
            if coupling.shape[0] == n:
                raise ModelError(
                    f"{self.name}: pinocchio model has nv={self.model.nv}, expected {n}"
                )
            raise ModelError(
                f"{self.name}: pinocchio model has nv={self.model.nv}, the coupling has "
                f"{coupling.shape[0]} rows (one per model joint)"
            )
        if self.model is None and coupling.shape[0] != n:
            raise ModelError(f"{self.name}: coupling must be {n}x{n}, got {coupling.shape}")
        if (
            self.model is not None
            and self.tip_frame is not None
            and not self.model.existFrame(self.tip_frame)
        ):
            raise ModelError(f"{self.name}: no frame named {self.tip_frame!r} in the model")
        rotor = np.asarray(self.rotor_inertia_kgm2, dtype=float).reshape(-1)
        if rotor.shape != (n,):
            raise ModelError(f"{self.name}: rotor_inertia_kgm2 needs {n} values")
        object.__setattr__(self, "rotor_inertia_kgm2", rotor)
        for spring in self.springs:
            if spring.joint >= n:
                raise ModelError(f"{self.name}: spring on joint {spring.joint + 1} of {n}")
        inputs = self.friction_inputs or tuple((i,) for i in range(n))
        if len(inputs) != n:
            raise ModelError(f"{self.name}: friction_inputs needs one entry per joint")
        for entry in inputs:
            if not entry or any(not 0 <= j < n for j in entry):
                raise ModelError(f"{self.name}: bad friction input set {entry}")
        object.__setattr__(self, "friction_inputs", tuple(tuple(e) for e in inputs))
        for attr, default in (("q_min_rad", -np.pi), ("q_max_rad", np.pi)):
            value = np.asarray(getattr(self, attr), dtype=float).reshape(-1)
            if value.size == 0:
                value = np.full(n, default)
            if value.shape != (n,):
                raise ModelError(f"{self.name}: {attr} needs {n} values")
            object.__setattr__(self, attr, value)
        names = self.joint_names or tuple(f"joint {i + 1}" for i in range(n))
        if len(names) != n:
            raise ModelError(f"{self.name}: joint_names needs {n} names")
        object.__setattr__(self, "joint_names", tuple(names))

    @property
    def has_rigid_body(self) -> bool:
        """Whether the description carries rigid-body (pinocchio) terms."""
        return self.model is not None

    @property
    def n_model(self) -> int:
        """Number of model joints (``coupling`` rows): ``n_joints`` for a serial chain."""
        return int(self.coupling.shape[0])

    @property
    def is_serial(self) -> bool:
        """Whether the coupling is square (a serial chain, no extra closed-chain joints)."""
        return self.n_model == self.n_joints

    @property
    def n_links(self) -> int:
        """Number of moving bodies with dynamic parameters (0 without a model)."""
        return 0 if self.model is None else self.model.njoints - 1

    def link_parameters(self) -> np.ndarray:
        """Stack the model's link dynamic parameters (10 per link, pinocchio order)."""
        if self.model is None:
            return np.zeros(0)
        return np.concatenate(
            [self.model.inertias[j].toDynamicParameters() for j in range(1, self.model.njoints)]
        )

    def with_link_parameters(self, link_parameters: np.ndarray) -> RobotDescription:
        """Return a copy whose links carry ``link_parameters`` (need not be physical)."""
        if self.model is None:
            raise ModelError(f"{self.name}: no rigid-body model to set parameters on")
        values = np.asarray(link_parameters, dtype=float)
        if values.shape != (10 * self.n_links,):
            raise ModelError(f"expected {10 * self.n_links} link parameters, got {values.shape}")
        model = self.model.copy()
        for j in range(1, model.njoints):
            model.inertias[j] = pin.Inertia.FromDynamicParameters(values[10 * (j - 1) : 10 * j])
        return _replace(self, model=model)

    def with_rotor_inertia(
        self, rotor_inertia_kgm2: Sequence[float] | np.ndarray
    ) -> RobotDescription:
        """Return a copy with other rotor inertias."""
        return _replace(self, rotor_inertia_kgm2=np.asarray(rotor_inertia_kgm2, dtype=float))


def _replace(description: RobotDescription, **changes: object) -> RobotDescription:
    fields = {name: getattr(description, name) for name in RobotDescription.__dataclass_fields__}
    fields.update(changes)
    return RobotDescription(**fields)


class Robot:
    """Rigid-body computations of a :class:`RobotDescription`, in motor coordinates.

    Holds pinocchio scratch data, so one instance per thread.
    """

    def __init__(self, description: RobotDescription) -> None:
        """Bind the description and allocate pinocchio data."""
        if description.model is None:
            raise ModelError(f"{description.name}: no rigid-body model")
        self.description = description
        self.model = description.model
        self.data = self.model.createData()
        self.coupling = description.coupling
        self.n = description.n_joints
        self._tip_id = (
            self.model.getFrameId(description.tip_frame) if description.tip_frame else None
        )
        self._rotor = description.rotor_inertia_kgm2
        self._spring_rows = np.array([s.joint for s in description.springs], dtype=int)
        self._spring_rest = np.array([s.rest_angle_rad for s in description.springs])

    def to_model(self, q_motor: np.ndarray) -> np.ndarray:
        """Map motor coordinates to model coordinates (``T @ q``)."""
        return self.coupling @ q_motor

    def tip_position_in_base(self, q: np.ndarray) -> np.ndarray:
        """Tip position in the base frame [m]."""
        pin.framesForwardKinematics(self.model, self.data, self.to_model(q))
        return self.data.oMf[self._require_tip()].translation.copy()

    def tip_jacobian_in_base(self, q: np.ndarray) -> np.ndarray:
        """Return the tip's translational Jacobian in the base frame, d p / d q_motor (3 x n)."""
        qm = self.to_model(q)
        tip = self._require_tip()
        j6 = pin.computeFrameJacobian(self.model, self.data, qm, tip, pin.LOCAL_WORLD_ALIGNED)
        return j6[:3, :] @ self.coupling

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia matrix in motor coordinates, rotor inertias included."""
        m = pin.crba(self.model, self.data, self.to_model(q))
        m = np.triu(m) + np.triu(m, 1).T
        return self.coupling.T @ m @ self.coupling + np.diag(self._rotor)

    def momentum(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Generalized momentum ``M(q) qd`` [N m s]."""
        return self.mass_matrix(q) @ qd

    def coriolis_matrix(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Coriolis matrix ``C`` (Christoffel form, ``Mdot = C + C^T``) in motor coordinates."""
        c = pin.computeCoriolisMatrix(self.model, self.data, self.to_model(q), self.to_model(qd))
        return self.coupling.T @ c @ self.coupling

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Gravity torque ``N(q)`` [N m]."""
        return self.coupling.T @ pin.computeGeneralizedGravity(
            self.model, self.data, self.to_model(q)
        )

    def spring_torque(self, q: np.ndarray, stiffness_nm_per_rad: np.ndarray) -> np.ndarray:
        """Torque of the description's springs for the given stiffnesses."""
        tau = np.zeros(self.n)
        if self._spring_rows.size:
            np.add.at(
                tau,
                self._spring_rows,
                stiffness_nm_per_rad * (q[self._spring_rows] - self._spring_rest),
            )
        return tau

    def inverse_dynamics(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Rigid-body torque ``M qdd + C qd + N`` (no spring, no friction) [N m]."""
        tau = pin.rnea(
            self.model, self.data, self.to_model(q), self.to_model(qd), self.to_model(qdd)
        )
        return self.coupling.T @ tau + self._rotor * qdd

    def bias_torque(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``C qd + N`` [N m]."""
        tau = pin.nonLinearEffects(self.model, self.data, self.to_model(q), self.to_model(qd))
        return self.coupling.T @ tau

    def coriolis_transpose_gravity(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """``-C(q, qd)^T qd + N(q)``: the acceleration-free part of the momentum form [N m]."""
        return -self.coriolis_matrix(q, qd).T @ qd + self.gravity_torque(q)

    def tip_force_from_joint_torque(
        self, q: np.ndarray, tau_external: np.ndarray, sigma_min: float = 1e-3
    ) -> np.ndarray:
        """Tip force in the base frame from ``tau_external = J^T F`` (least squares for n != 3).

        Raises:
            SingularityError: when the Jacobian's smallest singular value is below
                ``sigma_min`` [m/rad].

        """
        jac = self.tip_jacobian_in_base(q)
        u, s, vt = np.linalg.svd(jac.T, full_matrices=False)
        if s[-1] < sigma_min:
            raise SingularityError(float(s[-1]), sigma_min)
        return vt.T @ ((u.T @ tau_external) / s)

    def _require_tip(self) -> int:
        if self._tip_id is None:
            raise ModelError(f"{self.description.name}: no tip frame")
        return self._tip_id
