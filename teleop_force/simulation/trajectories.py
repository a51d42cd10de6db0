"""Reference trajectories for the simulated experiments: positions and velocities of time.

Every :class:`Trajectory` maps time to ``(q_ref, qd_ref)`` (vectorised: a float gives (n,)
arrays, an (N,) array gives (N, n) arrays) and starts at rest, so a plant started at
``q_ref(0)`` begins without a jump. Builders for the paper's protocols (section IV):

- :func:`rigid_body_trajectory`: sums of 4 sinusoids per joint, 12 distinct frequencies in
  0.5-2 Hz (IV-A, identification of the rigid-body parameters).
- :func:`friction_trajectory`: 4 sinusoids per joint at <= 0.7 Hz with joints 2 and 3
  ``"equal"``, ``"opposite"`` (equal with opposite sign about their mid-range) or
  ``"independent"`` (IV-B, experiments 1 and 2).
- :func:`teleoperation_trajectory`: band-limited random motion (IV-B, experiment 3).
- :func:`slow_stretch_trajectory`: the same with slow stretches (:class:`TimeWarped`), free
  motion that also dwells at low joint speeds (identification excitation).
- :func:`palpation_trajectory`: approach a tissue, press into it, slide, release.

All of them stay inside the Omni's joint ranges with a margin (checked on construction).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots import omni

#: Distance kept from the ends of the joint ranges [rad].
DEFAULT_MARGIN_RAD = 0.1
#: Duration of the smooth start of the periodic and random trajectories [s].
DEFAULT_FADE_IN_S = 2.0
FRICTION_MODES = ("equal", "opposite", "independent")


class Trajectory(ABC):
    """Joint reference ``t -> (q_ref [rad], qd_ref [rad/s])``."""

    @property
    @abstractmethod
    def n_joints(self) -> int:
        """Number of joints."""

    @abstractmethod
    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities at ``t_s``: (n,) for a float, (N, n) for an (N,) array."""

    def __call__(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Evaluate the trajectory, like :meth:`sample`."""
        return self.sample(t_s)


def _fade(t: np.ndarray, fade_in_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Raised-cosine window rising from 0 to 1 over ``fade_in_s``, and its derivative."""
    if fade_in_s <= 0.0:
        return np.ones_like(t), np.zeros_like(t)
    x = np.clip(t / fade_in_s, 0.0, 1.0)
    window = 0.5 - 0.5 * np.cos(math.pi * x)
    rate = np.where(
        (t > 0.0) & (t < fade_in_s), 0.5 * math.pi / fade_in_s * np.sin(math.pi * x), 0.0
    )
    return window, rate


def _times(t_s: float | np.ndarray) -> tuple[np.ndarray, bool]:
    t = np.asarray(t_s, dtype=float)
    if t.ndim > 1 or not np.all(np.isfinite(t)):
        raise DataError(f"time must be a finite float or 1-D array, got shape {t.shape}")
    return np.atleast_1d(t), t.ndim == 0


def _usable_range(margin_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre and usable half-width of each Omni joint range."""
    centre = 0.5 * (omni.Q_MIN_RAD + omni.Q_MAX_RAD)
    half = 0.5 * (omni.Q_MAX_RAD - omni.Q_MIN_RAD) - margin_rad
    if np.any(half <= 0.0):
        raise ConfigurationError(f"margin {margin_rad} rad leaves no usable joint range")
    return centre, half


@dataclass(frozen=True, eq=False)
class MultiSine(Trajectory):
    """``q_j(t) = c_j + w(t) sum_k A_jk sin(2 pi f_jk t + phi_jk)``, ``w`` a smooth fade-in.

    Attributes:
        centre_rad: ``c`` (n,).
        amplitudes_rad: ``A`` (n, K); a negative amplitude mirrors a sinusoid.
        frequencies_hz: ``f`` (n, K), > 0.
        phases_rad: ``phi`` (n, K).
        fade_in_s: Duration of the raised-cosine fade-in ``w`` (0: none).

    """

    centre_rad: np.ndarray
    amplitudes_rad: np.ndarray
    frequencies_hz: np.ndarray
    phases_rad: np.ndarray
    fade_in_s: float = DEFAULT_FADE_IN_S

    def __post_init__(self) -> None:
        centre = np.array(self.centre_rad, dtype=float).reshape(-1)
        shape = (centre.shape[0], -1)
        arrays = {
            name: np.array(getattr(self, name), dtype=float).reshape(shape)
            for name in ("amplitudes_rad", "frequencies_hz", "phases_rad")
        }
        if len({a.shape for a in arrays.values()}) != 1:
            raise ConfigurationError(
                "amplitudes, frequencies and phases must share one shape (n, K)"
            )
        if any(not np.all(np.isfinite(a)) for a in (centre, *arrays.values())):
            raise ConfigurationError("multisine parameters must be finite")
        if np.any(arrays["frequencies_hz"] <= 0.0):
            raise ConfigurationError("multisine frequencies must be > 0")
        if not (math.isfinite(self.fade_in_s) and self.fade_in_s >= 0.0):
            raise ConfigurationError(f"fade_in_s must be >= 0, got {self.fade_in_s}")
        for name, value in (("centre_rad", centre), *arrays.items()):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return int(self.centre_rad.shape[0])

    def peak_excursion_rad(self) -> np.ndarray:
        """Upper bound of ``|q_j - c_j|``: the sum of the absolute amplitudes (n,)."""
        return np.abs(self.amplitudes_rad).sum(axis=1)

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (see :class:`Trajectory`)."""
        t, scalar = _times(t_s)
        omega = 2.0 * math.pi * self.frequencies_hz  # (n, K)
        angle = omega[None] * t[:, None, None] + self.phases_rad[None]  # (N, n, K)
        deviation = np.einsum("jk,njk->nj", self.amplitudes_rad, np.sin(angle))
        rate = np.einsum("jk,njk->nj", self.amplitudes_rad * omega, np.cos(angle))
        window, window_rate = _fade(t, self.fade_in_s)
        q = self.centre_rad + window[:, None] * deviation
        qd = window[:, None] * rate + window_rate[:, None] * deviation
        return (q[0], qd[0]) if scalar else (q, qd)


@dataclass(frozen=True, eq=False)
class SaturatedMotion(Trajectory):
    """``q_j = c_j + h_j tanh(s_j(t) / h_j)``: a signal ``s`` squashed smoothly into a range.

    Attributes:
        signal: A :class:`MultiSine` centred on 0 giving ``s``.
        centre_rad: ``c`` (n,).
        half_width_rad: ``h`` (n,), > 0: ``q`` never leaves ``c +- h``.

    """

    signal: MultiSine
    centre_rad: np.ndarray
    half_width_rad: np.ndarray

    def __post_init__(self) -> None:
        n = self.signal.n_joints
        centre = np.array(self.centre_rad, dtype=float).reshape(-1)
        half = np.array(self.half_width_rad, dtype=float).reshape(-1)
        if centre.shape != (n,) or half.shape != (n,) or np.any(~(half > 0.0)):
            raise ConfigurationError(f"centre and half-width need {n} values, half-width > 0")
        object.__setattr__(self, "centre_rad", centre)
        object.__setattr__(self, "half_width_rad", half)

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self.signal.n_joints

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (see :class:`Trajectory`)."""
        s, s_rate = self.signal.sample(t_s)
        squashed = np.tanh(s / self.half_width_rad)
        q = self.centre_rad + self.half_width_rad * squashed
        qd = (1.0 - squashed**2) * s_rate
        return q, qd


@dataclass(frozen=True, eq=False)
class TimeWarped(Trajectory):
    """``q(t) = q_base(tau(t))``: a trajectory played at a time-varying rate ``r = tau'``.

    The rate is 1 except in the slow stretches ``[starts_s[i], ends_s[i]]``, where it blends
    down to ``rates[i]`` over ``ramp_s`` (a smoothstep), stays there and blends back up, so
    ``qd = qd_base(tau) r`` is continuous and the positions are those of the base
    trajectory (same range), only visited slower. ``tau`` is the rate's exact integral.

    Attributes:
        base: The trajectory played.
        starts_s: (S,) starts of the slow stretches (increasing, non-overlapping).
        ends_s: (S,) their ends (each at least ``2 ramp_s`` after its start).
        rates: (S,) the rate inside each stretch, in (0, 1].
        ramp_s: Duration of the blends into and out of a stretch.

    """

    base: Trajectory
    starts_s: np.ndarray
    ends_s: np.ndarray
    rates: np.ndarray
    ramp_s: float = 0.5

    def __post_init__(self) -> None:
        starts = np.array(self.starts_s, dtype=float).reshape(-1)
        ends = np.array(self.ends_s, dtype=float).reshape(-1)
        rates = np.array(self.rates, dtype=float).reshape(-1)
        ramp = float(self.ramp_s)
        if not (math.isfinite(ramp) and ramp > 0.0):
            raise ConfigurationError(f"ramp_s must be > 0, got {self.ramp_s}")
        if starts.shape != ends.shape or starts.shape != rates.shape:
            raise ConfigurationError("slow stretches need one start, end and rate each")
        if not (np.all(np.isfinite(starts)) and np.all(np.isfinite(ends))):
            raise ConfigurationError("slow stretch times must be finite")
        if np.any(ends - starts < 2.0 * ramp) or np.any(starts[1:] < ends[:-1]):
            raise ConfigurationError("slow stretches must last 2 ramps and not overlap")
        if np.any(~((rates > 0.0) & (rates <= 1.0))):
            raise ConfigurationError("slow stretch rates must be in (0, 1]")
        for name, value in (("starts_s", starts), ("ends_s", ends), ("rates", rates)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @property
    def n_joints(self) -> int:
        """Number of joints."""
        return self.base.n_joints

    def warp(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Warped time ``tau`` and rate ``r`` at ``t_s`` ((N,) each, also for a float)."""
        t, _ = _times(t_s)
        tau = t.copy()
        rate = np.ones_like(t)
        ramp = float(self.ramp_s)
        for start, end, slow in zip(self.starts_s, self.ends_s, self.rates, strict=True):
            # depth d(t) in [0, 1] of the slowdown: r = 1 - (1 - slow) d, tau = t - (1 - slow) D
            x_in = np.clip((t - start) / ramp, 0.0, 1.0)
            x_out = np.clip((t - (end - ramp)) / ramp, 0.0, 1.0)
            depth = x_in**2 * (3.0 - 2.0 * x_in) - x_out**2 * (3.0 - 2.0 * x_out)
            held = np.maximum(t - (start + ramp), 0.0) - np.maximum(t - end, 0.0)
            area = ramp * (x_in**3 - 0.5 * x_in**4) + held
            area -= ramp * (x_out**3 - 0.5 * x_out**4)
            rate -= (1.0 - slow) * depth
            tau -= (1.0 - slow) * area
        return tau, rate

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (see :class:`Trajectory`)."""
        _, scalar = _times(t_s)
        tau, rate = self.warp(t_s)
        q, qd = self.base.sample(tau)
        qd = qd * rate[:, None]
        return (q[0], qd[0]) if scalar else (q, qd)


def _minimum_jerk(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``10x^3 - 15x^4 + 6x^5`` and its derivative, for x in [0, 1]."""
    return x**3 * (10.0 + x * (-15.0 + 6.0 * x)), 30.0 * x**2 * (1.0 - x) ** 2


def omni_inverse_kinematics(p_in_base_m: np.ndarray) -> np.ndarray:
    """Omni joint angles putting the tip at ``p`` ((3,) -> (3,), (N, 3) -> (N, 3)).

    Inverts :func:`teleop_force.robots.omni.tip_position_formula` on the elbow-up branch (link 1
    above the line from the shoulder to the tip), the Omni's working posture.

    Raises:
        DataError: for a point out of reach (farther than ``l1 + l2``, or on the yaw axis).

    """
    p = np.asarray(p_in_base_m, dtype=float)
    if p.ndim not in (1, 2) or p.shape[-1] != 3:
        raise DataError(f"points must have shape (3,) or (N, 3), got {p.shape}")
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    l1, l2 = omni.UPPER_ARM_LENGTH_M, omni.FOREARM_LENGTH_M
    r = np.hypot(x, z)
    distance = np.hypot(r, y)
    cos_inner = (distance**2 + l1**2 - l2**2) / (2.0 * l1 * np.maximum(distance, 1e-12))
    if np.any(r < 1e-6) or np.any(np.abs(cos_inner) > 1.0):
        raise DataError("point out of the Omni's reach (or on the yaw axis)")
    q1 = np.arctan2(-x, z)
    direction = np.arctan2(y, r)
    q2 = direction + np.arccos(cos_inner)
    # Forearm: from the elbow to the tip; its direction (sin q3, -cos q3) in the (r, y) plane.
    dr = r - l1 * np.cos(q2)
    dy = y - l1 * np.sin(q2)
    q3 = np.arctan2(dr, -dy)
    return np.stack((q1, q2, q3), axis=-1)


def _omni_tip_jacobians(q: np.ndarray) -> np.ndarray:
    """:func:`~teleop_force.robots.omni.tip_jacobian_formula` of a batch of angles (N, 3)."""
    q1, q2, q3 = q[:, 0], q[:, 1], q[:, 2]
    l1, l2 = omni.UPPER_ARM_LENGTH_M, omni.FOREARM_LENGTH_M
    r = l1 * np.cos(q2) + l2 * np.sin(q3)
    dr2, dr3 = -l1 * np.sin(q2), l2 * np.cos(q3)
    s1, c1 = np.sin(q1), np.cos(q1)
    jac = np.zeros((q.shape[0], 3, 3))
    jac[:, 0] = np.stack((-c1 * r, -s1 * dr2, -s1 * dr3), axis=1)
    jac[:, 1, 1] = l1 * np.cos(q2)
    jac[:, 1, 2] = l2 * np.sin(q3)
    jac[:, 2] = np.stack((-s1 * r, c1 * dr2, c1 * dr3), axis=1)
    return jac


@dataclass(frozen=True, eq=False)
class CartesianWaypoints(Trajectory):
    """Tip waypoints joined by straight minimum-jerk segments, mapped to the Omni's joints.

    The tip stops at every waypoint, moves along straight lines in between, and holds the last
    waypoint afterwards. Joint velocities are ``J(q)^-1 p_dot``.

    Attributes:
        times_s: Strictly increasing arrival times (K,), the first one the start.
        points_in_base_m: Tip positions (K, 3) in the base frame.

    """

    times_s: np.ndarray
    points_in_base_m: np.ndarray

    def __post_init__(self) -> None:
        times = np.array(self.times_s, dtype=float).reshape(-1)
        points = np.array(self.points_in_base_m, dtype=float)
        if points.shape != (times.shape[0], 3) or times.shape[0] < 2:
            raise ConfigurationError("need K >= 2 times and K x 3 points")
        if np.any(np.diff(times) <= 0.0) or not np.all(np.isfinite(times)):
            raise ConfigurationError("waypoint times must increase strictly")
        try:
            q = omni_inverse_kinematics(points)
        except DataError as error:
            raise ConfigurationError(f"a waypoint is unreachable: {error}") from error
        if np.any(q < omni.Q_MIN_RAD) or np.any(q > omni.Q_MAX_RAD):
            raise ConfigurationError("a waypoint lies outside the Omni's joint ranges")
        for name, value in (("times_s", times), ("points_in_base_m", points)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    @property
    def n_joints(self) -> int:
        """Always 3 (the Omni)."""
        return 3

    @property
    def duration_s(self) -> float:
        """Time of the last waypoint."""
        return float(self.times_s[-1])

    def tip_sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip position and velocity in the base frame at ``t_s``."""
        t, scalar = _times(t_s)
        times, points = self.times_s, self.points_in_base_m
        segment = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.shape[0] - 2)
        span = times[segment + 1] - times[segment]
        x = np.clip((t - times[segment]) / span, 0.0, 1.0)
        shape, shape_rate = _minimum_jerk(x)
        delta = points[segment + 1] - points[segment]
        p = points[segment] + shape[:, None] * delta
        v = (shape_rate / span)[:, None] * delta
        v[(t < times[0]) | (t > times[-1])] = 0.0
        return (p[0], v[0]) if scalar else (p, v)

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (see :class:`Trajectory`)."""
        p, v = self.tip_sample(np.atleast_1d(np.asarray(t_s, dtype=float)))
        q = omni_inverse_kinematics(p)
        qd = np.linalg.solve(_omni_tip_jacobians(q), v[..., None])[..., 0]
        return (q[0], qd[0]) if np.ndim(t_s) == 0 else (q, qd)


def rigid_body_trajectory(
    seed: int = 0, *, fill: float = 0.8, margin_rad: float = DEFAULT_MARGIN_RAD
) -> MultiSine:
    """Paper IV-A: 4 sinusoids per joint, 12 distinct frequencies spread over 0.5-2 Hz.

    Frequencies are a fixed grid (joint j takes every third), phases are random (seeded), and
    equal amplitudes fill ``fill`` of each joint's usable half-range.
    """
    _check_fill(fill)
    centre, half = _usable_range(margin_rad)
    grid = np.linspace(0.5, 2.0, 12)
    frequencies = np.stack([grid[j::3] for j in range(3)])
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2.0 * math.pi, size=(3, 4))
    amplitudes = np.repeat((fill * half / 4.0)[:, None], 4, axis=1)
    return MultiSine(centre, amplitudes, frequencies, phases)


def friction_trajectory(
    mode: str,
    seed: int = 0,
    *,
    fill: float = 0.8,
    max_frequency_hz: float = 0.7,
    margin_rad: float = DEFAULT_MARGIN_RAD,
) -> MultiSine:
    """Paper IV-B: 4 sinusoids per joint at frequencies up to ``max_frequency_hz``.

    ``mode`` sets joints 2 and 3: ``"equal"`` (same motion about their mid-ranges, small
    ``qd2 - qd3``), ``"opposite"`` (mirrored, large ``qd2 - qd3``) or ``"independent"``
    (own frequencies and phases, the whole ``qd2``-``qd3`` plane).
    """
    if mode not in FRICTION_MODES:
        raise ConfigurationError(f"mode must be one of {FRICTION_MODES}, got {mode!r}")
    _check_fill(fill)
    if not 0.2 < max_frequency_hz <= 5.0:
        raise ConfigurationError(f"max_frequency_hz must be in (0.2, 5], got {max_frequency_hz}")
    centre, half = _usable_range(margin_rad)
    grid = np.linspace(0.12, max_frequency_hz, 12)
    frequencies = np.stack([grid[j::3] for j in range(3)])
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0.0, 2.0 * math.pi, size=(3, 4))
    amplitudes = np.repeat((fill * half / 4.0)[:, None], 4, axis=1)
    if mode != "independent":
        shared = fill * min(half[1], half[2]) / 4.0
        frequencies[2] = frequencies[1]
        phases[2] = phases[1]
        amplitudes[1] = shared
        amplitudes[2] = shared if mode == "equal" else -shared
    return MultiSine(centre, amplitudes, frequencies, phases)


def teleoperation_trajectory(
    seed: int = 0,
    *,
    bandwidth_hz: float = 0.4,
    n_components: int = 40,
    fill: float = 0.8,
    margin_rad: float = DEFAULT_MARGIN_RAD,
) -> SaturatedMotion:
    """Paper IV-B experiment 3: band-limited random motion, like a hand moving a master arm.

    Gaussian noise through a 2nd-order low-pass at ``bandwidth_hz``, realised as a sum of
    ``n_components`` sinusoids per joint at random frequencies (0.02 Hz to 2.5 bandwidths) with
    Rayleigh amplitudes shaped by the filter's gain and random phases: stationary,
    band-limited, non-periodic, and exactly differentiable. Its standard deviation is 35 % of
    the usable half-range, and a ``tanh`` keeps it strictly inside ``fill`` of it.
    """
    _check_fill(fill)
    if not (math.isfinite(bandwidth_hz) and 0.0 < bandwidth_hz <= 10.0):
        raise ConfigurationError(f"bandwidth_hz must be in (0, 10], got {bandwidth_hz}")
    if n_components < 4:
        raise ConfigurationError(f"n_components must be >= 4, got {n_components}")
    centre, half = _usable_range(margin_rad)
    rng = np.random.default_rng(seed)
    shape = (3, n_components)
    frequencies = rng.uniform(0.02, 2.5 * bandwidth_hz, size=shape)
    gain = 1.0 / np.sqrt(1.0 + (frequencies / bandwidth_hz) ** 4)
    amplitudes = gain * rng.rayleigh(1.0, size=shape)
    std = np.sqrt(0.5 * np.sum(amplitudes**2, axis=1, keepdims=True))
    amplitudes *= (0.35 * half)[:, None] / std
    phases = rng.uniform(0.0, 2.0 * math.pi, size=shape)
    signal = MultiSine(np.zeros(3), amplitudes, frequencies, phases)
    return SaturatedMotion(signal, centre, fill * half)


def slow_stretch_trajectory(
    duration_s: float,
    seed: int = 0,
    *,
    slow_fraction: float = 0.4,
    stretch_s: tuple[float, float] = (4.0, 8.0),
    rates: tuple[float, float] = (0.02, 0.2),
    ramp_s: float = 0.5,
) -> TimeWarped:
    """Band-limited random motion with slow stretches: free motion that also covers low speed.

    :func:`teleoperation_trajectory` (same seed) played at rate 1, except in slow stretches
    of ``U(*stretch_s)`` s (scaled down together so that they take exactly ``slow_fraction``
    of ``duration_s``; a stretch shorter than two ramps is refused), played at a rate drawn
    log-uniform in ``rates`` (:class:`TimeWarped`): the same positions and reversals, visited
    1/50 to 1/5 as fast, so joint speeds of 0.005-0.1 rad/s are held for seconds instead of
    crossed in a blink. The stretches are spread evenly with random gaps (none before 3 s).
    """
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        raise ConfigurationError(f"duration_s must be > 0, got {duration_s}")
    if not 0.0 <= slow_fraction < 1.0:
        raise ConfigurationError(f"slow_fraction must be in [0, 1), got {slow_fraction}")
    low, high = (float(x) for x in stretch_s)
    if not 2.0 * ramp_s <= low <= high:
        raise ConfigurationError("need 2 ramp_s <= stretch_s[0] <= stretch_s[1]")
    slowest, fastest = (float(x) for x in rates)
    if not 0.0 < slowest <= fastest <= 1.0:
        raise ConfigurationError("need 0 < rates[0] <= rates[1] <= 1")
    rng = np.random.default_rng(seed + 7919)
    base = teleoperation_trajectory(seed)
    target = slow_fraction * duration_s
    lengths: list[float] = []
    while sum(lengths) < target:
        lengths.append(float(rng.uniform(low, high)))
    if lengths:  # scaled down so that they take the fraction exactly
        lengths = [length * target / sum(lengths) for length in lengths]
    free = duration_s - 3.0 - sum(lengths)
    if lengths and free <= 0.0:
        raise ConfigurationError("the slow stretches do not fit into the duration")
    gaps = rng.dirichlet(np.ones(len(lengths) + 1)) * max(free, 0.0)
    starts, ends = [], []
    t = 3.0
    for gap, length in zip(gaps[:-1], lengths, strict=True):
        t += float(gap)
        starts.append(t)
        ends.append(t + length)
        t += length
    rate = np.exp(rng.uniform(math.log(slowest), math.log(fastest), size=len(lengths)))
    return TimeWarped(base, np.array(starts), np.array(ends), rate, ramp_s)


def palpation_trajectory(
    duration_s: float,
    seed: int = 0,
    *,
    surface_y_m: float = -0.06,
    depth_m: float = 0.006,
    hover_m: float = 0.02,
    slide_m: float = 0.04,
) -> CartesianWaypoints:
    """Repeated palpation of a horizontal tissue at ``y = surface_y_m``.

    Each ~7 s cycle: move above a random spot, descend to ``depth_m`` below the undeformed
    surface (the tip's reference; the tissue stops the real tip short of it), dwell, slide
    ``slide_m`` in a random horizontal direction, dwell, lift back to ``hover_m`` above. The
    reference waits at the start hover point for 1 s.
    """
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        raise ConfigurationError(f"duration_s must be > 0, got {duration_s}")
    if not (0.0 < depth_m < 0.03 and 0.0 < hover_m < 0.06 and 0.0 < slide_m < 0.1):
        raise ConfigurationError("need 0 < depth_m < 0.03, 0 < hover_m < 0.06, 0 < slide_m < 0.1")
    rng = np.random.default_rng(seed)
    centre = np.array([0.0, surface_y_m, 0.12])
    times = [0.0, 1.0]
    points = [np.array([0.0, surface_y_m + hover_m, 0.12])] * 2
    t = 1.0
    while t < duration_s:
        start = centre + np.array([rng.uniform(-0.03, 0.03), 0.0, rng.uniform(-0.015, 0.015)])
        heading = rng.uniform(0.0, 2.0 * math.pi)
        end = start + slide_m * np.array([math.cos(heading), 0.0, math.sin(heading)])
        end[0] = np.clip(end[0], -0.05, 0.05)
        end[2] = np.clip(end[2], 0.09, 0.15)
        up = np.array([0.0, hover_m, 0.0])
        down = np.array([0.0, -depth_m, 0.0])
        for duration, point in (
            (1.2, start + up),
            (1.2, start + down),
            (0.6, start + down),
            (2.5, end + down),
            (0.4, end + down),
            (1.0, end + up),
        ):
            t += duration
            times.append(t)
            points.append(np.array(point, dtype=float))
    return CartesianWaypoints(np.array(times), np.array(points))


def _check_fill(fill: float) -> None:
    if not (math.isfinite(fill) and 0.0 < fill <= 1.0):
        raise ConfigurationError(f"fill must be in (0, 1], got {fill}")
