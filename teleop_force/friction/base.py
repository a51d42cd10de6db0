"""The :class:`FrictionModel` abstract base: joint friction linear in its parameters.

Most friction models are a set of per-joint bases (``block_diagonal``): joint ``j``'s friction
torque is ``basis(j, qd) @ parameters[slice_j]`` where ``qd`` holds the velocities of all
motor joints. Keeping the bases per joint lets networks with hundreds of wavelets per joint
be fitted without building a dense ``(samples, joints, parameters)`` tensor.

A model whose parameters act on several joints at once (friction in the model coordinates of
a coupled robot, mapped to the motors through the coupling) is not block-diagonal: it
overrides :meth:`FrictionModel.regressor` and :meth:`FrictionModel.torque`, and its
per-joint interface (``basis``, ``joint_slice``) refuses to answer. Fits that take every
parameter at once use :meth:`FrictionModel.regressor` and work with both.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Annotated, Any, ClassVar

import numpy as np
from msgspec import Meta

from teleop_force.errors import ModelError, ModelFileError

#: Most joints a model file may declare (keeps a bad count from allocating gigabytes).
MAX_JOINTS = 256
#: A model file's joint count (``n_joints``).
JointCount = Annotated[int, Meta(ge=1, le=MAX_JOINTS)]
#: A 0-based joint index in a model file.
JointIndex = Annotated[int, Meta(ge=0, lt=MAX_JOINTS)]


def file_error(exc: Exception, field: str, what: str) -> ModelFileError:
    """Return the ModelFileError that ``exc``, raised reading ``field`` of a ``what``, becomes.

    A ModelFileError that already names its field is kept; a missing key, or a bad value met
    by a constructor (``TypeError``, ``ValueError``, ``OverflowError``), is named ``field``.
    """
    if isinstance(exc, ModelFileError):
        return exc if exc.column is not None else ModelFileError(exc.problem, column=field)
    if isinstance(exc, KeyError):
        return ModelFileError(f"missing {exc}", column=field)
    return ModelFileError(f"bad {what}: {exc}", column=field)


#: What a model-file reader turns into a ModelFileError with :func:`file_error`.
FILE_ERRORS = (ModelFileError, KeyError, TypeError, ValueError, OverflowError)


class FrictionModel(ABC):
    """Joint friction ``tau_f(qd)``, linear in ``parameters``."""

    #: Short name used in model files and on the command line.
    kind: ClassVar[str]
    #: Whether joint ``j``'s torque is ``basis(j, qd) @ joint_parameters(j)`` (each parameter
    #: acts on one joint). Models acting through a coupling set it False.
    block_diagonal: ClassVar[bool] = True

    def __init__(self, n_joints: int, parameters: np.ndarray | None = None) -> None:
        """Create the model; ``parameters`` defaults to zeros."""
        if n_joints < 1:
            raise ModelError(f"friction model needs >= 1 joint, got {n_joints}")
        self.n_joints = n_joints
        count = int(sum(self.parameter_counts()))
        if parameters is None:
            parameters = np.zeros(count)
        self.parameters = np.asarray(parameters, dtype=float).copy()
        if self.parameters.shape != (count,):
            raise ModelError(
                f"{self.kind}: expected {count} parameters, got {self.parameters.shape}"
            )

    @abstractmethod
    def parameter_counts(self) -> tuple[int, ...]:
        """Return the number of parameters of each joint's basis.

        Of each parameter group for a model that is not ``block_diagonal``.
        """

    @abstractmethod
    def basis(self, joint: int, qd: np.ndarray) -> np.ndarray:
        """Return joint ``joint``'s (0-based) basis at velocities ``qd``: (N x n) -> (N x p_j)."""

    @abstractmethod
    def parameter_names(self, joint: int) -> list[str]:
        """Human-readable names of joint ``joint``'s parameters."""

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """Serialise to JSON-compatible values (``kind`` included)."""

    def regressor(self, qd: np.ndarray) -> np.ndarray:
        """Friction regressor at velocities ``qd`` (N x n) -> (N x n x p): torque = it @ parameters.

        Block-diagonal here: joint ``j``'s row holds ``basis(j, qd)`` in its own slice.
        """
        qd = np.asarray(qd, dtype=float)
        out = np.zeros((qd.shape[0], self.n_joints, self.parameters.size))
        for j in range(self.n_joints):
            out[:, j, self.joint_slice(j)] = self.basis(j, qd)
        return out

    def all_parameter_names(self) -> list[str]:
        """Names of every parameter, in the order of ``parameters``."""
        return [name for j in range(self.n_joints) for name in self.parameter_names(j)]

    def joint_slice(self, joint: int) -> slice:
        """Slice of ``parameters`` that belongs to ``joint``."""
        counts = self.parameter_counts()
        start = int(sum(counts[:joint]))
        return slice(start, start + counts[joint])

    def joint_parameters(self, joint: int) -> np.ndarray:
        """View of joint ``joint``'s parameters."""
        return self.parameters[self.joint_slice(joint)]

    def set_joint_parameters(self, joint: int, values: np.ndarray) -> None:
        """Overwrite joint ``joint``'s parameters."""
        self.parameters[self.joint_slice(joint)] = values

    def torque(self, qd: np.ndarray) -> np.ndarray:
        """Friction torque [N m] at velocities ``qd`` ((n,) -> (n,), or (N, n) -> (N, n))."""
        qd = np.asarray(qd, dtype=float)
        single = qd.ndim == 1
        batch = qd.reshape(1, -1) if single else qd
        if batch.shape[1] != self.n_joints:
            raise ModelError(
                f"{self.kind}: expected {self.n_joints} velocities, got {batch.shape[1]}"
            )
        out = np.empty((batch.shape[0], self.n_joints))
        for j in range(self.n_joints):
            out[:, j] = self.basis(j, batch) @ self.joint_parameters(j)
        return out[0] if single else out

    def coverage_weight(self, qd: np.ndarray) -> np.ndarray:
        """How much each joint's estimate at ``qd`` (N x n) rests on training data, in [0, 1].

        Models with a fixed parametric shape trust themselves everywhere (all ones).
        """
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        return np.ones((qd.shape[0], self.n_joints))
