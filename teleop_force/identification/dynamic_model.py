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
from teleop_force.friction import friction_from_dict
from teleop_force.friction.base import MAX_JOINTS, FrictionModel, file_floats, file_int
from teleop_force.identification.filtered_regressor import FilterConfig, FilteredSignals
from teleop_force.identification.lowpass import lowpass_batch
from teleop_force.identification.regressor import BaseParameters
from teleop_force.robots.description import RobotDescription
from teleop_force.robots.registry import resolve_robot

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
            :mod:`teleop_force.identification.effects`).
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
        """Return the robot description this model was identified for."""
        return resolve_robot(self.robot, self.n_joints)

    def friction_torque(self, qd: np.ndarray, blend: bool = True) -> np.ndarray:
        """Friction torque at velocities ``qd`` (N x n); coverage-aware unless ``blend=False``."""
        blended = getattr(self.friction, "blended_torque", None) if blend else None
        return blended(qd) if blended is not None else self.friction.torque(qd)

    def effects_torque(
        self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, load: np.ndarray
    ) -> np.ndarray:
        """Torque of the found effects (N x n); ``load`` is the filtered rigid-body model torque."""
        total = np.zeros_like(np.asarray(q, dtype=float))
        for effect in self.effects:
            total += effect.torque(t_s, q, qd, load)
        return total

    def predict_filtered_torque(
        self, signals: FilteredSignals, tau_nm: np.ndarray, blend: bool = True
    ) -> np.ndarray:
        """Return the filtered model torque ``tau_hat_L`` (the paper's eq. (10)) of a recording."""
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
        """Read what :meth:`to_dict` wrote; raise ModelFileError naming the file and field.

        Every number the estimate depends on must be finite (``base_values``,
        ``offsets_nm``, ``base.dependency``, friction parameters, filter settings, effect
        coefficients); indices must lie inside what they index (``base.independent``, a
        network's active wavelets, friction inputs); the base must fit the robot's parameter
        count when the robot can be resolved. ``base_std`` may hold NaN (unknown).
        """
        if not isinstance(data, dict) or data.get("format") != MODEL_FORMAT:
            raise ModelFileError("not a teleop-force model file", path=source, column="format")
        version = data.get("version")
        if type(version) is not int or version != MODEL_VERSION:
            shown = repr(version) if not isinstance(version, int) or abs(version) < 10**9 else "?"
            raise ModelFileError(
                f"model version {shown} is not supported (expected {MODEL_VERSION})",
                path=source,
                column="version",
            )
        current = "robot"
        try:
            robot = data["robot"]
            if not isinstance(robot, str) or not robot:
                raise ModelFileError("expected a robot name or description file")
            current = "n_joints"
            n_joints = file_int(data["n_joints"], current, 1, MAX_JOINTS)
            current = "filter"
            config = _filter_config(data["filter"])
            current = "base"
            base_value = data["base"]
            base = None if base_value is None else BaseParameters.from_dict(base_value)
            current = "base_values"
            values = _vector(data["base_values"], current, 0 if base is None else base.count)
            current = "base_std"
            std = data.get("base_std")
            if std is None:
                std = np.zeros_like(values)
            else:
                std = _vector(std, current, values.size, finite=False)
            current = "friction"
            friction = friction_from_dict(data["friction"])
            if friction.n_joints != n_joints:
                raise ModelFileError(
                    f"friction model has {friction.n_joints} joints, expected {n_joints}"
                )
            current = "offsets_nm"
            offsets = data.get("offsets_nm")
            offsets = np.zeros(n_joints) if offsets is None else _vector(offsets, current, n_joints)
            current = "effects"
            effects = _effects(data.get("effects", []), n_joints)
            current = "notes"
            notes = data.get("notes", {})
            if not isinstance(notes, dict):
                raise ModelFileError(f"expected an object, got {type(notes).__name__}")
            current = "base"
            if base is not None:
                _check_base_fits_robot(base, robot, n_joints)
            current = "model"
            return cls(
                robot, n_joints, config, base, values, std, friction, offsets, effects, dict(notes)
            )
        except ModelFileError as exc:
            column = current if exc.column is None else f"{current}.{exc.column}"
            if exc.column is not None and exc.column.split(".")[0].split("[")[0] == current:
                column = exc.column
            raise ModelFileError(exc.problem, path=source, row=exc.row, column=column) from None
        except KeyError as exc:
            raise ModelFileError(f"missing {exc}", path=source, column=current) from None
        except (TypeError, ValueError, ArithmeticError, LookupError) as exc:
            # ModelError and ConfigurationError are ValueErrors: their message names the problem
            raise ModelFileError(f"bad value: {exc}", path=source, column=current) from None

    @classmethod
    def load(cls, path: str | Path) -> DynamicModel:
        """Load a model saved by :meth:`save`; raise ModelFileError naming the file (and field)."""
        try:
            raw = Path(path).read_bytes()
        except OSError as exc:
            raise ModelFileError(f"cannot read: {exc.strerror or exc}", path=path) from None
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ModelFileError(f"not UTF-8 text (byte {exc.start})", path=path) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ModelFileError(f"not JSON: {exc.msg}", path=path, row=exc.lineno) from None
        except (ValueError, RecursionError) as exc:  # e.g. an integer of > 4300 digits
            raise ModelFileError(f"not JSON: {str(exc)[:120]}", path=path) from None
        return cls.from_dict(data, str(path))


