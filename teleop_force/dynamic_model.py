"""The identified dynamic model: rigid-body base parameters, friction and found effects.

Saved as JSON so it can be read back exactly (``save`` / ``load``) and shared.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from teleop_force.errors import ModelError, ModelFileError
from teleop_force.filtered_regressor import FilterConfig, FilteredSignals
from teleop_force.friction import friction_from_dict
from teleop_force.friction.base import FrictionModel
from teleop_force.lowpass import lowpass_batch
from teleop_force.regressor import BaseParameters
from teleop_force.robot import RobotDescription
from teleop_force.robots import resolve_robot

MODEL_FORMAT = "teleop-force-model"
MODEL_VERSION = 1


@dataclass(frozen=True, eq=False)
class DynamicModel:
    """Everything needed to compute the model torque of a robot from its motion.

    Attributes:
        robot: Name of the robot description (``omni``, ``none``...).
        n_joints: Number of motor joints.
        filter_config: Filters used in identification; estimation uses the same.
        base: Structure of the base parameters (``None`` without rigid-body terms).
        base_values: Identified base parameters.
        base_std: Their standard deviations.
        friction: Friction model (its parameters may adapt online).
        offsets_nm: Constant torque per joint (used when there are no rigid-body terms).
        effects: Effects found by the residual loop (JSON dicts understood by
            :mod:`teleop_force.effects`).
        notes: Free-form provenance (data files, figures at identification time).
    """

    robot: str
    n_joints: int
    filter_config: FilterConfig
    base: BaseParameters | None
    base_values: np.ndarray
    base_std: np.ndarray
    friction: FrictionModel
    offsets_nm: np.ndarray
    effects: tuple[Any, ...] = ()
    notes: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        r = 0 if self.base is None else self.base.count
        if self.base_values.shape != (r,):
            raise ModelError(f"model has {self.base_values.shape} base values, expected {r}")
        if self.friction.n_joints != self.n_joints:
            raise ModelError("friction model and robot differ in joint count")
        if self.offsets_nm.shape != (self.n_joints,):
            raise ModelError("offsets_nm needs one value per joint")

    def description(self) -> RobotDescription:
        """The robot description this model was identified for."""
        return resolve_robot(self.robot, self.n_joints)

    def friction_torque(self, qd: np.ndarray, blend: bool = True) -> np.ndarray:
        """Friction torque at velocities ``qd`` (N x n); coverage-aware unless ``blend=False``."""
        blended = getattr(self.friction, "blended_torque", None) if blend else None
        return blended(qd) if blended is not None else self.friction.torque(qd)

    def effects_torque(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, load: np.ndarray) -> np.ndarray:
        """Torque of the found effects (N x n); ``load`` is the filtered rigid-body model torque."""
        total = np.zeros_like(np.asarray(q, dtype=float))
        for effect in self.effects:
            total += effect.torque(t_s, q, qd, load)
        return total

    def predict_filtered_torque(
        self, signals: FilteredSignals, tau_nm: np.ndarray, blend: bool = True
    ) -> np.ndarray:
        """The filtered model torque ``tau_hat_L`` of the paper's eq. (10) for a recording."""
        t = signals.t_s
        rigid = np.einsum("kjp,p->kj", signals.rigid_regressor, self.base_values)
        other = self.friction_torque(signals.qd_rad_s, blend) + self.offsets_nm[None, :]
        if self.effects:
            other = other + self.effects_torque(t, signals.q_rad, signals.qd_rad_s, rigid)
        return rigid + lowpass_batch(other, t, self.filter_config.cutoff_hz)

    def to_dict(self) -> dict[str, Any]:
        """Serialise to JSON-compatible values."""
        return {
            "format": MODEL_FORMAT,
            "version": MODEL_VERSION,
            "robot": self.robot,
            "n_joints": self.n_joints,
            "filter": asdict(self.filter_config),
            "base": None if self.base is None else self.base.to_dict(),
            "base_names": [] if self.base is None else self.base.names(),
            "base_values": self.base_values.tolist(),
            "base_std": self.base_std.tolist(),
            "friction": self.friction.to_dict(),
            "offsets_nm": self.offsets_nm.tolist(),
            "effects": [e.to_dict() for e in self.effects],
            "notes": self.notes,
        }

    def save(self, path: str | Path) -> None:
        """Write the model as JSON."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<model>") -> DynamicModel:
        """Read what :meth:`to_dict` wrote; raise ModelFileError naming the field otherwise."""
        from teleop_force.effects import effect_from_dict

        if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
            raise ModelFileError("not a teleop-force model file", path=source, column="format")
        if data.get("version") != MODEL_VERSION:
            raise ModelFileError(
                f"model version {data.get('version')!r} is not supported (expected {MODEL_VERSION})",
                path=source,
                column="version",
            )
        current = "robot"
        try:
            robot = str(data["robot"])
            current = "n_joints"
            n_joints = int(data["n_joints"])
            current = "filter"
            config = FilterConfig(**data["filter"])
            current = "base"
            base = None if data["base"] is None else BaseParameters.from_dict(data["base"])
            current = "base_values"
            values = np.asarray(data["base_values"], dtype=float)
            std = np.asarray(data.get("base_std", np.zeros_like(values)), dtype=float)
            current = "friction"
            friction = friction_from_dict(data["friction"])
            current = "offsets_nm"
            offsets = np.asarray(data.get("offsets_nm", np.zeros(n_joints)), dtype=float)
            current = "effects"
            effects = tuple(effect_from_dict(e) for e in data.get("effects", []))
            return cls(robot, n_joints, config, base, values, std, friction, offsets, effects, dict(data.get("notes", {})))
        except ModelFileError:
            raise
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ModelFileError(f"bad value: {exc}", path=source, column=current) from exc

    @classmethod
    def load(cls, path: str | Path) -> DynamicModel:
        """Load a model saved by :meth:`save`."""
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise ModelFileError(f"cannot read: {exc.strerror}", path=path) from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ModelFileError(f"not JSON: {exc.msg}", path=path, row=exc.lineno) from exc
        return cls.from_dict(data, str(path))
