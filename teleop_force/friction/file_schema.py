"""The friction entries of a model file as msgspec schemas (types, ranges, counts).

Each friction model's ``from_dict`` reads its entry with :func:`teleop_force.schema.read_entry`
and builds the model from it: what needs the built model (a network's pool) is checked there.
Keys that ``to_dict`` writes and no reader needs (``kind``) are ignored, as they always were.
"""

from __future__ import annotations

import sys
from typing import Annotated

from msgspec import Meta, Struct

from teleop_force.errors import ConfigurationError, ModelFileError
from teleop_force.friction.base import MAX_JOINTS
from teleop_force.friction.coulomb_viscous import CoupledCoulombViscous
from teleop_force.friction.coverage import CoverageConfig, CoverageMap
from teleop_force.friction.model_coordinates import MAX_MODEL_JOINTS
from teleop_force.friction.wavelet_network import A0_DEFAULT, B0_DEFAULT, WaveletJointSpec
from teleop_force.schema import Finite

JointCount = Annotated[int, Meta(ge=1, le=MAX_JOINTS)]
JointIndex = Annotated[int, Meta(ge=0, lt=MAX_JOINTS)]
#: A wavelet's dilation bound: the pool's own limits refuse what is too large to build.
Dilation = Annotated[int, Meta(ge=-1000, le=1000)]
#: A wavelet's dilation or translation in an ``active`` row (exact in a float64).
WaveletIndex = Annotated[int, Meta(ge=-(2**52), le=2**52)]
SampleCount = Annotated[float, Meta(ge=0.0, le=sys.float_info.max)]


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


class WaveletJointSpecEntry(Struct):
    """One joint network's inputs, velocity region, dilations and thresholds."""

    inputs: list[JointIndex]
    x_min_rad_s: list[Finite]
    x_max_rad_s: list[Finite]
    m_min: Dilation
    m_max: Dilation
    mu: Finite
    theta: Finite

    def __post_init__(self) -> None:
        self.spec()  # WaveletJointSpec's own checks, named after this entry

    def spec(self) -> WaveletJointSpec:
        """Build the joint's :class:`WaveletJointSpec` (ModelFileError if inconsistent)."""
        try:
            return WaveletJointSpec(
                tuple(self.inputs), tuple(self.x_min_rad_s), tuple(self.x_max_rad_s),
                self.m_min, self.m_max, self.mu, self.theta,
            )  # fmt: skip
        except ConfigurationError as exc:
            raise ModelFileError(str(exc)) from None


class WaveletJointEntry(WaveletJointSpecEntry):
    """A joint network: its spec, active wavelets as ``[m, n1..nd]`` rows, coefficients."""

    active: list[list[WaveletIndex]]
    coefficients: list[Finite]


class CoverageGridEntry(Struct):
    """One joint's occupancy grid: inputs, region and (flattened) sample counts."""

    inputs: list[JointIndex]
    x_min_rad_s: list[Finite]
    x_max_rad_s: list[Finite]
    counts: list[SampleCount]


class CoverageEntry(Struct):
    """A coverage map: its configuration and one grid per joint."""

    config: CoverageConfig
    grids: list[CoverageGridEntry]


class WaveletNetworkEntry(Struct):
    """``wn``: joint networks, the pool constants, the fallback and the coverage map."""

    n_joints: JointCount
    joints: list[WaveletJointEntry]
    a0: Finite = A0_DEFAULT
    b0: Finite = B0_DEFAULT
    edge_ring: bool = True
    fallback: CoupledCoulombViscous | None = None
    coverage: CoverageMap | None = None

    def __post_init__(self) -> None:
        n = self.n_joints
        if len(self.joints) != n:
            raise ModelFileError(f"expected {n} joint networks", column="joints")
        for j, joint in enumerate(self.joints):
            if max(joint.inputs) >= n:
                raise ModelFileError(
                    f"velocity index {max(joint.inputs)} >= {n}", column=f"joints[{j}].inputs"
                )
        if self.coverage is not None:
            if self.coverage.n_joints != n:
                raise ModelFileError(
                    f"{self.coverage.n_joints} grids for {n} joints", column="coverage.grids"
                )
            for j in range(n):
                if max(self.coverage.grid_inputs(j)) >= n:
                    raise ModelFileError(
                        f"reads a velocity beyond joint {n}", column=f"coverage.grids[{j}].inputs"
                    )
