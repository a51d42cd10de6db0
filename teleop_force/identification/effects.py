"""Effects the residual loop adds to a model: torques linear in their parameters.

An effect is a :class:`BasisSpec` (which variable, which fixed shape, which modulation) and
its coefficients. Variables are named as in docs/cli.md: ``q2`` (angle), ``q2-q3`` (angle
difference), ``qd1`` (velocity), ``tau3`` (the load on joint 3), ``t`` (time since start).

``tau<j>`` is the *rigid-body model* torque of joint ``j`` (low-pass filtered), not the measured
motor torque: the measured torque contains the very residual being explained, and as a
variable it "explains" 15-20 % of a clean recording's friction misfit by itself (measured on
simulated clean data). The model torque carries the same load (gravity, inertia, spring)
without that leak.

An effect acts on the joint it was found on, or, found on a coupled robot whose physics acts at
its model joints, at that model joint, reaching the motors through the coupling
(:attr:`FoundEffect.reach`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Annotated, Any

import numpy as np
from msgspec import UNSET, Meta, Struct, UnsetType, structs

from teleop_force.errors import ModelError
from teleop_force.friction.base import JointIndex
from teleop_force.identification.effect_terms import (
    VARIABLE_CODES,
    EffectModulation,
    EffectShape,
    EffectTable,
    EffectVariable,
    VariableKind,
    effect_basis,
    effects_torque,
    variable_values_batch,
)
from teleop_force.schema import Finite, read_entry

#: A count of bumps or harmonics in a model file.
BasisCount = Annotated[int, Meta(ge=0, le=10**6)]


def _samples(values: np.ndarray) -> np.ndarray:
    """``values`` as a C-contiguous 2-D float array."""
    return np.ascontiguousarray(np.asarray(values, dtype=float))


def _since_start(t_s: np.ndarray) -> np.ndarray:
    """Time since the first sample."""
    t = np.ascontiguousarray(np.asarray(t_s, dtype=float).reshape(-1))
    return t - t[0] if t.size else t


def variable_values(
    name: str, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Values of the named variable at every sample (``t`` is time since the first sample)."""
    variable = EffectVariable.parse(name)
    q = _samples(q)
    variable.check_joints(q.shape[1])
    return variable_values_batch(
        VARIABLE_CODES[variable.kind], variable.first, variable.second,
        _since_start(t_s), q, _samples(qd), _samples(tau),
    )  # fmt: skip


