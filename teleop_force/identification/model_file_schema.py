"""The model file written by :meth:`DynamicModel.save` as msgspec schemas.

:class:`ModelFileEntry` is the whole file after its ``format`` and ``version`` (checked first,
so that a file of another kind says so): the base parameters, friction model and effects
are built by their own readers (``from_dict``, through :func:`teleop_force.schema.built_by`),
and the counts that tie the entries together are checked here. The friction entries are in
:mod:`teleop_force.friction.file_schema`.
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from msgspec import UNSET, Meta, Struct, UnsetType, structs

from teleop_force.errors import ConfigurationError, ModelError, ModelFileError
from teleop_force.friction import FrictionModel, friction_from_dict
from teleop_force.friction.base import MAX_JOINTS
from teleop_force.identification.effects import BasisSpec, FoundEffect, effect_from_dict
from teleop_force.identification.filtered_regressor import FilterConfig
from teleop_force.identification.regressor import BaseParameters
from teleop_force.schema import Finite, NonEmptyStr, built_by, shown

JointCount = Annotated[int, Meta(ge=1, le=MAX_JOINTS)]
ParameterIndex = Annotated[int, Meta(ge=0, lt=2**31)]
BasisCount = Annotated[int, Meta(ge=0, le=10**6)]

#: Builds the entries that are objects of the model (``base``, ``friction``, ``effects``).
MODEL_FILE_HOOK = built_by({FrictionModel: friction_from_dict, FoundEffect: effect_from_dict})


class FilterEntry(Struct, forbid_unknown_fields=True):
    """``filter``: the :class:`FilterConfig` of identification (its defaults when absent)."""

    cutoff_hz: Finite = FilterConfig.cutoff_hz
    velocity_cutoff_hz: Finite = FilterConfig.velocity_cutoff_hz
    torque_lag_samples: Annotated[int, Meta(ge=0, le=1)] = FilterConfig.torque_lag_samples
    warmup_s: Finite = FilterConfig.warmup_s

    def __post_init__(self) -> None:
        self.config()  # FilterConfig's own range checks, named after this entry

    def config(self) -> FilterConfig:
        """Build the :class:`FilterConfig` (ModelFileError when out of range)."""
        try:
            return FilterConfig(
                self.cutoff_hz, self.velocity_cutoff_hz, self.torque_lag_samples, self.warmup_s
            )
        except ConfigurationError as exc:
            raise ModelFileError(str(exc)) from None


class BaseParametersEntry(Struct):
    """``base``: full parameter names, the independent / dependent split and ``K``."""

    full_names: list[str]
    independent: list[ParameterIndex]
    dependent: list[ParameterIndex]
    dependency: list[list[Finite]]

    def __post_init__(self) -> None:
        size = len(self.full_names)
        for name, indices in (("independent", self.independent), ("dependent", self.dependent)):
            if any(i >= size for i in indices):
                raise ModelFileError(f"index {max(indices)} outside 0..{size - 1}", column=name)
        rows, cols = len(self.independent), len(self.dependent)
        if len(self.dependency) != rows or any(len(row) != cols for row in self.dependency):
            raise ModelFileError(f"expected {rows} rows of {cols} numbers", column="dependency")
        self.parameters()  # BaseParameters' own checks (each index once)

    def parameters(self) -> BaseParameters:
        """Build the :class:`BaseParameters` (ModelFileError if an index repeats or lacks)."""
        rows, cols = len(self.independent), len(self.dependent)
        try:
            return BaseParameters(
                tuple(self.full_names),
                np.array(self.independent, dtype=np.int64),
                np.array(self.dependent, dtype=np.int64),
                np.array(self.dependency, dtype=float).reshape(rows, cols),
            )
        except ModelError as exc:
            raise ModelFileError(str(exc), column="independent") from None


class BasisSpecEntry(Struct, forbid_unknown_fields=True):
    """An effect's :class:`BasisSpec`; keys left out take the BasisSpec's defaults."""

    joint: Annotated[int, Meta(ge=0, lt=MAX_JOINTS)]
    variable: str
    shape: str
    modulation: str | UnsetType = UNSET
    lo: Finite | UnsetType = UNSET
    hi: Finite | UnsetType = UNSET
    count: BasisCount | UnsetType = UNSET
    frequency: Finite | UnsetType = UNSET
    harmonics: BasisCount | UnsetType = UNSET
    scales: list[Finite] | UnsetType = UNSET

    def spec(self) -> BasisSpec:
        """Build the :class:`BasisSpec` (ModelError if the shape's settings do not fit)."""
        given = {k: v for k, v in structs.asdict(self).items() if v is not UNSET}
        if "scales" in given:
            given["scales"] = tuple(given["scales"])
        return BasisSpec(**given)


class EffectEntry(Struct, tag="basis", tag_field="kind"):
    """One found effect: its basis, coefficients, held-out share and reach (motor weights)."""

    spec: BasisSpecEntry
    coefficients: list[Finite]
    explained: float = 0.0
    reach: list[Finite] | None = None


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


__all__ = [
    "MODEL_FILE_HOOK",
    "BaseParametersEntry",
    "EffectEntry",
    "FilterEntry",
    "ModelFileEntry",
]
