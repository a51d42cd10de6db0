"""Coulomb + viscous friction, plain (per joint) and coupled (paper experiment 2)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.friction.base import MAX_JOINTS, FrictionModel, file_floats, file_int


class CoulombViscous(FrictionModel):
    """``tau_f,i = a_c,i sgn(qd_i) + a_v,i qd_i`` for every joint."""

    kind: ClassVar[str] = "cv"

    def parameter_counts(self) -> tuple[int, ...]:
        """Two parameters per joint."""
        return (2,) * self.n_joints

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """``[sgn(qd_j), qd_j]``."""
        v = qd[:, joint]
        return np.stack((np.sign(v), v), axis=1)

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
        n_joints, parameters = _common_fields(data)
        return _built(lambda: cls(n_joints, parameters))


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
        super().__init__(n_joints, parameters)

    def parameter_counts(self) -> tuple[int, ...]:
        """Two, plus two per coupled joint."""
        return tuple(2 + 2 * len(p) for p in self._pairs)

    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """``[sgn(qd_j), qd_j, sgn(qd_ab), qd_ab, ...]``."""
        v = qd[:, joint]
        columns = [np.sign(v), v]
        for a, b in self._pairs[joint]:
            rel = qd[:, a] - qd[:, b]
            columns += [np.sign(rel), rel]
        return np.stack(columns, axis=1)

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
        n_joints, parameters = _common_fields(data)
        value = data.get("friction_inputs")
        if not isinstance(value, list) or len(value) != n_joints:
            raise ModelFileError(
                f"expected {n_joints} lists of joint indices", column="friction_inputs"
            )
        inputs = []
        for j, entry in enumerate(value):
            field = f"friction_inputs[{j}]"
            if not isinstance(entry, list):
                raise ModelFileError("expected a list of joint indices", column=field)
            inputs.append(tuple(file_int(k, field, 0, n_joints - 1) for k in entry))
        return _built(lambda: cls(n_joints, tuple(inputs), parameters))


def _common_fields(data: object) -> tuple[int, np.ndarray]:
    """``n_joints`` and finite ``parameters`` of a CV model's dict (ModelFileError naming them)."""
    if not isinstance(data, dict):
        raise ModelFileError(f"expected an object, got {type(data).__name__}")
    if "n_joints" not in data or "parameters" not in data:
        missing = "n_joints" if "n_joints" not in data else "parameters"
        raise ModelFileError("missing", column=missing)
    n_joints = file_int(data["n_joints"], "n_joints", 1, MAX_JOINTS)
    parameters = file_floats(data["parameters"], "parameters")
    if parameters.ndim != 1:
        raise ModelFileError("expected a flat list of numbers", column="parameters")
    return n_joints, parameters


def _built(build: Callable[[], FrictionModel]) -> Any:
    """``build()``, its ModelError (a count that does not match...) as ModelFileError."""
    try:
        return build()
    except ModelError as exc:
        raise ModelFileError(str(exc), column="parameters") from None
