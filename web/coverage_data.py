"""Where the friction network was trained, read from the model JSON the service returns.

The model JSON is :meth:`teleop_force.identification.dynamic_model.DynamicModel.to_dict`; its
``friction``
entry, for a wavelet network (``kind == "wn"``), holds per joint the input set, the velocity
region ``X_r``, the active wavelets ``[m, n...]`` (centre ``a0^m n b0``) and a ``coverage``
map (occupancy counts per grid cell, see :mod:`teleop_force.friction.coverage`).

Everything here tolerates missing or partial data: a model without a network or without a
coverage map gives a :class:`CoverageInfo` that says so instead of raising.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

#: The Omni's coupled networks read (qd2, qd3); joint 1's reads qd1 (0-based indices).
PLANE_INPUTS: Final = (1, 2)
LINE_INPUTS: Final = (0,)
#: Narrowest trust ramp [samples per cell] (model files cannot hold a narrower one).
_MIN_RAMP: Final = 1e-12


@dataclass(frozen=True)
class AxisCoverage:
    """Coverage of one network input set (1-D line or 2-D plane).

    Attributes:
        lo, hi: Velocity region ``X_r`` per input [rad/s].
        trust: Trust in [0, 1] per cell, indexed ``[input0, input1]`` (``None`` if the model
            has no coverage map).
        samples: Training samples counted in the region.
        centres: Active wavelet centres per joint using this input set, ``{joint: (K, d)}``.

    """

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    trust: np.ndarray | None
    samples: float
    centres: Mapping[int, np.ndarray]


@dataclass(frozen=True)
class CoverageInfo:
    """What the dashboard draws under the live trajectories."""

    friction_kind: str
    plane: AxisCoverage | None
    line: AxisCoverage | None
    message: str


def unwrap_model(reply: Any) -> Mapping[str, Any] | None:
    """Return the model dict from a service reply (the model itself or ``{"model": ...}``)."""
    if not isinstance(reply, Mapping):
        return None
    if "friction" in reply:
        return reply
    inner = reply.get("model")
    if isinstance(inner, Mapping) and "friction" in inner:
        return inner
    return None


def _trust_from_counts(counts: np.ndarray, config: Mapping[str, Any]) -> np.ndarray:
    """Trust per cell as :class:`~teleop_force.friction.coverage.CoverageMap` computes it.

    Missing settings take :class:`~teleop_force.friction.coverage.CoverageConfig`'s defaults.
    """
    # imported here: numba and scipy would add a second to the dashboard's start
    from teleop_force.friction.coverage import CoverageConfig, density_trust, smoothed_density

    defaults = CoverageConfig()
    sigma = float(config.get("smoothing_cells", defaults.smoothing_cells))
    lo = float(config.get("untrained_density", defaults.untrained_density))
    hi = float(config.get("trained_density", defaults.trained_density))
    return density_trust(smoothed_density(counts, sigma), lo, max(hi, lo + _MIN_RAMP))


def _grid_counts(grid: Mapping[str, Any], d: int) -> np.ndarray:
    counts = np.asarray(grid["counts"], dtype=float).reshape(-1)
    if d == 1:
        return counts
    side = round(counts.size ** (1.0 / d))
    if side**d != counts.size:
        raise ValueError(f"{counts.size} counts do not form a {d}-D square grid")
    return counts.reshape((side,) * d)


def _centres(entry: Mapping[str, Any], a0: float, b0: float, d: int) -> np.ndarray:
    active = np.asarray(entry.get("active", []), dtype=float).reshape(-1, 1 + d)
    return (a0 ** active[:, :1]) * active[:, 1:] * b0


def _axis(
    friction: Mapping[str, Any], inputs: Sequence[int]
) -> tuple[AxisCoverage | None, str | None]:
    joints = friction.get("joints") or []
    a0 = float(friction.get("a0", 2.0))
    b0 = float(friction.get("b0", 1.0))
    want = list(inputs)
    d = len(want)
    centres: dict[int, np.ndarray] = {}
    lo: tuple[float, ...] | None = None
    hi: tuple[float, ...] | None = None
    for j, entry in enumerate(joints):
        if not isinstance(entry, Mapping) or list(entry.get("inputs", [])) != want:
            continue
        centres[j] = _centres(entry, a0, b0, d)
        if lo is None:
            lo = tuple(float(v) for v in entry["x_min_rad_s"])
            hi = tuple(float(v) for v in entry["x_max_rad_s"])
    trust, samples, note = None, 0.0, None
    coverage = friction.get("coverage")
    if isinstance(coverage, Mapping):
        config = coverage.get("config") or {}
        for grid in coverage.get("grids") or []:
            if list(grid.get("inputs", [])) != want:
                continue
            counts = _grid_counts(grid, d)
            trust = _trust_from_counts(counts, config)
            samples = float(counts.sum())
            lo = tuple(float(v) for v in grid["x_min_rad_s"])
            hi = tuple(float(v) for v in grid["x_max_rad_s"])
            break
    else:
        note = "model has no coverage map"
    if lo is None or hi is None:
        return None, note
    return AxisCoverage(lo, hi, trust, samples, centres), note


def coverage_from_model(model: Mapping[str, Any] | None) -> CoverageInfo:
    """Extract the (qd2, qd3) plane and the qd1 line coverage from a model dict."""
    if model is None:
        return CoverageInfo("none", None, None, "no model from the service yet")
    friction = model.get("friction")
    if not isinstance(friction, Mapping):
        return CoverageInfo("none", None, None, "model has no friction entry")
    kind = str(friction.get("kind", "?"))
    if kind != "wn":
        return CoverageInfo(kind, None, None, f"friction model '{kind}' has no training map")
    try:
        plane, note_plane = _axis(friction, PLANE_INPUTS)
        line, note_line = _axis(friction, LINE_INPUTS)
    except (KeyError, TypeError, ValueError) as exc:
        return CoverageInfo(kind, None, None, f"cannot read the network's coverage: {exc}")
    notes = [n for n in (note_plane, note_line) if n]
    message = notes[0] if notes else ""
    if plane is not None and plane.trust is not None:
        message = message or f"{plane.samples:.0f} training samples in the qd2-qd3 region"
    return CoverageInfo(kind, plane, line, message)


def trust_at(axis: AxisCoverage, points: np.ndarray) -> np.ndarray:
    """Nearest-cell trust of ``axis`` at velocity ``points`` (N, d); 0 outside the grid."""
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    if axis.trust is None:
        return np.ones(pts.shape[0])
    shape = np.asarray(axis.trust.shape)
    lo, hi = np.asarray(axis.lo), np.asarray(axis.hi)
    finite = np.all(np.isfinite(pts), axis=1)
    scaled = np.where(finite[:, None], (pts - lo) / ((hi - lo) / shape), -1.0)
    cell = np.floor(np.clip(scaled, -1.0, shape)).astype(np.int64)
    inside = np.all((cell >= 0) & (cell < shape), axis=1)
    out = np.zeros(pts.shape[0])
    if np.any(inside):
        out[inside] = axis.trust[tuple(cell[inside].T)]
    return out


def finite_or(value: Any, default: float) -> float:
    """``value`` as a finite float, else ``default``."""
    try:
        result = float(value)
    except (TypeError, ValueError):
        return default
    return result if math.isfinite(result) else default


__all__ = [
    "LINE_INPUTS",
    "PLANE_INPUTS",
    "AxisCoverage",
    "CoverageInfo",
    "coverage_from_model",
    "finite_or",
    "trust_at",
    "unwrap_model",
]


def compile_kernels(model_path: Path | None = None) -> None:
    """Compile (or load) the coverage map's kernel (``teleop_force.process.warm_up``)."""
    _trust_from_counts(np.zeros(4), {})
