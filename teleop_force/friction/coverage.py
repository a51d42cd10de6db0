"""Where a friction network was trained: occupancy grids and a smooth trust weight.

A :class:`CoverageMap` keeps, for every joint, a ``d_j``-dimensional grid over that joint's
network input region ``X_r`` (velocities ``qd[S_j]``) counting the training samples that fell
in each cell (0.05 rad/s cells in 1-D, 40 cells per axis otherwise; samples outside ``X_r``
are not counted). The *trust* at a velocity is::

    density = (counts smoothed by a Gaussian of ``smoothing_cells`` cells), interpolated
              multilinearly between cell centres (falling to 0 one cell outside the grid)
    s       = clip((density - untrained_density) / (trained_density - untrained_density), 0, 1)
    trust   = 3 s^2 - 2 s^3      (smoothstep: continuous, monotone in density)

so it is 0 far from trained ground (the Gaussian is truncated at 4 sigma), 1 where at least
``trained_density`` samples per cell were seen, and continuous in between. The paper's
Experiment 3 (Fig. 4) is the motivation: a 2-D network is only as good as its training
covered the velocity plane.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
from msgspec import Meta, Struct

from teleop_force.errors import ConfigurationError, DataError, ModelFileError
from teleop_force.friction.base import JointIndex
from teleop_force.friction.terms import coverage_trust_values, grid_density_batch
from teleop_force.schema import Finite, read_entry

#: Most cells one joint's grid may have (a bad region or cell size cannot allocate gigabytes).
MAX_GRID_CELLS = 1_000_000
#: Widest smoothing, in cells (the Gaussian's cost grows with it: 1e6 took 90 s per grid).
MAX_SMOOTHING_CELLS = 50.0
#: A grid cell's sample count in a model file (non-negative, finite).
SampleCount = Annotated[float, Meta(ge=0.0, le=sys.float_info.max)]


@dataclass(frozen=True)
class CoverageConfig:
    """Grid resolution and trust ramp of a :class:`CoverageMap`.

    Attributes:
        cell_size_1d_rad_s: Cell width of 1-D grids [rad/s].
        cells_per_axis_nd: Cells per axis of grids with 2 or more inputs.
        smoothing_cells: Standard deviation of the Gaussian smoothing, in cells.
        untrained_density: Smoothed samples per cell at or below which trust is 0.
        trained_density: Smoothed samples per cell at or above which trust is 1.

    """

    cell_size_1d_rad_s: float = 0.05
    cells_per_axis_nd: int = 40
    smoothing_cells: float = 1.0
    untrained_density: float = 1.0
    trained_density: float = 20.0

    def __post_init__(self) -> None:
        for name in (
            "cell_size_1d_rad_s", "cells_per_axis_nd", "smoothing_cells", "untrained_density",
            "trained_density",
        ):  # fmt: skip
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.number):
                raise ConfigurationError(f"{name} must be a number, got {type(value).__name__}")
            try:
                finite = math.isfinite(value)
            except OverflowError:  # an int beyond float64
                finite = False
            if not finite:
                raise ConfigurationError(f"{name} must be finite and within float64")
        if not self.cell_size_1d_rad_s > 0.0:
            raise ConfigurationError("cell_size_1d_rad_s must be > 0")
        if int(self.cells_per_axis_nd) != self.cells_per_axis_nd or self.cells_per_axis_nd < 2:
            raise ConfigurationError("cells_per_axis_nd must be an integer >= 2")
        if not 0.0 <= self.smoothing_cells <= MAX_SMOOTHING_CELLS:
            raise ConfigurationError(f"smoothing_cells must be in 0..{MAX_SMOOTHING_CELLS}")
        if not 0.0 <= self.untrained_density < self.trained_density:
            raise ConfigurationError("need 0 <= untrained_density < trained_density")

    def to_dict(self) -> dict[str, Any]:
        """Serialise."""
        return {
            "cell_size_1d_rad_s": self.cell_size_1d_rad_s,
            "cells_per_axis_nd": int(self.cells_per_axis_nd),
            "smoothing_cells": self.smoothing_cells,
            "untrained_density": self.untrained_density,
            "trained_density": self.trained_density,
        }


def smoothed_density(counts: np.ndarray, smoothing_cells: float) -> np.ndarray:
    """Smooth a grid's samples per cell by a Gaussian of ``smoothing_cells`` cells (0: none)."""
    if smoothing_cells > 0:
        from scipy.ndimage import gaussian_filter  # lazy: scipy.ndimage is slow to import

        return gaussian_filter(counts, smoothing_cells, mode="constant")
    return counts


