"""The found effects' terms, each defined once (numba): variables, shapes, modulations.

An effect is a variable ``x`` (:class:`EffectVariable`: ``t``, ``q2``, ``q2-q3``, ``qd1``,
``tau3``), a fixed shape of it (:class:`EffectShape`) and a modulation by the direction of
its joint's velocity (:class:`EffectModulation`). The compiled functions take an effect
encoded as a row of integer codes (:data:`CODE_COLUMNS`) and a float array (its shape
parameters, coefficients and reach), so the batch basis of
:class:`~teleop_force.identification.effects.BasisSpec`, the batch torque of
:class:`~teleop_force.identification.effects.FoundEffect` and the streaming estimator (one
call for all effects at a sample, :func:`add_effects_torque_into`) evaluate the same code.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.errors import ModelError
from teleop_force.friction.terms import add_weighted_into, sign


class EffectShape(StrEnum):
    """Fixed shape of an effect's variable (the model-file strings)."""

    CONSTANT = "constant"
    LINEAR = "linear"
    SMOOTH = "smooth"
    PERIODIC = "periodic"
    ABS = "abs"
    STRIBECK = "stribeck"


class EffectModulation(StrEnum):
    """How the shape is modulated by the direction of the effect joint's velocity."""

    NONE = "none"
    SIGN = "sign"
    POSITIVE = "positive"
    BOTH = "both"


class VariableKind(StrEnum):
    """What an effect variable reads."""

    TIME = "t"
    ANGLE = "q"
    ANGLE_DIFFERENCE = "q-q"
    VELOCITY = "qd"
    LOAD = "tau"


# integer codes of the compiled functions (numba reads module integers as constants)
_T, _Q, _QQ, _QD, _TAU = 0, 1, 2, 3, 4
_CONSTANT, _LINEAR, _SMOOTH, _PERIODIC, _ABS, _STRIBECK = 0, 1, 2, 3, 4, 5
_NONE, _SIGN, _POSITIVE, _BOTH = 0, 1, 2, 3
VARIABLE_CODES = {
    VariableKind.TIME: _T,
    VariableKind.ANGLE: _Q,
    VariableKind.ANGLE_DIFFERENCE: _QQ,
    VariableKind.VELOCITY: _QD,
    VariableKind.LOAD: _TAU,
}
SHAPE_CODES = {
    EffectShape.CONSTANT: _CONSTANT,
    EffectShape.LINEAR: _LINEAR,
    EffectShape.SMOOTH: _SMOOTH,
    EffectShape.PERIODIC: _PERIODIC,
    EffectShape.ABS: _ABS,
    EffectShape.STRIBECK: _STRIBECK,
}
MODULATION_CODES = {
    EffectModulation.NONE: _NONE,
    EffectModulation.SIGN: _SIGN,
    EffectModulation.POSITIVE: _POSITIVE,
    EffectModulation.BOTH: _BOTH,
}

#: Columns of an effect's code row.
CODE_COLUMNS = (
    "variable", "first", "second", "shape", "modulation", "joint", "count",
    "parameters", "coefficients", "size", "reach",
)  # fmt: skip
_VAR, _FIRST, _SECOND, _SHAPE, _MOD, _JOINT, _COUNT, _PARAMS, _COEFS, _SIZE, _REACH = range(11)

_VARIABLE = re.compile(r"^(t|q(\d+)-q(\d+)|q(\d+)|qd(\d+)|tau(\d+))$")


@dataclass(frozen=True)
class EffectVariable:
    """An effect variable, parsed: what it reads and which joints (0-based; -1 unused).

    ``str()`` gives the model-file spelling back (``q2``, ``q2-q3``, ``qd1``, ``tau3``, ``t``).
    """

    kind: VariableKind
    first: int = -1
    second: int = -1

    def __post_init__(self) -> None:
        needed = {VariableKind.TIME: 0, VariableKind.ANGLE_DIFFERENCE: 2}.get(self.kind, 1)
        used = [i for i in (self.first, self.second) if i != -1]
        if len(used) != needed or any(i < 0 for i in used) or (needed == 1 and self.second != -1):
            raise ModelError(f"effect variable {self.kind.value} needs {needed} joint(s) >= 0")

    @classmethod
    def parse(cls, name: str) -> EffectVariable:
        """Parse ``t``, ``q<j>``, ``q<a>-q<b>``, ``qd<j>`` or ``tau<j>`` (1-based joints)."""
        match = _VARIABLE.match(name) if isinstance(name, str) else None
        if match is None:
            raise ModelError(f"unknown effect variable {name!r}")
        groups = match.groups()
        if name == "t":
            return cls(VariableKind.TIME)
        if groups[1] is not None:
            return cls(VariableKind.ANGLE_DIFFERENCE, int(groups[1]) - 1, int(groups[2]) - 1)
        if groups[3] is not None:
            return cls(VariableKind.ANGLE, int(groups[3]) - 1)
        if groups[4] is not None:
            return cls(VariableKind.VELOCITY, int(groups[4]) - 1)
        return cls(VariableKind.LOAD, int(groups[5]) - 1)

    @property
    def joints(self) -> tuple[int, ...]:
        """Joints read (0-based)."""
        return tuple(i for i in (self.first, self.second) if i >= 0)

    def names(self) -> list[str]:
        """Return the single variables it reads (``q2-q3`` -> ``q2``, ``q3``)."""
        return str(self).split("-") if self.kind is VariableKind.ANGLE_DIFFERENCE else [str(self)]

    def __str__(self) -> str:
        """Return the model-file spelling."""
        if self.kind is VariableKind.TIME:
            return "t"
        if self.kind is VariableKind.ANGLE_DIFFERENCE:
            return f"q{self.first + 1}-q{self.second + 1}"
        return f"{self.kind.value}{self.first + 1}"

    def check_joints(self, n_joints: int) -> None:
        """Raise ModelError if the variable reads a joint outside ``1..n_joints``."""
        if any(not 0 <= i < n_joints for i in self.joints):
            raise ModelError(f"effect variable {str(self)!r} names a joint outside 1..{n_joints}")


