"""Effects the residual loop adds to a model: torques linear in their parameters.

Each :class:`FoundEffect` acts on one joint with a fixed basis of named features (joint
angles, their differences, velocities, time, motor torque...) and identified coefficients.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from teleop_force.errors import ModelError


class FoundEffect(ABC):
    """A torque on one joint, linear in ``coefficients``."""

    joint: int
    coefficients: np.ndarray

    @abstractmethod
    def basis(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Basis functions at every sample (N x p)."""

    @abstractmethod
    def to_dict(self) -> dict[str, Any]:
        """Serialise (``kind`` included)."""

    def torque(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Torque of this effect on all joints (N x n), non-zero on ``joint`` only."""
        out = np.zeros_like(np.asarray(q, dtype=float))
        out[:, self.joint] = self.basis(t_s, q, qd, tau) @ self.coefficients
        return out


_REGISTRY: dict[str, type[FoundEffect]] = {}


def register_effect(kind: str):  # type: ignore[no-untyped-def]
    """Class decorator registering an effect class under ``kind`` for :func:`effect_from_dict`."""

    def wrap(cls: type[FoundEffect]) -> type[FoundEffect]:
        _REGISTRY[kind] = cls
        return cls

    return wrap


def effect_from_dict(data: dict[str, Any]) -> FoundEffect:
    """Rebuild an effect from its ``to_dict`` form."""
    kind = data.get("kind") if isinstance(data, dict) else None
    cls = _REGISTRY.get(str(kind))
    if cls is None:
        raise ModelError(f"unknown effect kind {kind!r}")
    return cls.from_dict(data)  # type: ignore[attr-defined,no-any-return]
