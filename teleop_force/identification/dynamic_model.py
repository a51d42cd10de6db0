"""The identified dynamic model: rigid-body base parameters, friction and found effects.

Saved as JSON so it can be read back exactly (``save`` / ``load``) and shared. The file after
its ``format`` and ``version`` (checked first, so that a file of another kind says so) is read
as :class:`ModelFileEntry`: the base parameters, friction model and effects are read by their
own entries (beside the classes they describe) or built by their readers (``from_dict``,
through :func:`teleop_force.schema.built_by`), and the counts that tie them together are
checked here.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from msgspec import Struct

from teleop_force.errors import ModelError, ModelFileError, TeleopForceError
from teleop_force.friction.base import FrictionModel, JointCount
from teleop_force.friction.model_file import friction_from_dict
from teleop_force.identification.effects import FoundEffect, effect_from_dict, total_torque
from teleop_force.identification.filtered_regressor import (
    FilterConfig,
    FilteredSignals,
    FilterEntry,
)
from teleop_force.identification.regressor import (
    BaseParameters,
    BaseParametersEntry,
    full_parameter_names,
)
from teleop_force.lowpass import lowpass_batch
from teleop_force.robots.description import RobotDescription
from teleop_force.robots.registry import resolve_robot
from teleop_force.schema import Finite, NonEmptyStr, built_by, read_entry, shown

MODEL_FORMAT = "teleop-force-model"
MODEL_VERSION = 1

#: Builds the entries that are objects of the model (``base``, ``friction``, ``effects``).
MODEL_FILE_HOOK = built_by({FrictionModel: friction_from_dict, FoundEffect: effect_from_dict})


def friction_torque(friction: FrictionModel, qd: np.ndarray, blend: bool = True) -> np.ndarray:
    """``friction``'s torque at ``qd`` (N x n) as a model evaluates it.

    Coverage-blended when the friction blends (a wavelet network with a fallback), unless
    ``blend=False``.
    """
    blended = getattr(friction, "blended_torque", None) if blend else None
    return np.asarray(blended(qd) if blended is not None else friction.torque(qd))


def sticking_rad_of(friction: FrictionModel) -> float:
    """Return the sticking transition angle [rad] of the Coulomb terms (a network's fallback's).

    0 for a friction without a sticking state.
    """
    table = getattr(friction, "fallback", None) or friction
    return float(getattr(table, "sticking_rad", 0.0))


def path_friction_torque(
    friction: FrictionModel, q_rad: np.ndarray, qd_rad_s: np.ndarray, blend: bool = True
) -> np.ndarray:
    """:func:`friction_torque` along a path of one stream: a sticking state follows ``q_rad``.

    Coulomb-viscous models with a sticking transition angle, and wavelet networks whose
    fallback has one, evaluate it along the angles (from ``z = 0``); others as
    :func:`friction_torque`.
    """
    path_torque = getattr(friction, "path_torque", None)
    if path_torque is None:
        return friction_torque(friction, qd_rad_s, blend)
    if getattr(friction, "fallback", None) is not None:  # a network
        return np.asarray(path_torque(q_rad, qd_rad_s, blend))
    return np.asarray(path_torque(q_rad, qd_rad_s))


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
        effects: Effects found by the residual loop
            (:class:`~teleop_force.identification.effects.FoundEffect`).
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
    effects: tuple[FoundEffect, ...] = ()
    notes: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        r = 0 if self.base is None else self.base.count
        if self.base_values.shape != (r,):
            raise ModelError(f"model has {self.base_values.shape} base values, expected {r}")
        if self.friction.n_joints != self.n_joints:
            raise ModelError("friction model and robot differ in joint count")
        if self.offsets_nm.shape != (self.n_joints,):
            raise ModelError("offsets_nm needs one value per joint")
        counts = len(self.filter_config.count_rad)
        if counts not in (0, self.n_joints):
            raise ModelError(f"filter count_rad has {counts} counts for {self.n_joints} joints")

    def description(self) -> RobotDescription:
        """Return the robot description this model was identified for."""
        return resolve_robot(self.robot, self.n_joints)

    def friction_torque(self, qd: np.ndarray, blend: bool = True) -> np.ndarray:
        """Friction torque at velocities ``qd`` (N x n); coverage-aware unless ``blend=False``."""
        return friction_torque(self.friction, qd, blend)

    def path_friction_torque(
        self, q_rad: np.ndarray, qd_rad_s: np.ndarray, blend: bool = True
    ) -> np.ndarray:
        """Friction torque along a path of one stream (:func:`path_friction_torque`)."""
        return path_friction_torque(self.friction, q_rad, qd_rad_s, blend)

    def effects_torque(
        self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, load: np.ndarray
    ) -> np.ndarray:
        """Torque of the found effects (N x n); ``load`` is the filtered rigid-body model torque."""
        if not self.effects:
            return np.zeros_like(np.asarray(q, dtype=float))
        return total_torque(self.effects, t_s, q, qd, load)

    def predict_filtered_torque(
        self, signals: FilteredSignals, tau_nm: np.ndarray, blend: bool = True
    ) -> np.ndarray:
        """Return the filtered model torque ``tau_hat_L`` (the paper's eq. (10)) of a recording."""
        t = signals.t_s
        rigid = np.einsum("kjp,p->kj", signals.rigid_regressor, self.base_values)
        other = self.path_friction_torque(signals.q_rad, signals.qd_rad_s, blend)
        other = other + self.offsets_nm[None, :]
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
            "filter": _filter_dict(self.filter_config),
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
            given = repr(version) if not isinstance(version, int) or abs(version) < 10**9 else "?"
            raise ModelFileError(
                f"model version {given} is not supported (expected {MODEL_VERSION})",
                path=source,
                column="version",
            )
        try:
            entry = read_entry(data, ModelFileEntry, dec_hook=MODEL_FILE_HOOK)
            base = None if entry.base is None else entry.base.parameters()
            if base is not None:
                _check_base_fits_robot(base, entry.robot, entry.n_joints)
        except ModelFileError as exc:
            raise ModelFileError(exc.problem, path=source, row=exc.row, column=exc.column) from None
        n = entry.n_joints
        offsets = np.zeros(n) if entry.offsets_nm is None else np.array(entry.offsets_nm)
        values = np.array(entry.base_values)
        std = np.zeros_like(values) if entry.base_std is None else np.array(entry.base_std)
        try:
            return cls(
                entry.robot, n, entry.filter.config(), base, values, std, entry.friction,
                offsets, tuple(entry.effects), dict(entry.notes),
            )  # fmt: skip
        except ModelError as exc:
            raise ModelFileError(f"bad value: {exc}", path=source, column="model") from None

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


def _filter_dict(config: FilterConfig) -> dict[str, Any]:
    """Return a model file's ``filter``: the count observer's fields only when used."""
    values = asdict(config)
    if not values["count_observer"]:
        del values["count_observer"]
    if values["count_rad"]:
        values["count_rad"] = list(values["count_rad"])
    else:
        del values["count_rad"]
    return values


class ModelFileEntry(Struct):
    """A model file's content (``base_names`` is written for readers, never read back)."""

    robot: NonEmptyStr
    n_joints: JointCount
    filter: FilterEntry
    base: BaseParametersEntry | None
    base_values: list[Finite]
    friction: FrictionModel
    base_std: list[float] | None = None  # NaN: unknown
    offsets_nm: list[Finite] | None = None
    effects: list[FoundEffect] = []
    notes: dict[str, Any] = {}

    def __post_init__(self) -> None:
        n = self.n_joints
        sizes = {
            "base_values": (
                self.base_values,
                0 if self.base is None else len(self.base.independent),
            ),
            "base_std": (self.base_std, len(self.base_values)),
            "offsets_nm": (self.offsets_nm, n),
        }
        for name, (values, size) in sizes.items():
            if values is not None and len(values) != size:
                raise ModelFileError(f"expected {size} numbers, got {len(values)}", column=name)
        if self.friction.n_joints != n:
            raise ModelFileError(
                f"friction model has {self.friction.n_joints} joints, expected {n}",
                column="friction",
            )
        for i, effect in enumerate(self.effects):
            if not 0 <= effect.spec.joint < n:
                raise ModelFileError(
                    f"acts on joint {shown(effect.spec.joint)}, outside 0..{n - 1}",
                    column=f"effects[{i}]",
                )
            if effect.reach is not None and effect.reach.size != n:
                raise ModelFileError(
                    f"reach has {effect.reach.size} weights, the model has {n} joints",
                    column=f"effects[{i}].reach",
                )


def _check_base_fits_robot(base: BaseParameters, robot: str, n_joints: int) -> None:
    """Check the base indexes the robot's full parameters (skipped if the robot is not found)."""
    try:
        description = resolve_robot(robot, n_joints)
    except (TeleopForceError, OSError):
        return  # reported when the model is used (an estimator resolves it again)
    if description.model is None:
        return
    if description.n_joints != n_joints:
        raise ModelFileError(
            f"robot {robot!r} has {description.n_joints} joints, the model {n_joints}",
            column="base",
        )
    expected = len(full_parameter_names(description))
    if len(base.full_names) != expected:
        raise ModelFileError(
            f"{len(base.full_names)} full parameters, robot {robot!r} has {expected}",
            column="base.full_names",
        )