# -- the compiled terms ------------------------------------------------------------------------


@njit_cached()
def variable_value(
    kind: int, first: int, second: int, t: float, q: np.ndarray, qd: np.ndarray, tau: np.ndarray
) -> float:  # pragma: no cover - compiled
    """Value of an effect variable at one sample (``t``: time since the first sample)."""
    if kind == _T:
        return t
    if kind == _QQ:
        return q[first] - q[second]
    if kind == _Q:
        return q[first]
    if kind == _QD:
        return qd[first]
    return tau[first]


@njit_cached()
def shape_basis_into(
    shape: int, x: float, count: int, parameters: np.ndarray, out: np.ndarray, at: int
) -> int:  # pragma: no cover - compiled
    """Write the shape's basis functions of ``x`` to ``out[at:]``; return how many.

    ``constant``: 1; ``linear``: x; ``abs``: |x|; ``smooth``: ``count`` Gaussian bumps
    ``exp(-((x - c_i) / w)^2 / 2)`` centred evenly over ``[lo, hi] = parameters[:2]``,
    ``w = (hi - lo) / (count - 1)``; ``periodic``: ``sin(x k f)`` then ``cos(x k f)``,
    ``k = 1..count``, ``f = parameters[0]``; ``stribeck``: ``exp(-(x / v_i)^2)`` for the
    ``count`` scales ``v_i = parameters[i]``.
    """
    if shape == _CONSTANT:
        out[at] = 1.0
        return 1
    if shape == _LINEAR:
        out[at] = x
        return 1
    if shape == _ABS:
        out[at] = abs(x)
        return 1
    if shape == _SMOOTH:
        lo = parameters[0]
        hi = parameters[1]
        width = (hi - lo) / (count - 1)
        for i in range(count):
            centre = hi if i == count - 1 else lo + i * width
            u = (x - centre) / width
            out[at + i] = math.exp(-0.5 * u * u)
        return count
    if shape == _PERIODIC:
        frequency = parameters[0]
        for i in range(count):
            phase = x * ((i + 1) * frequency)
            out[at + i] = math.sin(phase)
            out[at + count + i] = math.cos(phase)
        return 2 * count
    if shape == _STRIBECK:
        for i in range(count):
            u = x / parameters[i]
            out[at + i] = math.exp(-(u * u))
        return count
    for i in range(count):  # an unknown shape code: NaN, never another shape's values
        out[at + i] = math.nan
    return count


