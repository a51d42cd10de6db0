"""Training trajectories that fill a velocity region, and how well a trajectory covers it.

The paper's Experiment 3 (Fig. 4) failed on "untrained ground": the 2-D friction networks of
joints 2 and 3 were only trained where the training velocities went. Given the region of the
``qd2``-``qd3`` plane (and the ``qd1`` range) the user will work in, :func:`training_trajectory`
returns joint position references whose velocities sweep all of it:

* each joint's velocity is ``c_i S_i(t) + h_i A_i(t) sin(2 pi f_i t + phi_i)`` with ``c_i``,
  ``h_i`` the centre and half-width of the wanted range. ``A_i(t)`` sweeps slowly between
  0.15 and 1 so the inside of the range is covered, not only its edges (a plain sinusoid
  dwells at its extremes), and ``f_3 / f_2`` is irrational, so ``(qd2, qd3)`` traces a dense
  Lissajous figure of the rectangle with varying amplitude ratios;
* a velocity with a non-zero mean would run into the joint limits, so when the range does
  not straddle 0 the offset ``c_i`` is switched by a smooth square wave ``S_i(t) = +-1``:
  half of the time is spent in the wanted region, half in its mirror image through 0;
* the frequencies are raised until the positions (velocity integrals) fit inside the joint
  limits minus a margin, and each joint is centred in its range.

:func:`region_coverage` measures the fraction of the region's cells (0.05 rad/s in ``qd1``,
40 x 40 in the ``qd2``-``qd3`` rectangle) that a trajectory's velocities visit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots.omni import Q_MAX_RAD, Q_MIN_RAD

#: ``f_3 / f_2``: irrational, so the Lissajous figure never closes.
_FREQUENCY_RATIO = math.sqrt(5.0) - 1.0
_AMPLITUDE_MIN = 0.15


@dataclass(frozen=True)
class VelocityRegion:
    """Velocity ranges the user will work in: ``qd1`` and a ``qd2``-``qd3`` rectangle [rad/s]."""

    qd1_rad_s: tuple[float, float]
    qd2_rad_s: tuple[float, float]
    qd3_rad_s: tuple[float, float]

    def __post_init__(self) -> None:
        for name in ("qd1_rad_s", "qd2_rad_s", "qd3_rad_s"):
            lo, hi = (float(v) for v in getattr(self, name))
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                raise ConfigurationError(f"{name}: need finite min < max, got ({lo}, {hi})")
            object.__setattr__(self, name, (lo, hi))

    @property
    def lo(self) -> np.ndarray:
        """Lower bounds of ``qd1, qd2, qd3``."""
        return np.asarray([self.qd1_rad_s[0], self.qd2_rad_s[0], self.qd3_rad_s[0]])

    @property
    def hi(self) -> np.ndarray:
        """Upper bounds of ``qd1, qd2, qd3``."""
        return np.asarray([self.qd1_rad_s[1], self.qd2_rad_s[1], self.qd3_rad_s[1]])


@dataclass(frozen=True)
class TrainingTrajectory:
    """Joint references: time ``t_s`` (N,), positions ``q_rad`` (N, 3), velocities (N, 3)."""

    t_s: np.ndarray
    q_rad: np.ndarray
    qd_rad_s: np.ndarray

    def __post_init__(self) -> None:
        n = self.t_s.shape[0]
        if self.q_rad.shape != (n, 3) or self.qd_rad_s.shape != (n, 3):
            raise ConfigurationError("TrainingTrajectory: arrays must be (N,), (N, 3), (N, 3)")


@dataclass(frozen=True)
class RegionCoverage:
    """Fractions of a :class:`VelocityRegion`'s cells visited by a trajectory's velocities."""

    qd1_fraction: float
    qd23_fraction: float

    def __post_init__(self) -> None:
        for name in ("qd1_fraction", "qd23_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigurationError(f"{name} must be in [0, 1]")


def _smooth_square(t_s: np.ndarray, period_s: float, phase: float) -> np.ndarray:
    """Smooth square wave in [-1, 1] with zero mean over a period."""
    s = np.sin(2.0 * math.pi * t_s / period_s + phase)
    return np.tanh(4.0 * s) / math.tanh(4.0)


def _velocities(
    t_s: np.ndarray,
    centre: np.ndarray,
    half: np.ndarray,
    freq_hz: np.ndarray,
    half_range_rad: np.ndarray,
    duration_s: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Velocity references of the three joints (N, 3)."""
    qd = np.empty((t_s.size, 3))
    phases = rng.uniform(0.0, 2.0 * math.pi, size=(3, 3))
    for i in range(3):
        # the amplitude sweeps 0.15..1 a few times over the recording (at least one sweep)
        sweep_hz = max(1.5 / duration_s, 0.02 * (1.0 + 0.37 * i))
        amp = _AMPLITUDE_MIN + (1.0 - _AMPLITUDE_MIN) * 0.5 * (
            1.0 - np.cos(2.0 * math.pi * sweep_hz * t_s + phases[i, 0])
        )
        qd[:, i] = half[i] * amp * np.sin(2.0 * math.pi * freq_hz[i] * t_s + phases[i, 1])
        if abs(centre[i]) > 1e-12:
            period = 1.2 * half_range_rad[i] / abs(centre[i])
            qd[:, i] += centre[i] * _smooth_square(t_s, period, phases[i, 2])
    return qd