@dataclass(frozen=True)
class BasisSpec:
    """How an effect's basis is computed.

    Attributes:
        joint: Joint the torque acts on (0-based).
        variable: Variable the effect depends on (``q2``, ``q2-q3``, ``qd1``, ``tau3``, ``t``).
        shape: ``constant``; ``linear`` (x); ``smooth`` (Gaussian bumps over ``[lo, hi]``);
            ``periodic`` (sin/cos of ``k * frequency * x``, k = 1..harmonics); ``abs`` (|x|);
            ``stribeck`` (``exp(-(x / v)^2)`` for each scale v).
        modulation: ``none``; ``sign`` (times ``sgn(qd_joint)``); ``positive`` (times
            ``[qd_joint > 0]``); ``both`` (the basis and the basis times ``sgn(qd_joint)``: a
            shape with a direction-dependent part, like a cable's hysteresis).
        lo, hi: Range of ``smooth`` bumps.
        count: Number of bumps (``smooth``).
        frequency: Base spatial frequency [rad/unit of x] (``periodic``).
        harmonics: Harmonics (``periodic``).
        scales: Velocity scales (``stribeck``).

    """

    joint: int
    variable: str
    shape: EffectShape | str
    modulation: EffectModulation | str = "none"
    lo: float = 0.0
    hi: float = 1.0
    count: int = 0
    frequency: float = 0.0
    harmonics: int = 0
    scales: tuple[float, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "shape", EffectShape(self.shape))
        except ValueError:
            raise ModelError(f"unknown effect shape {self.shape!r}") from None
        try:
            object.__setattr__(self, "modulation", EffectModulation(self.modulation))
        except ValueError:
            raise ModelError(f"unknown effect modulation {self.modulation!r}") from None
        parsed: EffectVariable | None = None
        if self.shape != "constant":
            parsed = EffectVariable.parse(self.variable)
        # the parsed variable (not a field: the model file keeps the spelling)
        object.__setattr__(self, "_parsed_variable", parsed)
        if self.shape == "smooth" and (self.count < 2 or not self.hi > self.lo):
            raise ModelError("smooth effect needs count >= 2 and hi > lo")
        if self.shape == "periodic" and (self.harmonics < 1 or not self.frequency > 0):
            raise ModelError("periodic effect needs harmonics >= 1 and frequency > 0")
        if self.shape == "stribeck" and (not self.scales or min(self.scales) <= 0):
            raise ModelError("stribeck effect needs positive velocity scales")
        object.__setattr__(self, "scales", tuple(float(s) for s in self.scales))

    @property
    def effect_variable(self) -> EffectVariable | None:
        """The variable, parsed (None for a ``constant`` shape, which reads none)."""
        return self._parsed_variable  # type: ignore[attr-defined]

    @property
    def shape_count(self) -> int:
        """Bumps (``smooth``), harmonics (``periodic``) or scales (``stribeck``); else 1."""
        return {
            "smooth": self.count,
            "periodic": self.harmonics,
            "stribeck": len(self.scales),
        }.get(self.shape, 1)

    def shape_parameters(self) -> np.ndarray:
        """Floats of the shape: ``[lo, hi]`` (smooth), ``[frequency]`` (periodic), the scales."""
        if self.shape == "smooth":
            return np.array([self.lo, self.hi])
        if self.shape == "periodic":
            return np.array([self.frequency])
        return np.asarray(self.scales, dtype=float)

    def check_joints(self, n_joints: int) -> None:
        """Raise ModelError if the effect acts on or reads a joint outside ``1..n_joints``."""
        if not 0 <= self.joint < n_joints:
            raise ModelError(f"effect on joint {self.joint + 1}, outside 1..{n_joints}")
        if self.effect_variable is not None:
            self.effect_variable.check_joints(n_joints)

    def term_row(
        self,
    ) -> tuple[EffectVariable | None, EffectShape, EffectModulation, int, int, int]:
        """``(variable, shape, modulation, joint, count, size)`` for :meth:`EffectTable.build`."""
        return (
            self.effect_variable, EffectShape(self.shape), EffectModulation(self.modulation),
            self.joint, self.shape_count, self.size,
        )  # fmt: skip

    def table(
        self, n_joints: int, coefficients: np.ndarray | None = None, reach: np.ndarray | None = None
    ) -> EffectTable:
        """Encode the basis for the compiled terms (ModelError: a joint outside 1..n)."""
        self.check_joints(n_joints)
        return EffectTable.build(
            [self.term_row()],
            [self.shape_parameters()],
            [np.zeros(self.size) if coefficients is None else coefficients],
            [np.eye(n_joints)[self.joint] if reach is None else reach],
        )

    @property
    def size(self) -> int:
        """Number of basis functions."""
        per_direction = 2 if self.modulation == "both" else 1
        return per_direction * (2 if self.shape == "periodic" else 1) * self.shape_count

    @property
    def kind(self) -> str:
        """Short name of the effect family, as reported by ``residual``."""
        if self.shape == "constant":
            return "direction-dependent offset" if self.modulation != "none" else "offset"
        if self.shape == "stribeck":
            return "stribeck friction"
        variable = self.effect_variable.kind if self.effect_variable is not None else None
        if variable == VariableKind.TIME:
            return "friction drift" if self.modulation != "none" else "torque drift"
        if variable == VariableKind.LOAD:
            return "load-dependent friction"
        if variable == VariableKind.VELOCITY:
            return "cross-joint coupling"
        if self.modulation == "both":
            return "position-dependent torque, direction-dependent part"
        if self.modulation != "none":
            return "position-dependent friction"
        if self.shape == "periodic":
            return "position-periodic torque"
        return "position-dependent torque"

    def depends_on(self) -> list[str]:
        """Variables the effect depends on (the ``depends_on`` field of the report)."""
        names: list[str] = []
        if self.effect_variable is not None:
            names += self.effect_variable.names()
        if self.modulation != "none":
            names.append(f"qd{self.joint + 1}")
        return list(dict.fromkeys(names))

    def describe(self) -> str:
        """One readable line."""
        var = "1" if self.shape == "constant" else self.variable
        mod = {
            "none": "",
            "sign": f" x sgn(qd{self.joint + 1})",
            "positive": f" x [qd{self.joint + 1} > 0]",
            "both": f" x (1, sgn(qd{self.joint + 1}))",
        }
        return f"joint {self.joint + 1}: {self.shape}({var}){mod[self.modulation]}"

    def basis(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Basis functions at every sample (N x size), compiled (``effect_terms``)."""
        q = _samples(q)
        table = self.table(q.shape[1])
        return effect_basis(
            table.codes[0], table.floats, _since_start(t_s), q, _samples(qd), _samples(tau)
        )


class FoundEffect:
    """An effect with identified coefficients: ``tau_joint = basis @ coefficients``.

    ``reach``: where the torque lands, one weight per motor joint (None: on :attr:`joint`
    alone). An effect acting at a *model* joint ``k`` of a coupled robot reaches the motors
    through the coupling like any model torque, ``tau_motor = T^T e_k tau``: its reach is row
    ``k`` of ``T`` (scaled so that the weight on :attr:`joint` is 1), e.g. a cable spring at the
    dVRK MTM's wrist platform loads joints 2 and 3 with the cable's ratio.
    """

    def __init__(
        self,
        spec: BasisSpec,
        coefficients: np.ndarray,
        explained: float = 0.0,
        reach: np.ndarray | None = None,
    ) -> None:
        """Bind a basis to its coefficients (``explained``: held-out variance fraction)."""
        coefficients = np.asarray(coefficients, dtype=float).reshape(-1)
        if coefficients.shape != (spec.size,):
            raise ModelError(f"effect {spec.describe()} needs {spec.size} coefficients")
        if reach is not None:
            reach = np.asarray(reach, dtype=float).reshape(-1)
            if reach.size <= spec.joint or not np.all(np.isfinite(reach)):
                raise ModelError(
                    f"effect {spec.describe()}: reach needs a finite weight per joint"
                    f" (at least {spec.joint + 1}), got {reach.tolist()}"
                )
        self.spec = spec
        self.coefficients = coefficients
        self.explained = float(explained)
        self.reach = reach

    @property
    def joint(self) -> int:
        """Joint the effect was found on (0-based)."""
        return self.spec.joint

    def weights(self, n_joints: int) -> np.ndarray:
        """Motor torque per unit of the effect's torque (``n_joints``,)."""
        if self.reach is None:
            return np.eye(n_joints)[self.spec.joint]
        if self.reach.size != n_joints:
            raise ModelError(
                f"effect {self.spec.describe()} reaches {self.reach.size} joints, not {n_joints}"
            )
        return self.reach

    def torque(self, t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Torque on all joints (N x n): on :attr:`joint`, or spread by :attr:`reach`."""
        q = _samples(q)
        table = self.table(q.shape[1])
        return effects_torque(
            table.codes, table.floats, _since_start(t_s), q, _samples(qd), _samples(tau)
        )

    def table(self, n_joints: int) -> EffectTable:
        """Encode the effect for the compiled terms (coefficients and reach included)."""
        return self.spec.table(n_joints, self.coefficients, self.weights(n_joints))

    def to_dict(self) -> dict[str, Any]:
        """Serialise."""
        spec = asdict(self.spec)
        spec["scales"] = list(self.spec.scales)
        out = {
            "kind": "basis",
            "spec": spec,
            "coefficients": self.coefficients.tolist(),
            "explained": self.explained,
        }
        if self.reach is not None:
            out["reach"] = self.reach.tolist()
        return out


def effects_table(effects: Sequence[FoundEffect], n_joints: int) -> EffectTable:
    """All ``effects`` encoded in one table, for one compiled call per sample."""
    for effect in effects:
        effect.spec.check_joints(n_joints)
    return EffectTable.build(
        [effect.spec.term_row() for effect in effects],
        [effect.spec.shape_parameters() for effect in effects],
        [effect.coefficients for effect in effects],
        [effect.weights(n_joints) for effect in effects],
    )


def total_torque(
    effects: Sequence[FoundEffect], t_s: np.ndarray, q: np.ndarray, qd: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Torque of all ``effects`` on all joints (N x n), in one compiled call."""
    q = _samples(q)
    table = effects_table(effects, q.shape[1])
    return effects_torque(
        table.codes, table.floats, _since_start(t_s), q, _samples(qd), _samples(tau)
    )


def describe_reach(joint: int, reach: Sequence[float] | None) -> str:
    """Where an effect acts, for reports: ``joint 4`` or ``j2 +0.6697, j3 -0.6697, j4 +1``.

    ``joint`` is 1-based (as in the residual JSON); ``reach`` the motor weights or None.
    """
    if reach is None:
        return f"joint {joint}"
    return ", ".join(f"j{i + 1} {w:+.4g}" for i, w in enumerate(reach) if w != 0.0)


class BasisSpecEntry(Struct, forbid_unknown_fields=True):
    """An effect's :class:`BasisSpec`; keys left out take the BasisSpec's defaults."""

    joint: JointIndex
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


def effect_from_dict(data: dict[str, Any]) -> FoundEffect:
    """Rebuild an effect from :meth:`FoundEffect.to_dict`; ModelFileError names a bad field."""
    entry = read_entry(data, EffectEntry)
    reach = None if entry.reach is None else np.array(entry.reach)
    return FoundEffect(entry.spec.spec(), np.array(entry.coefficients), entry.explained, reach)
