"""Coulomb + viscous friction, plain (per joint) and coupled (paper experiment 2).

The formulas are the terms of :mod:`teleop_force.friction.terms` (one definition for the
batch fit and the streaming estimator): each model is a table of terms, one velocity form
(``qd_j``, ``qd_a - qd_b``) per pair of parameters ``[a_c, a_v]``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from msgspec import Struct

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.friction.base import FrictionModel, JointCount, JointIndex
from teleop_force.friction.terms import linear_friction_basis, term_table_torque
from teleop_force.schema import Finite, read_entry


class CoulombViscousEntry(Struct):
    """``cv``: Coulomb and viscous per joint."""

    n_joints: JointCount
    parameters: list[Finite]


class CoupledCoulombViscousEntry(CoulombViscousEntry):
    """``coupled-cv``: the joints each joint's friction sees (0-based), inside the model."""

    friction_inputs: list[list[JointIndex]]

    def __post_init__(self) -> None:
        n = self.n_joints
        if len(self.friction_inputs) != n:
            raise ModelFileError(f"expected {n} lists of joint indices", column="friction_inputs")
        for j, inputs in enumerate(self.friction_inputs):
            if any(k >= n for k in inputs):
                raise ModelFileError(
                    f"joint index {max(inputs)} outside 0..{n - 1}", column=f"friction_inputs[{j}]"
                )


class CoulombViscous(FrictionModel):
    """``tau_f,i = a_c,i sgn(qd_i) + a_v,i qd_i`` for every joint."""

    kind: ClassVar[str] = "cv"

    def parameter_counts(self) -> tuple[int, ...]:
        """Two parameters per joint."""
        return (2,) * self.n_joints

    def term_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(rows, reach)`` of the terms (:mod:`~teleop_force.friction.terms`): ``qd_j``."""
        eye = np.eye(self.n_joints)
        return eye, eye

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """``[sgn(qd_j), qd_j]``."""
        rows, _ = self.term_table()
        return linear_friction_basis(_samples(qd), rows, joint, joint + 1)

    def torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction torque [N m] at ``qd`` ((n,) -> (n,), or (N, n) -> (N, n))."""
        return term_table_torque(qd, *self.term_table(), self.parameters, self.kind)

    def parameter_names(self, joint: int) -> list[str]:
        """``a_c,j`` and ``a_v,j``, 1-based."""
        return [f"a_c,{joint + 1}", f"a_v,{joint + 1}"]

    def to_dict(self) -> dict[str, Any]:
        """Serialise."""
        return {
            "kind": self.kind,
            "n_joints": self.n_joints,
            "parameters": self.parameters.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoulombViscous:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        entry = read_entry(data, CoulombViscousEntry)
        return _built(lambda: cls(entry.n_joints, np.array(entry.parameters)))


class CoupledCoulombViscous(FrictionModel):
    """Coulomb + viscous with relative-velocity terms for coupled joints (paper experiment 2).

    Joint ``j`` whose friction depends on the velocities ``S_j`` gets, for every other joint
    ``k`` in ``S_j``, the terms ``sgn(qd_a - qd_b)`` and ``(qd_a - qd_b)`` with ``a < b`` the two
    of ``{j, k}`` in order (for the Omni, ``qd23 = qd2 - qd3`` on joints 2 and 3).
    """

    kind: ClassVar[str] = "coupled-cv"

    def __init__(
        self,
        n_joints: int,
        friction_inputs: tuple[tuple[int, ...], ...],
        parameters: np.ndarray | None = None,
    ) -> None:
        """Create the model for the given per-joint velocity sets."""
        if len(friction_inputs) != n_joints:
            raise ModelError("friction_inputs needs one entry per joint")
        self.friction_inputs = tuple(tuple(int(k) for k in s) for s in friction_inputs)
        for j, inputs in enumerate(self.friction_inputs):
            if any(not 0 <= k < n_joints for k in inputs):
                raise ModelError(f"friction_inputs[{j}]: joint index outside 0..{n_joints - 1}")
        self._pairs = tuple(
            tuple((min(j, k), max(j, k)) for k in s if k != j)
            for j, s in enumerate(self.friction_inputs)
        )
        # the terms joint by joint (own velocity, then the pairs), as the parameters
        rows, reach, self._first = [], [], [0]
        for j, pairs in enumerate(self._pairs):
            for a, b in ((j, -1), *pairs):
                row = np.zeros(n_joints)
                row[a] = 1.0
                if b >= 0:
                    row[b] = -1.0
                rows.append(row)
                reach.append(np.eye(n_joints)[j])
            self._first.append(len(rows))
        self._rows = np.array(rows)
        self._reach = np.array(reach)
        super().__init__(n_joints, parameters)

    def term_table(self) -> tuple[np.ndarray, np.ndarray]:
        """``(rows, reach)`` of the terms (:mod:`teleop_force.friction.terms`), joint by joint."""
        return self._rows, self._reach

    def parameter_counts(self) -> tuple[int, ...]:
        """Two, plus two per coupled joint."""
        return tuple(2 + 2 * len(p) for p in self._pairs)

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """``[sgn(qd_j), qd_j, sgn(qd_ab), qd_ab, ...]``."""
        return linear_friction_basis(
            _samples(qd), self._rows, self._first[joint], self._first[joint + 1]
        )

    def torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction torque [N m] at ``qd`` ((n,) -> (n,), or (N, n) -> (N, n))."""
        return term_table_torque(qd, self._rows, self._reach, self.parameters, self.kind)

    def parameter_names(self, joint: int) -> list[str]:
        """``a_c,j``, ``a_v,j``, then ``a_cr,j(ab)`` and ``a_vr,j(ab)`` per pair."""
        names = [f"a_c,{joint + 1}", f"a_v,{joint + 1}"]
        for a, b in self._pairs[joint]:
            names += [f"a_cr,{joint + 1}({a + 1}{b + 1})", f"a_vr,{joint + 1}({a + 1}{b + 1})"]
        return names

    def to_dict(self) -> dict[str, Any]:
        """Serialise."""
        return {
            "kind": self.kind,
            "n_joints": self.n_joints,
            "friction_inputs": [list(s) for s in self.friction_inputs],
            "parameters": self.parameters.tolist(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoupledCoulombViscous:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        entry = read_entry(data, CoupledCoulombViscousEntry)
        inputs = tuple(tuple(s) for s in entry.friction_inputs)
        return _built(lambda: cls(entry.n_joints, inputs, np.array(entry.parameters)))


def _samples(qd: np.ndarray) -> np.ndarray:
    """``qd`` as a C-contiguous (N, n) float array."""
    return np.ascontiguousarray(np.atleast_2d(np.asarray(qd, dtype=float)))


def _built(build: Callable[[], FrictionModel]) -> Any:
    """``build()``, its ModelError (a count that does not match...) as ModelFileError."""
    try:
        return build()
    except ModelError as exc:
        raise ModelFileError(str(exc), column="parameters") from None