def training_trajectory(
    region: VelocityRegion,
    duration_s: float,
    sample_rate_hz: float = 1000.0,
    *,
    q_min_rad: np.ndarray = Q_MIN_RAD,
    q_max_rad: np.ndarray = Q_MAX_RAD,
    margin_rad: float = 0.05,
    min_frequency_hz: float = 0.1,
    seed: int = 0,
) -> TrainingTrajectory:
    """Position references whose velocities fill ``region`` within the joint limits.

    Raises ConfigurationError when the region cannot be reached inside the joint limits
    (it would need frequencies above 5 Hz).
    """
    if not duration_s > 0.0 or not sample_rate_hz > 0.0:
        raise ConfigurationError("duration_s and sample_rate_hz must be > 0")
    q_min = np.asarray(q_min_rad, dtype=float).reshape(3)
    q_max = np.asarray(q_max_rad, dtype=float).reshape(3)
    half_range = 0.5 * (q_max - q_min) - margin_rad
    if np.any(half_range <= 0.0):
        raise ConfigurationError("joint range smaller than twice the margin")
    n = round(duration_s * sample_rate_hz) + 1
    t = np.arange(n) / sample_rate_hz
    centre = 0.5 * (region.lo + region.hi)
    half = 0.5 * (region.hi - region.lo)
    # sinusoid position amplitude h / (2 pi f) within 60 % of the half range
    freq = np.maximum(min_frequency_hz, half / (2.0 * math.pi * 0.6 * half_range))
    freq[2] = max(freq[2], freq[1] * _FREQUENCY_RATIO)
    freq[1] = max(freq[1], freq[2] / _FREQUENCY_RATIO)
    for _ in range(20):
        rng = np.random.default_rng(seed)
        qd = _velocities(t, centre, half, freq, half_range, duration_s, rng)
        q = np.zeros_like(qd)
        q[1:] = np.cumsum(0.5 * (qd[1:] + qd[:-1]), axis=0) / sample_rate_hz
        span = q.max(axis=0) - q.min(axis=0)
        over = span / (2.0 * half_range)
        if np.all(over <= 1.0):
            offset = 0.5 * (q_min + q_max) - 0.5 * (q.max(axis=0) + q.min(axis=0))
            return TrainingTrajectory(t_s=t, q_rad=q + offset, qd_rad_s=qd)
        freq = freq * np.maximum(1.0, over * 1.05)
        if np.any(freq > 5.0):
            break
    raise ConfigurationError("velocity region not reachable within the joint limits")


def region_coverage(
    qd: np.ndarray,
    region: VelocityRegion,
    *,
    cell_size_1d_rad_s: float = 0.05,
    cells_2d: int = 40,
    min_samples: int = 1,
) -> RegionCoverage:
    """Fraction of the ``qd1`` and ``qd2``-``qd3`` cells of ``region`` visited by ``qd`` (N x 3)."""
    qd = np.asarray(qd, dtype=float)
    if qd.ndim != 2 or qd.shape[1] < 3:
        raise DataError(f"need velocities (N, 3), got {qd.shape}")
    if not cell_size_1d_rad_s > 0.0 or cells_2d < 1 or min_samples < 1:
        raise ConfigurationError("need cell_size_1d_rad_s > 0, cells_2d >= 1, min_samples >= 1")
    lo, hi = region.lo, region.hi
    n1 = max(1, math.ceil((hi[0] - lo[0]) / cell_size_1d_rad_s - 1e-9))
    c1 = np.floor((qd[:, 0] - lo[0]) / (hi[0] - lo[0]) * n1).astype(np.int64)
    ok1 = (c1 >= 0) & (c1 < n1)
    frac1 = float(np.mean(np.bincount(c1[ok1], minlength=n1) >= min_samples))
    cells = np.floor((qd[:, 1:3] - lo[1:3]) / (hi[1:3] - lo[1:3]) * cells_2d).astype(np.int64)
    ok2 = np.all((cells >= 0) & (cells < cells_2d), axis=1)
    flat = cells[ok2, 0] * cells_2d + cells[ok2, 1]
    frac2 = float(np.mean(np.bincount(flat, minlength=cells_2d**2) >= min_samples))
    return RegionCoverage(qd1_fraction=frac1, qd23_fraction=frac2)
