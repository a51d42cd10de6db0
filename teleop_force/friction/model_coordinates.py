"""Coulomb + viscous friction in model coordinates, reaching the motors through the coupling.

A coupled robot's bearings and cables do not turn with its motors: the dVRK MTM's elbow
bearing turns with ``qd3 - qd2`` (the parallelogram), its joint-4 cable with
``0.6697 (qd2 - qd3) + qd4``. Their friction is a function of a *model* joint's velocity
``w = T qd`` (``T`` the description's coupling, ``q_model = T q_motor``) and reaches the
motors as every model torque does, through ``T^T``::

    tau_f = T^T f(T qd),    f_k(w_k) = a_c,k sgn(w_k) + a_v,k w_k

Each model joint's friction is set by all the motors that move it, and a motor feels the
friction of every model joint it moves, with the coupling's fixed ratios: a per-motor model,
even one on pairwise velocity differences (:class:`CoupledCoulombViscous`), cannot express
that (``docs/robots.md``).

Model joints whose coupling rows are parallel (the same velocity up to a factor, such as the
MTM's elbow ``qd3 - qd2`` and its parallelogram's top link ``qd2 - qd3``) give the same
regressor columns up to a factor, so they share one friction law: the model's *axes* are the
coupling's distinct row directions, each kept with its first row's scale (its friction acts
on that row's velocity). With an identity coupling this is :class:`CoulombViscous`.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

import numpy as np
from msgspec import Meta, Struct

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.friction.base import MAX_JOINTS, FrictionModel, JointCount
from teleop_force.friction.terms import linear_friction_basis, term_table_torque
from teleop_force.schema import Finite, read_entry

#: Most model joints (coupling rows) a model file may declare.
MAX_MODEL_JOINTS = 4 * MAX_JOINTS
#: Rows with ``1 - |cos(angle)|`` below this (angle below ~4e-5 rad) are one axis.
_PARALLEL_TOLERANCE = 1e-9
#: Parameters per axis: Coulomb and viscous.
_PER_AXIS = 2


class ModelCoordinateEntry(Struct):
    """``model-cv``: an ``n_model x n_joints`` coupling and two parameters per direction."""

    n_joints: JointCount
    coupling: Annotated[list[list[Finite]], Meta(min_length=1, max_length=MAX_MODEL_JOINTS)]
    parameters: list[Finite]

    def __post_init__(self) -> None:
        if any(len(row) != self.n_joints for row in self.coupling):
            lengths = sorted({len(row) for row in self.coupling})
            raise ModelFileError(
                f"expected rows of {self.n_joints} numbers, got rows of {lengths}",
                column="coupling",
            )


def distinct_axes(coupling: np.ndarray) -> tuple[int, ...]:
    """Return the coupling rows that start a new direction, in row order.

    A row starts one when it is nonzero and not parallel to an earlier row.
    """
    kept: list[int] = []
    units: list[np.ndarray] = []
    for i, row in enumerate(np.asarray(coupling, dtype=float)):
        norm = float(np.linalg.norm(row))
        if norm == 0.0:
            continue
        unit = row / norm
        if any(1.0 - abs(float(unit @ u)) < _PARALLEL_TOLERANCE for u in units):
            continue
        kept.append(i)
        units.append(unit)
    return tuple(kept)


class ModelCoordinateFriction(FrictionModel):
    """``tau_f = T^T f(T qd)`` with Coulomb + viscous ``f`` on each distinct model axis."""

    kind: ClassVar[str] = "model-cv"
    block_diagonal: ClassVar[bool] = False

    def __init__(self, coupling: np.ndarray, parameters: np.ndarray | None = None) -> None:
        """Create the model for the coupling ``T`` (``n_model x n``, full column rank)."""
        coupling = np.array(coupling, dtype=float)
        if coupling.ndim != 2 or coupling.shape[0] < 1 or coupling.shape[1] < 1:
            raise ModelError(f"{self.kind}: coupling must be a matrix, got shape {coupling.shape}")
        if not np.all(np.isfinite(coupling)):
            raise ModelError(f"{self.kind}: coupling matrix is not finite")
        n_model, n = coupling.shape
        if n_model < n or np.linalg.svd(coupling, compute_uv=False)[-1] < 1e-9:
            raise ModelError(
                f"{self.kind}: coupling {coupling.shape} does not have full column rank"
            )
        coupling.setflags(write=False)
        self.coupling = coupling
        #: Coupling rows whose velocities carry a friction law, one per distinct direction.
        self.axis_rows = distinct_axes(coupling)
        #: Those rows (``n_axes x n``): axis ``a``'s velocity is ``axes[a] @ qd``.
        self.axes = np.ascontiguousarray(coupling[list(self.axis_rows)])
        self.axes.setflags(write=False)
        super().__init__(n, parameters)

    @property
    def n_axes(self) -> int:
        """Number of friction laws (distinct coupling directions)."""
        return len(self.axis_rows)

    def parameter_counts(self) -> tuple[int, ...]:
        """Two parameters (Coulomb, viscous) per axis, not per motor joint."""
        return (_PER_AXIS,) * self.n_axes

    def axis_velocities(self, qd: np.ndarray) -> np.ndarray:
        """Velocities of the axes, ``(N, n) -> (N, n_axes)``."""
        return np.asarray(qd, dtype=float) @ self.axes.T

    def regressor(self, qd: np.ndarray) -> np.ndarray:
        """``(N, n, 2 n_axes)``: joint ``j``'s row holds ``T[a, j] [sgn(w_a), w_a]`` per axis.

        The columns ``[sgn(w_a), w_a]`` are the terms' (:func:`linear_friction_basis`).
        """
        qd = np.ascontiguousarray(np.atleast_2d(np.asarray(qd, dtype=float)))
        if qd.ndim != 2 or qd.shape[1] != self.n_joints:
            raise ModelError(
                f"{self.kind}: expected {self.n_joints} velocities, got {qd.shape[-1]}"
            )
        basis = linear_friction_basis(qd, self.axes, 0, self.n_axes)
        per_axis = basis.reshape(qd.shape[0], self.n_axes, _PER_AXIS)
        out = np.einsum("aj,kas->kjas", self.axes, per_axis)
        return out.reshape(qd.shape[0], self.n_joints, _PER_AXIS * self.n_axes)

    def torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction torque ``T^T f(T qd)`` [N m] ((n,) -> (n,), or (N, n) -> (N, n))."""
        return term_table_torque(qd, self.axes, self.axes, self.parameters, self.kind)

    def term_table(self) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, reach)`` of the terms (:mod:`teleop_force.friction.terms`): one per axis.

        Axis ``a``'s velocity is ``axes[a] @ qd`` and its torque reaches the motors as
        ``axes[a]`` (``T^T``).
        """
        return self.axes, self.axes

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """Not available: a parameter acts on several joints (use :meth:`regressor`)."""
        raise ModelError(self._not_per_joint())

    def joint_slice(self, joint: int) -> slice:
        """Not available: parameters belong to axes, not joints (use :meth:`axis_slice`)."""
        raise ModelError(self._not_per_joint())

    def axis_slice(self, axis: int) -> slice:
        """Slice of ``parameters`` of axis ``axis`` (Coulomb, viscous)."""
        if not 0 <= axis < self.n_axes:
            raise ModelError(f"{self.kind}: axis {axis} outside 0..{self.n_axes - 1}")
        return slice(_PER_AXIS * axis, _PER_AXIS * (axis + 1))

    def axis_label(self, axis: int) -> str:
        """``m<k>``: the 1-based model joint (coupling row) whose velocity the axis is."""
        return f"m{self.axis_rows[axis] + 1}"

    def parameter_names(self, joint: int) -> list[str]:
        """Names of the parameters acting on motor joint ``joint`` (its axes')."""
        if not 0 <= joint < self.n_joints:
            raise ModelError(f"{self.kind}: joint {joint} outside 0..{self.n_joints - 1}")
        names = self.all_parameter_names()
        return [
            name
            for a in range(self.n_axes)
            if self.axes[a, joint] != 0.0
            for name in names[self.axis_slice(a)]
        ]

    def all_parameter_names(self) -> list[str]:
        """``a_c,m<k>`` and ``a_v,m<k>`` per axis, ``k`` the model joint (coupling row)."""
        return [
            name
            for a in range(self.n_axes)
            for name in (f"a_c,{self.axis_label(a)}", f"a_v,{self.axis_label(a)}")
        ]

    def to_dict(self) -> dict[str, Any]:
        """Serialise (the coupling included, so the file needs no robot description)."""
        return {
            "kind": self.kind,
            "n_joints": self.n_joints,
            "coupling": self.coupling.tolist(),
            "parameters": self.parameters.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelCoordinateFriction:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field.

        The coupling must be an ``n_model x n_joints`` matrix of finite numbers with full
        column rank, the parameters two finite numbers per distinct row direction.
        """
        entry = read_entry(data, ModelCoordinateEntry)
        try:
            model = cls(np.array(entry.coupling))
        except (ValueError, ArithmeticError) as exc:  # ModelError: rank, parallel rows...
            raise ModelFileError(
                f"bad model-coordinate friction: {exc}", column="coupling"
            ) from None
        if len(entry.parameters) != model.parameters.size:
            raise ModelFileError(
                f"expected {model.parameters.size} numbers (2 per distinct coupling"
                f" direction), got {len(entry.parameters)}",
                column="parameters",
            )
        model.parameters = np.array(entry.parameters)
        return model

    def _not_per_joint(self) -> str:
        return (
            f"{self.kind}: friction acts through the coupling, a parameter on several joints;"
            " it has no per-joint basis (use regressor() / torque())"
        )