def density_trust(density: np.ndarray, untrained: float, trained: float) -> np.ndarray:
    """Trust of every entry of a smoothed density array, any shape (``terms.coverage_trust``)."""
    density = np.asarray(density, dtype=float)
    flat = np.ascontiguousarray(density).reshape(-1)
    return coverage_trust_values(flat, float(untrained), float(trained)).reshape(density.shape)


@dataclass(frozen=True)
class _Grid:
    """One joint's occupancy grid."""

    inputs: tuple[int, ...]
    lo: np.ndarray
    hi: np.ndarray
    shape: tuple[int, ...]

    @property
    def cell(self) -> np.ndarray:
        return (self.hi - self.lo) / np.asarray(self.shape)


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


class CoverageMap:
    """Per-joint occupancy grids of training velocities, with a smooth trust weight."""

    def __init__(
        self,
        inputs: Sequence[Sequence[int]],
        x_min_rad_s: Sequence[Sequence[float] | np.ndarray],
        x_max_rad_s: Sequence[Sequence[float] | np.ndarray],
        config: CoverageConfig | None = None,
        counts: Sequence[np.ndarray] | None = None,
    ) -> None:
        """Create empty grids (or with ``counts``) over each joint's region ``X_r``."""
        self.config = config if config is not None else CoverageConfig()
        if not len(inputs) == len(x_min_rad_s) == len(x_max_rad_s) or not inputs:
            raise ConfigurationError("coverage: need inputs and bounds for every joint")
        grids = []
        for s, lo, hi in zip(inputs, x_min_rad_s, x_max_rad_s, strict=True):
            lo_a = np.asarray(lo, dtype=float).reshape(-1)
            hi_a = np.asarray(hi, dtype=float).reshape(-1)
            s_t = tuple(int(v) for v in s)
            if lo_a.shape != (len(s_t),) or hi_a.shape != lo_a.shape or np.any(~(hi_a > lo_a)):
                raise ConfigurationError(f"coverage: bad region for inputs {s_t}")
            if not s_t or min(s_t) < 0 or len(set(s_t)) != len(s_t):
                raise ConfigurationError(f"coverage: bad input set {s_t}")
            if not np.all(np.isfinite(lo_a)) or not np.all(np.isfinite(hi_a)):
                raise ConfigurationError(f"coverage: region of inputs {s_t} must be finite")
            if len(s_t) == 1:
                cells = (hi_a[0] - lo_a[0]) / self.config.cell_size_1d_rad_s - 1e-9
                if not cells <= MAX_GRID_CELLS:
                    raise ConfigurationError(
                        f"coverage: {cells:.3g} cells for inputs {s_t} (at most {MAX_GRID_CELLS})"
                    )
                shape: tuple[int, ...] = (max(1, math.ceil(cells)),)
            else:
                shape = (int(self.config.cells_per_axis_nd),) * len(s_t)
                if float(self.config.cells_per_axis_nd) ** len(s_t) > MAX_GRID_CELLS:
                    raise ConfigurationError(
                        f"coverage: {shape} cells for inputs {s_t} (at most {MAX_GRID_CELLS})"
                    )
            grids.append(_Grid(s_t, lo_a, hi_a, shape))
        self._grids = tuple(grids)
        if counts is None:
            self._counts = [np.zeros(g.shape) for g in self._grids]
        else:
            self._counts = [
                np.asarray(c, dtype=float).reshape(g.shape)
                for c, g in zip(counts, self._grids, strict=True)
            ]
        self._density: list[np.ndarray | None] = [None] * len(self._grids)
        #: Incremented whenever the counts change (streaming users re-read the grids).
        self.version = 0

    @classmethod
    def for_inputs(
        cls,
        inputs: Sequence[Sequence[int]],
        x_min_rad_s: Sequence[Sequence[float]],
        x_max_rad_s: Sequence[Sequence[float]],
        config: CoverageConfig | None = None,
    ) -> CoverageMap:
        """Empty map over the given per-joint input sets and regions."""
        return cls(inputs, x_min_rad_s, x_max_rad_s, config)

    @property
    def n_joints(self) -> int:
        """Number of joints (grids)."""
        return len(self._grids)

    def grid_inputs(self, joint: int) -> tuple[int, ...]:
        """Velocities (0-based joint indices) ``joint``'s grid reads."""
        return self._grids[joint].inputs

    def grid_shape(self, joint: int) -> tuple[int, ...]:
        """Cells per axis of ``joint``'s grid."""
        return self._grids[joint].shape

    def counts(self, joint: int) -> np.ndarray:
        """Return the samples counted per cell of ``joint``'s grid (a copy)."""
        return self._counts[joint].copy()

    def total_samples(self, joint: int) -> float:
        """Return the number of samples counted inside ``joint``'s region."""
        return float(self._counts[joint].sum())

    def _check(self, qd: np.ndarray) -> np.ndarray:
        qd = np.atleast_2d(np.asarray(qd, dtype=float))
        needed = 1 + max(max(g.inputs) for g in self._grids)
        if qd.ndim != 2 or qd.shape[1] < needed:
            raise DataError(f"coverage: need velocities with >= {needed} columns, got {qd.shape}")
        return qd

    def add(self, qd: np.ndarray) -> None:
        """Count the training velocities ``qd`` (N x n) into every joint's grid."""
        qd = self._check(qd)
        for j, g in enumerate(self._grids):
            x = qd[:, list(g.inputs)]
            cell = np.floor((x - g.lo) / g.cell).astype(np.int64)
            inside = np.all((cell >= 0) & (cell < np.asarray(g.shape)), axis=1)
            inside &= np.all(np.isfinite(x), axis=1)
            if not np.any(inside):
                continue
            flat = np.ravel_multi_index(tuple(cell[inside].T), g.shape)
            self._counts[j] += np.bincount(flat, minlength=int(np.prod(g.shape))).reshape(g.shape)
            self._density[j] = None
            self.version += 1

    def density_grid(self, joint: int) -> np.ndarray:
        """Smoothed samples per cell of ``joint``'s grid."""
        cached = self._density[joint]
        if cached is None:
            counts = self._counts[joint]
            cached = smoothed_density(counts, self.config.smoothing_cells)
            self._density[joint] = cached
        return cached

    def density(self, qd: np.ndarray, joint: int) -> np.ndarray:
        """Smoothed samples per cell around ``qd`` (N x n) for ``joint`` -> (N,).

        Computed by :func:`~teleop_force.friction.terms.grid_density` at every sample.
        """
        qd = np.ascontiguousarray(self._check(qd))
        inputs, lo, cell, shape = self.grid_geometry(joint)
        values = np.ascontiguousarray(self.density_grid(joint)).reshape(-1)
        return grid_density_batch(qd, inputs, lo, cell, shape, values)

    def grid_geometry(self, joint: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(inputs, lo, cell, shape)`` of ``joint``'s grid as arrays (compiled terms)."""
        g = self._grids[joint]
        return (
            np.asarray(g.inputs, dtype=np.int64),
            np.ascontiguousarray(g.lo, dtype=float),
            np.ascontiguousarray(g.cell, dtype=float),
            np.asarray(g.shape, dtype=np.int64),
        )

    def trust(self, qd: np.ndarray) -> np.ndarray:
        """Trust weight in [0, 1] of every joint: (n,) -> (n_joints,), (N, n) -> (N, n_joints)."""
        qd_arr = np.asarray(qd, dtype=float)
        single = qd_arr.ndim == 1
        batch = self._check(qd_arr)
        lo, hi = self.config.untrained_density, self.config.trained_density
        out = np.empty((batch.shape[0], self.n_joints))
        for j in range(self.n_joints):
            out[:, j] = density_trust(self.density(batch, j), lo, hi)
        return out[0] if single else out

    def fraction_on_trained_ground(
        self, qd_samples: np.ndarray, joint: int, min_trust: float = 0.5
    ) -> float:
        """Fraction of ``qd_samples`` (N x n) where ``joint``'s trust is >= ``min_trust``."""
        batch = self._check(qd_samples)
        if batch.shape[0] == 0:
            return 0.0
        lo, hi = self.config.untrained_density, self.config.trained_density
        w = density_trust(self.density(batch, joint), lo, hi)
        return float(np.mean(w >= min_trust))

    def to_dict(self) -> dict[str, Any]:
        """Serialise grids and counts to JSON-compatible values."""
        return {
            "config": self.config.to_dict(),
            "grids": [
                {
                    "inputs": list(g.inputs),
                    "x_min_rad_s": g.lo.tolist(),
                    "x_max_rad_s": g.hi.tolist(),
                    "counts": self._counts[j].reshape(-1).tolist(),
                }
                for j, g in enumerate(self._grids)
            ],
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CoverageMap:
        """Deserialise what :meth:`to_dict` wrote; raise ModelFileError naming the field."""
        entry = read_entry(data, CoverageEntry)
        grids = entry.grids
        try:
            return cls(
                [g.inputs for g in grids], [g.x_min_rad_s for g in grids],
                [g.x_max_rad_s for g in grids], entry.config, [np.array(g.counts) for g in grids],
            )  # fmt: skip
        except (ValueError, ArithmeticError) as exc:  # ConfigurationError: sizes, regions...
            raise ModelFileError(f"bad coverage map: {exc}", column="grids") from None