def _vector(value: object, field: str, size: int, finite: bool = True) -> np.ndarray:
    """Read a flat list of ``size`` numbers (finite unless told); ModelFileError names ``field``."""
    out = file_floats(value, field, finite=finite)
    if out.shape != (size,):
        raise ModelFileError(f"expected {size} numbers, got shape {out.shape}", column=field)
    return out


def _filter_config(value: object) -> FilterConfig:
    """Read the ``filter`` object: known keys only, finite numbers within FilterConfig's ranges."""
    if not isinstance(value, dict):
        raise ModelFileError(f"expected an object, got {type(value).__name__}")
    for key, item in value.items():
        number = file_floats(item, str(key))
        if number.ndim != 0:
            raise ModelFileError("expected a number", column=str(key))
    try:
        return FilterConfig(**value)
    except TypeError as exc:  # an unknown key
        raise ModelFileError(str(exc)) from None
    except ValueError as exc:  # ConfigurationError: out of range
        raise ModelFileError(str(exc)) from None


def _effects(value: object, n_joints: int) -> tuple[Any, ...]:
    """Read the found effects: valid entries acting on a joint of the model, finite numbers."""
    from teleop_force.identification.effects import effect_from_dict

    if not isinstance(value, list):
        raise ModelFileError(f"expected a list, got {type(value).__name__}")
    out = []
    for i, entry in enumerate(value):
        field = f"effects[{i}]"
        try:
            effect = effect_from_dict(entry)
        except (KeyError, TypeError, ValueError, ArithmeticError, LookupError) as exc:
            raise ModelFileError(f"bad effect: {exc}", column=field) from None
        joint = getattr(effect.spec, "joint", None)
        if isinstance(joint, bool) or not isinstance(joint, int) or not 0 <= joint < n_joints:
            raise ModelFileError(
                f"acts on joint {joint!r}, outside 0..{n_joints - 1}", column=field
            )
        file_floats(effect.coefficients, f"{field}.coefficients")
        if effect.reach is not None and effect.reach.size != n_joints:
            raise ModelFileError(
                f"reach has {effect.reach.size} weights, the model has {n_joints} joints",
                column=f"{field}.reach",
            )
        out.append(effect)
    return tuple(out)


def _check_base_fits_robot(base: BaseParameters, robot: str, n_joints: int) -> None:
    """Check the base indexes the robot's full parameters (skipped if the robot is not found)."""
    from teleop_force.errors import TeleopForceError
    from teleop_force.identification.regressor import full_parameter_names

    try:
        description = resolve_robot(robot, n_joints)
    except (TeleopForceError, OSError):
        return  # reported when the model is used (an estimator resolves it again)
    if description.model is None:
        return
    if description.n_joints != n_joints:
        raise ModelFileError(
            f"robot {robot!r} has {description.n_joints} joints, the model {n_joints}"
        )
    expected = len(full_parameter_names(description))
    if len(base.full_names) != expected:
        raise ModelFileError(
            f"{len(base.full_names)} full parameters, robot {robot!r} has {expected}",
            column="full_names",
        )
