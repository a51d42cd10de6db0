"""Coulomb + viscous friction, plain (per joint) and coupled (paper experiment 2).

The formulas are the terms of :mod:`teleop_force.friction.terms` (one definition for the
batch fit and the streaming estimator): each model is a table of terms, one velocity form
(``qd_j``, ``qd_a - qd_b``) per pair of parameters ``[a_c, a_v]``.

Sticking (``sticking_rad`` > 0, the transition angle ``phi``): each term's ``sgn(w)`` is its
Dahl state ``z`` (:func:`~teleop_force.friction.terms.sticking_update_into`), a function of
the path of the term's angle: it turns to ``sgn(w)`` within a few ``phi`` of motion after a
reversal and holds at rest, so at rest under load the friction is that of the last motion (the
pre-sliding of the plant's bristles, LuGre's ``z``) instead of none (the standstill dead band,
which it replaces) or a sign picked by velocity noise. ``torque(qd)`` is then the sliding
friction; the friction along a recorded path is :meth:`TermTableFriction.path_torque`.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from msgspec import Struct

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.friction.base import FrictionModel, JointCount, JointIndex
from teleop_force.friction.terms import (
    linear_friction_basis,
    sticking_friction_torque,
    sticking_states,
    term_table_torque,
)
from teleop_force.schema import Finite, read_entry

#: Range [rad] searched for a term's sticking transition angle: from a few encoder counts
#: (3e-5 rad at the test stand's joint) to a tenth of a radian, where it is no longer sticking.
STICKING_RANGE_RAD = (1e-4, 1e-1)


class CoulombViscousEntry(Struct):
    """``cv``: Coulomb and viscous per joint; ``sticking_rad`` > 0: the Dahl transition angle."""

    n_joints: JointCount
    parameters: list[Finite]
    sticking_rad: Finite = 0.0

    def __post_init__(self) -> None:
        if self.sticking_rad < 0:
            raise ModelFileError(f"must be >= 0, got {self.sticking_rad}", column="sticking_rad")


class CoupledCoulombViscousEntry(CoulombViscousEntry, kw_only=True):
    """``coupled-cv``: the joints each joint's friction sees (0-based), inside the model."""

    friction_inputs: list[list[JointIndex]]

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.n_joints
        if len(self.friction_inputs) != n:
            raise ModelFileError(f"expected {n} lists of joint indices", column="friction_inputs")
        for j, inputs in enumerate(self.friction_inputs):
            if any(k >= n for k in inputs):
                raise ModelFileError(
                    f"joint index {max(inputs)} outside 0..{n - 1}", column=f"friction_inputs[{j}]"
                )


class TermTableFriction(FrictionModel):
    """A Coulomb-viscous term table (:meth:`term_table`), with an optional sticking state."""

    #: The Dahl transition angle [rad] of the Coulomb terms (module doc); 0: ``sgn(w)``.
    sticking_rad: float = 0.0

    @abstractmethod
    def term_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(rows, reach)`` of the terms (:mod:`~teleop_force.friction.terms`)."""

    def set_sticking(self, transition_rad: float) -> None:
        """Set the sticking transition angle [rad] (0: off); ModelError if negative or NaN."""
        value = float(transition_rad)
        if not (value >= 0.0 and math.isfinite(value)):
            raise ModelError(f"{self.kind}: sticking_rad must be finite and >= 0, got {value}")
        self.sticking_rad = value

    def sticking_states(self, q_rad: np.ndarray, starts: np.ndarray | None = None) -> np.ndarray:
        """Return the Dahl state of every term along the angles ``q_rad`` (N, n) -> (N, T).

        One stream from sample 0, another at every set ``starts`` (N, bool); ModelError
        without a transition angle.
        """
        if not self.sticking_rad > 0.0:
            raise ModelError(f"{self.kind}: no sticking state (sticking_rad is 0)")
        q = np.ascontiguousarray(np.atleast_2d(np.asarray(q_rad, dtype=float)))
        if starts is None:
            starts = np.zeros(q.shape[0], dtype=bool)
        rows, _ = self.term_table()
        return sticking_states(q, np.ascontiguousarray(rows), 1.0 / self.sticking_rad, starts)

    def path_regressor(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        """:meth:`regressor` along a path: ``sgn(w_t)`` columns are the Dahl states (if any)."""
        out = self.regressor(qd_rad_s)
        if self.sticking_rad > 0.0:
            z = self.sticking_states(q_rad)
            _, reach = self.term_table()
            for t in range(reach.shape[0]):
                out[:, :, 2 * t] = z[:, t, None] * reach[t][None, :]
        return out

    def path_torque(self, q_rad: np.ndarray, qd_rad_s: np.ndarray) -> np.ndarray:
        """Friction torque (N, n) along a path of one stream (``torque`` without sticking)."""
        if not self.sticking_rad > 0.0:
            return np.asarray(self.torque(qd_rad_s))
        rows, reach = self.term_table()
        qd = np.ascontiguousarray(np.atleast_2d(np.asarray(qd_rad_s, dtype=float)))
        return sticking_friction_torque(
            qd, np.ascontiguousarray(rows), np.ascontiguousarray(reach), self.parameters,
            self.sticking_states(q_rad),
        )  # fmt: skip

    def _sticking_entry(self) -> dict[str, Any]:
        """Return the model file's ``sticking_rad`` (only when set: older readers keep reading)."""
        return {"sticking_rad": self.sticking_rad} if self.sticking_rad > 0.0 else {}


class CoulombViscous(TermTableFriction):
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
            **self._sticking_entry(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoulombViscous:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        entry = read_entry(data, CoulombViscousEntry)
        model = _built(lambda: cls(entry.n_joints, np.array(entry.parameters)))
        model.set_sticking(entry.sticking_rad)
        return model


class CoupledCoulombViscous(TermTableFriction):
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
            **self._sticking_entry(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoupledCoulombViscous:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        entry = read_entry(data, CoupledCoulombViscousEntry)
        inputs = tuple(tuple(s) for s in entry.friction_inputs)
        model = _built(lambda: cls(entry.n_joints, inputs, np.array(entry.parameters)))
        model.set_sticking(entry.sticking_rad)
        return model


def _samples(qd: np.ndarray) -> np.ndarray:
    """``qd`` as a C-contiguous (N, n) float array."""
    return np.ascontiguousarray(np.atleast_2d(np.asarray(qd, dtype=float)))


def _built(build: Callable[[], FrictionModel]) -> Any:
    """``build()``, its ModelError (a count that does not match...) as ModelFileError."""
    try:
        return build()
    except ModelError as exc:
        raise ModelFileError(str(exc), column="parameters") from None