@njit_cached()
def effect_basis_into(
    codes: np.ndarray,
    floats: np.ndarray,
    t: float,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
    direction_scale: float,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Write one effect's basis at one sample to ``out[:size]``; return ``size``.

    ``codes`` is the effect's code row (:data:`CODE_COLUMNS`), ``floats`` the array its
    shape parameters start in. Modulation: ``sign`` multiplies by ``sgn(qd_joint)``,
    ``positive`` by ``[qd_joint > 0]``, ``both`` appends the basis times ``sgn(qd_joint)``;
    each direction factor is times ``direction_scale`` (1 when fitting; the estimator's
    standstill ramp, :func:`~teleop_force.friction.terms.standstill_factor`: at rest the
    direction, like the Coulomb term's sign, is unknown).
    """
    shape = codes[_SHAPE]
    x = 0.0
    if shape != _CONSTANT:
        x = variable_value(codes[_VAR], codes[_FIRST], codes[_SECOND], t, q, qd, tau)
    size = shape_basis_into(shape, x, codes[_COUNT], floats[codes[_PARAMS] :], out, 0)
    modulation = codes[_MOD]
    if modulation == _NONE:
        return size
    v = qd[codes[_JOINT]]
    if modulation == _BOTH:
        s = sign(v) * direction_scale
        for i in range(size):
            out[size + i] = out[i] * s
        return 2 * size
    factor = (sign(v) if modulation == _SIGN else (1.0 if v > 0.0 else 0.0)) * direction_scale
    for i in range(size):
        out[i] *= factor
    return size


@njit_cached()
def effect_torque(
    codes: np.ndarray,
    floats: np.ndarray,
    t: float,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
    direction_scale: float,
    work: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """One effect's torque ``basis @ coefficients`` at one sample (``work``: >= size floats).

    ``direction_scale``: as :func:`effect_basis_into`'s.
    """
    size = effect_basis_into(codes, floats, t, q, qd, tau, direction_scale, work)
    start = codes[_COEFS]
    total = 0.0
    for i in range(size):
        total += work[i] * floats[start + i]
    return total


@njit_cached()
def add_effects_torque_into(
    codes: np.ndarray,
    floats: np.ndarray,
    t: float,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
    direction_scale: float,
    work: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Add every effect's torque at one sample to ``out`` (n,), spread by its reach.

    ``codes`` (E, 11) holds one code row per effect; their reach (n weights) starts at
    ``floats[codes[e, reach]]``. ``direction_scale``: as :func:`effect_basis_into`'s.
    """
    n = out.size
    for e in range(codes.shape[0]):
        row = codes[e]
        value = effect_torque(row, floats, t, q, qd, tau, direction_scale, work)
        reach = row[_REACH]
        add_weighted_into(value, floats[reach : reach + n], out)


@njit_cached()
def effect_basis(
    codes: np.ndarray,
    floats: np.ndarray,
    t: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """One effect's basis at every sample (``t`` since the first sample): (N, size)."""
    size = codes[_SIZE]
    out = np.empty((q.shape[0], size))
    for k in range(q.shape[0]):
        effect_basis_into(codes, floats, t[k], q[k], qd[k], tau[k], 1.0, out[k])
    return out


@njit_cached()
def effects_torque(
    codes: np.ndarray,
    floats: np.ndarray,
    t: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Torque of the effects at every sample (``t`` since the first sample): (N, n)."""
    largest = 1
    for e in range(codes.shape[0]):
        largest = max(largest, codes[e, _SIZE])
    work = np.empty(largest)
    out = np.zeros(q.shape)
    for k in range(q.shape[0]):
        add_effects_torque_into(codes, floats, t[k], q[k], qd[k], tau[k], 1.0, work, out[k])
    return out


@dataclass(frozen=True)
class EffectTable:
    """Effects encoded for the compiled terms: ``codes`` (E, 11) int64 and ``floats``.

    ``work`` is a scratch array as long as the largest basis (for one-sample calls).
    """

    codes: np.ndarray
    floats: np.ndarray
    work: np.ndarray

    @classmethod
    def build(
        cls,
        rows: list[tuple[EffectVariable | None, EffectShape, EffectModulation, int, int, int]],
        parameters: list[np.ndarray],
        coefficients: list[np.ndarray],
        reaches: list[np.ndarray],
    ) -> EffectTable:
        """Encode effects.

        Per effect: ``(variable, shape, modulation, joint, count, size)``, its shape
        parameters, coefficients (``size``) and reach (n weights).
        """
        codes = np.zeros((len(rows), len(CODE_COLUMNS)), dtype=np.int64)
        chunks: list[np.ndarray] = []
        offset = 0
        for e, (variable, shape, modulation, joint, count, size) in enumerate(rows):
            if variable is None:
                kind, first, second = _T, -1, -1
            else:
                kind, first, second = VARIABLE_CODES[variable.kind], variable.first, variable.second
            codes[e, :_PARAMS] = (
                kind, first, second, SHAPE_CODES[shape], MODULATION_CODES[modulation], joint, count
            )  # fmt: skip
            for column, values in (
                (_PARAMS, parameters[e]), (_COEFS, coefficients[e]), (_REACH, reaches[e])
            ):  # fmt: skip
                codes[e, column] = offset
                chunk = np.asarray(values, dtype=float).reshape(-1)
                chunks.append(chunk)
                offset += chunk.size
            codes[e, _SIZE] = size
        floats = np.concatenate(chunks) if chunks else np.zeros(0)
        largest = int(codes[:, _SIZE].max()) if rows else 1
        return cls(codes, np.ascontiguousarray(floats), np.zeros(max(1, largest)))


@njit_cached()
def variable_values_batch(
    kind: int,
    first: int,
    second: int,
    t: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    tau: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`variable_value` at every sample (``t`` since the first sample): (N,)."""
    out = np.empty(q.shape[0])
    for k in range(q.shape[0]):
        out[k] = variable_value(kind, first, second, t[k], q[k], qd[k], tau[k])
    return out
