"""Single-sample kernels of the streaming estimator: the model's terms at one velocity sample.

At 1 kHz the estimator evaluates every term of the model on *one* sample. NumPy's per-call
overhead (~1 µs) then dominates arrays of three values, so these kernels take and return
plain Python floats. Each computes exactly what its batch counterpart computes on a one-row
array (same formulas, same operation order where it matters) and is checked against it in
``tests/estimation/test_estimation_kernels.py``:

* :class:`CoverageLookup`: :meth:`CoverageMap.trust` (multilinear interpolation of the
  smoothed density between cell centres, zero one cell outside, smoothstep ramp);
* :func:`linear_friction_kernel`: :meth:`CoulombViscous.torque` and
  :meth:`CoupledCoulombViscous.torque`;
* :func:`effect_kernel`: :meth:`FoundEffect.torque` for the shapes of
  :data:`teleop_force.identification.effects.SHAPES`.

Anything they do not know (another friction or effect class) is evaluated by its own
vectorised method on a one-row array, so the estimator stays correct for every model.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence

import numpy as np

from teleop_force.friction.base import FrictionModel
from teleop_force.friction.coulomb_viscous import CoulombViscous, CoupledCoulombViscous
from teleop_force.friction.coverage import CoverageMap
from teleop_force.identification.effects import BasisSpec, FoundEffect

#: ``f(qd) -> torque per joint`` on Python floats.
FrictionKernel = Callable[[Sequence[float]], list[float]]
#: ``f(t, q, qd, tau) -> torque on the effect's joint`` on Python floats.
EffectKernel = Callable[[float, Sequence[float], Sequence[float], Sequence[float]], float]

_VARIABLE = re.compile(r"^(t|q(\d+)-q(\d+)|q(\d+)|qd(\d+)|tau(\d+))$")


def _sign(x: float) -> float:
    """``np.sign`` of a finite float."""
    return float((x > 0.0) - (x < 0.0))


class CoverageLookup:
    """:meth:`CoverageMap.trust` of every joint at one velocity sample, in Python floats.

    ``map_coordinates(order=1, mode="grid-constant", cval=0)`` of the smoothed density:
    multilinear between the cell centres, zeros outside the grid. Joints whose grids are the
    same (the Omni's joints 2 and 3 share their inputs, region and counts) are computed once.
    """

    def __init__(self, coverage: CoverageMap) -> None:
        """Read the grids' geometry (bounds, cells) of ``coverage``; counts are read live."""
        self.coverage = coverage
        grids = coverage.to_dict()["grids"]
        self._geometry: list[tuple[tuple[int, ...], list[float], list[float], tuple[int, ...]]] = []
        for j, grid in enumerate(grids):
            shape = tuple(int(s) for s in coverage.grid_shape(j))
            lo = np.asarray(grid["x_min_rad_s"], dtype=float)
            hi = np.asarray(grid["x_max_rad_s"], dtype=float)
            inputs = tuple(int(i) for i in grid["inputs"])
            cell = (hi - lo) / np.asarray(shape)
            self._geometry.append((inputs, lo.tolist(), cell.tolist(), shape))
        self.n = len(grids)
        config = coverage.config
        self._ramp_lo = float(config.untrained_density)
        self._ramp_span = float(config.trained_density) - self._ramp_lo
        self._seen: list[np.ndarray | None] = [None] * self.n
        self._values: list[list[float]] = [[] for _ in range(self.n)]
        self._alias: list[int] = list(range(self.n))

    def _reload(self) -> None:
        """Re-read the density grids and find the joints that share one."""
        for j in range(self.n):
            grid = self.coverage.density_grid(j)
            self._seen[j] = grid
            self._values[j] = grid.reshape(-1).tolist()
        self._alias = list(range(self.n))
        for j in range(self.n):
            for i in range(j):
                if self._geometry[i] == self._geometry[j] and self._values[i] == self._values[j]:
                    self._alias[j] = i
                    break

    def density(self, qd: Sequence[float], joint: int) -> float:
        """Smoothed samples per cell at ``qd`` for ``joint`` (``CoverageMap.density``)."""
        if any(self.coverage.density_grid(j) is not self._seen[j] for j in range(self.n)):
            self._reload()
        return self._density(qd, joint)

    def _density(self, qd: Sequence[float], joint: int) -> float:
        values = self._values[joint]
        inputs, lo, cell, shape = self._geometry[joint]
        if len(inputs) == 1:
            c = (qd[inputs[0]] - lo[0]) / cell[0] - 0.5
            base = math.floor(c)
            frac = c - base
            size = shape[0]
            total = 0.0
            if 0 <= base < size:
                total += (1.0 - frac) * values[base]
            if 0 <= base + 1 < size:
                total += frac * values[base + 1]
            return total if total > 0.0 else 0.0
        if len(inputs) == 2:
            cx = (qd[inputs[0]] - lo[0]) / cell[0] - 0.5
            cy = (qd[inputs[1]] - lo[1]) / cell[1] - 0.5
            bx, by = math.floor(cx), math.floor(cy)
            fx, fy = cx - bx, cy - by
            nx, ny = shape
            if bx >= 0 and bx + 1 < nx and by >= 0 and by + 1 < ny:  # inside: four corners
                row = bx * ny + by
                gx = 1.0 - fx
                total = (1.0 - fy) * (gx * values[row] + fx * values[row + ny]) + fy * (
                    gx * values[row + 1] + fx * values[row + ny + 1]
                )
                return total if total > 0.0 else 0.0
            total = 0.0
            y_in, y1_in = 0 <= by < ny, 0 <= by + 1 < ny
            for i, wx in ((bx, 1.0 - fx), (bx + 1, fx)):
                if 0 <= i < nx:
                    row = i * ny + by
                    if y_in:
                        total += wx * (1.0 - fy) * values[row]
                    if y1_in:
                        total += wx * fy * values[row + 1]
            return total if total > 0.0 else 0.0
        corners: list[tuple[int, float]] = [(0, 1.0)]
        for axis, i in enumerate(inputs):
            c = (qd[i] - lo[axis]) / cell[axis] - 0.5
            base = math.floor(c)
            frac = c - base
            size = shape[axis]
            corners = [
                (index * size + k, weight * w)
                for index, weight in corners
                for k, w in ((base, 1.0 - frac), (base + 1, frac))
                if 0 <= k < size
            ]
        total = sum(weight * values[index] for index, weight in corners)
        return total if total > 0.0 else 0.0

    def trust(self, qd: Sequence[float]) -> list[float]:
        """Trust weight in [0, 1] of every joint at ``qd`` (``CoverageMap.trust``)."""
        seen = self._seen
        grid_of = self.coverage.density_grid
        for j in range(self.n):
            if grid_of(j) is not seen[j]:
                self._reload()
                break
        out: list[float] = []
        ramp_lo, span = self._ramp_lo, self._ramp_span
        for j, alias in enumerate(self._alias):
            if alias != j:
                out.append(out[alias])
                continue
            s = (self._density(qd, j) - ramp_lo) / span
            s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
            out.append(s * s * (3.0 - 2.0 * s))
        return out


def linear_friction_kernel(friction: FrictionModel) -> FrictionKernel | None:
    """Return a float kernel of a (coupled) Coulomb-viscous model; ``None`` for other models.

    The kernel reads the model's parameters at every call, so it follows later changes.
    """
    if type(friction) is CoulombViscous:
        pairs: tuple[tuple[tuple[int, int], ...], ...] = ((),) * friction.n_joints
    elif type(friction) is CoupledCoulombViscous:
        pairs = tuple(
            tuple((min(j, k), max(j, k)) for k in inputs if k != j)
            for j, inputs in enumerate(friction.friction_inputs)
        )
    else:
        return None
    n = friction.n_joints

    def torque(qd: Sequence[float]) -> list[float]:
        p = friction.parameters.tolist()
        out = []
        i = 0
        for j in range(n):
            v = qd[j]
            total = p[i] * _sign(v) + p[i + 1] * v
            i += 2
            for a, b in pairs[j]:
                rel = qd[a] - qd[b]
                total += p[i] * _sign(rel) + p[i + 1] * rel
                i += 2
            out.append(total)
        return out

    return torque


#: ``f(t, q, qd, tau) -> value`` on Python floats.
VariableReader = Callable[[float, Sequence[float], Sequence[float], Sequence[float]], float]


def _variable_reader(name: str) -> VariableReader:
    """Reader of an effect variable (``t`` is the time since the stream's first sample)."""
    match = _VARIABLE.match(name)
    if match is None:
        raise ValueError(f"unknown effect variable {name!r}")
    if name == "t":
        return lambda t, q, qd, tau: t
    if match.group(2) is not None:
        a, b = int(match.group(2)) - 1, int(match.group(3)) - 1
        return lambda t, q, qd, tau: q[a] - q[b]
    if match.group(4) is not None:
        i = int(match.group(4)) - 1
        return lambda t, q, qd, tau: q[i]
    if match.group(5) is not None:
        i = int(match.group(5)) - 1
        return lambda t, q, qd, tau: qd[i]
    i = int(match.group(6)) - 1
    return lambda t, q, qd, tau: tau[i]


def _shape_kernel(spec: BasisSpec, c: list[float]) -> Callable[[float], float]:
    """``BasisSpec.basis(x) @ c`` of one value ``x`` of the variable (before modulation)."""
    shape = spec.shape
    if shape == "constant":
        return lambda x: c[0]
    if shape == "linear":
        return lambda x: c[0] * x
    if shape == "abs":
        return lambda x: c[0] * abs(x)
    exp, sin, cos = math.exp, math.sin, math.cos
    if shape == "smooth":
        centres = np.linspace(spec.lo, spec.hi, spec.count).tolist()
        width = (spec.hi - spec.lo) / (spec.count - 1)
        pairs = list(zip(centres, c, strict=True))
        return lambda x: sum(w * exp(-0.5 * ((x - m) / width) ** 2) for m, w in pairs)
    if shape == "periodic":
        k = (np.arange(1, spec.harmonics + 1) * spec.frequency).tolist()
        terms = list(zip(k, c[: len(k)], c[len(k) :], strict=True))
        return lambda x: sum(a * sin(x * f) + b * cos(x * f) for f, a, b in terms)
    if shape == "stribeck":
        pairs = list(zip(spec.scales, c, strict=True))
        return lambda x: sum(w * exp(-((x / v) ** 2)) for v, w in pairs)
    raise ValueError(f"unknown effect shape {shape!r}")


def effect_kernel(effect: object, n_joints: int) -> tuple[int, EffectKernel] | None:
    """Return ``(joint, kernel)`` of a :class:`FoundEffect`; ``None`` for anything else.

    The kernel keeps the effect's coefficients as they are now (effects are not adapted).
    """
    if type(effect) is not FoundEffect:
        return None
    spec = effect.spec
    constant = spec.shape == "constant"
    coefficients = effect.coefficients.tolist()
    half = len(coefficients) // 2
    try:
        if spec.modulation == "both":  # the basis, then the basis times sgn(qd_joint)
            value = _shape_kernel(spec, coefficients[:half])
            signed = _shape_kernel(spec, coefficients[half:])
        else:
            value = _shape_kernel(spec, coefficients)
        read = (lambda t, q, qd, tau: 0.0) if constant else _variable_reader(spec.variable)
    except ValueError:
        return None
    if not constant:
        match = _VARIABLE.match(spec.variable)
        indices = [int(g) - 1 for g in (match.groups()[1:] if match else ()) if g is not None]
        if any(not 0 <= i < n_joints for i in indices):
            return None  # the vectorised path raises the model error
    joint = spec.joint
    Floats = Sequence[float]
    if spec.modulation == "sign":

        def torque(t: float, q: Floats, qd: Floats, tau: Floats) -> float:
            v = qd[joint]
            return value(read(t, q, qd, tau)) * ((v > 0.0) - (v < 0.0))

    elif spec.modulation == "positive":

        def torque(t: float, q: Floats, qd: Floats, tau: Floats) -> float:
            return value(read(t, q, qd, tau)) if qd[joint] > 0.0 else 0.0

    elif spec.modulation == "both":

        def torque(t: float, q: Floats, qd: Floats, tau: Floats) -> float:
            x = read(t, q, qd, tau)
            v = qd[joint]
            return value(x) + signed(x) * ((v > 0.0) - (v < 0.0))

    else:

        def torque(t: float, q: Floats, qd: Floats, tau: Floats) -> float:
            return value(read(t, q, qd, tau))

    return joint, torque


def linear_expression(row: Sequence[float], var: str) -> str:
    """Return the source of ``sum_j row[j] * var[j]`` over the non-zero entries (or ``0.0``)."""
    terms = []
    for j, v in enumerate(row):
        v = float(v)
        if v == 0.0:
            continue
        if v == 1.0:
            terms.append(f"{var}[{j}]")
        elif v == -1.0:
            terms.append(f"-{var}[{j}]")
        else:
            terms.append(f"{v!r} * {var}[{j}]")
    return " + ".join(terms).replace("+ -", "- ") if terms else "0.0"


def compile_linear_map(matrix: np.ndarray) -> Callable[[Sequence[float]], list[float]]:
    """``x -> (matrix @ x).tolist()`` as one unrolled Python expression (zeros skipped).

    For the small constant matrices of the streaming estimator (joint couplings): an
    unrolled list display costs a fraction of a NumPy call on three values.
    """
    rows = np.asarray(matrix, dtype=float)
    if rows.ndim != 2 or not np.all(np.isfinite(rows)):
        raise ValueError("compile_linear_map needs a finite 2-D matrix")
    body = ", ".join(linear_expression(row, "x") for row in rows)
    namespace: dict[str, object] = {}
    exec(f"def linear_map(x):\n    return [{body}]\n", namespace)
    return namespace["linear_map"]  # type: ignore[return-value]
