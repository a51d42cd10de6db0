"""Teleoperation touching a soft floor: random sliding tip motion with repeated presses.

The tip's reference moves like a hand on a master arm over a patch above a horizontal floor
at ``y = surface_y_m``: ``x`` and ``z`` wander as band-limited random signals (sums of
sinusoids at random frequencies up to ``bandwidth_hz``, random phases, a raised-cosine
fade-in from rest), while the height goes through press cycles joined by minimum-jerk moves:
descend from ``U(6, 12)`` mm above the surface to ``U(3.5, 8.5)`` mm below it in
``U(0.5, 0.9)`` s, stay, rise in ``U(0.5, 0.9)`` s, hover ``U(1.0, 2.0)`` s. The floor stops
the real tip short of the reference (the PID's integral presses on). While it presses the
tip either keeps sliding in ``x``/``z`` (stay ``U(0.3, 0.7)`` s) or, every other cycle on
average, stops and holds still (stay ``U(0.8, 1.4)`` s; the planar motion blends to the
point where the stay began over ``still_ramp_s``): pressing at rest, where the friction's
static band meets the load. On both plant families the tip is in
contact ~35 % of the time with an RMS contact force of 1-2 N (``teleop-force accuracy``
prints both figures per session). Joint references come from the Omni's inverse kinematics
(:func:`~teleop_force.simulation.trajectories.omni_inverse_kinematics`), velocities from
``J^-1 p_dot``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Unpack

import numpy as np

from teleop_force.errors import ConfigurationError, DataError
from teleop_force.robots import omni
from teleop_force.simulation.contact import PlaneContact
from teleop_force.simulation.families import PlantFamily, default_contact
from teleop_force.simulation.floor_contact import HuntCrossleyFloor
from teleop_force.simulation.session import SessionOptions, SimulatedSession, simulate_session
from teleop_force.simulation.trajectories import Trajectory, omni_inverse_kinematics

_N_COMPONENTS = 24
#: The reference hovers at its first height until then [s] (the x/z fade-in's end).
_FIRST_PRESS_S = 2.0


@dataclass(frozen=True, eq=False)
class FloorTouchTrajectory(Trajectory):
    """Tip reference of the module docstring, mapped to the Omni's joints.

    Attributes:
        frequencies_hz: (2, K) frequencies of the x and z signals.
        amplitudes: (2, K) amplitudes (each row of unit variance).
        phases_rad: (2, K) phases.
        knot_times_s: (M,) increasing times of the height knots.
        knot_heights_m: (M,) heights of the reference above the surface at the knots.
        still_starts_s: (S,) starts of the still holds (increasing, non-overlapping).
        still_ends_s: (S,) their ends.
        surface_y_m: Height of the floor.
        spread_x_m: Deviation of x.
        spread_z_m: Deviation of z about ``centre_z_m``.
        centre_z_m: Centre of the patch in z.
        fade_in_s: Duration of the x/z fade-in.
        still_ramp_s: Duration of the blends into and out of a still hold.

    """

    frequencies_hz: np.ndarray
    amplitudes: np.ndarray
    phases_rad: np.ndarray
    knot_times_s: np.ndarray
    knot_heights_m: np.ndarray
    still_starts_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    still_ends_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    surface_y_m: float = -0.06
    spread_x_m: float = 0.02
    spread_z_m: float = 0.012
    centre_z_m: float = 0.12
    fade_in_s: float = 2.0
    still_ramp_s: float = 0.2

    def __post_init__(self) -> None:
        shapes = {np.shape(self.frequencies_hz), np.shape(self.amplitudes)}
        shapes.add(np.shape(self.phases_rad))
        if len(shapes) != 1 or next(iter(shapes))[0] != 2:
            raise ConfigurationError("frequencies, amplitudes and phases must share one (2, K)")
        times = np.asarray(self.knot_times_s, dtype=float)
        heights = np.asarray(self.knot_heights_m, dtype=float)
        if times.ndim != 1 or times.shape != heights.shape or times.size < 2:
            raise ConfigurationError("need M >= 2 knot times and heights")
        if np.any(np.diff(times) <= 0.0):
            raise ConfigurationError("knot times must increase strictly")
        starts = np.asarray(self.still_starts_s, dtype=float)
        ends = np.asarray(self.still_ends_s, dtype=float)
        if starts.ndim != 1 or starts.shape != ends.shape or np.any(ends <= starts):
            raise ConfigurationError("still holds need one end after each start")
        if np.any(starts[1:] < ends[:-1] + self.still_ramp_s):
            raise ConfigurationError("still holds must not overlap")
        for name in ("spread_x_m", "spread_z_m", "fade_in_s", "still_ramp_s"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigurationError(f"{name} must be finite and >= 0, got {value}")

    @property
    def n_joints(self) -> int:
        """Always 3 (the Omni)."""
        return 3

    def _height(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times = np.asarray(self.knot_times_s, dtype=float)
        heights = np.asarray(self.knot_heights_m, dtype=float)
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
        span = times[k + 1] - times[k]
        x = np.clip((t - times[k]) / span, 0.0, 1.0)
        shape = x**3 * (10.0 + x * (-15.0 + 6.0 * x))
        rate = 30.0 * x**2 * (1.0 - x) ** 2 / span
        rate = np.where((t < times[0]) | (t > times[-1]), 0.0, rate)
        delta = heights[k + 1] - heights[k]
        return heights[k] + shape * delta, rate * delta

    def _planar(self, t: np.ndarray) -> np.ndarray:
        angle = 2.0 * math.pi * self.frequencies_hz[None] * t[:, None, None] + self.phases_rad
        s = np.sum(self.amplitudes * np.sin(angle), axis=2)
        x = np.clip(t / self.fade_in_s, 0.0, 1.0) if self.fade_in_s > 0.0 else np.ones_like(t)
        w = 0.5 - 0.5 * np.cos(math.pi * x)
        return np.asarray(w[:, None] * np.array([self.spread_x_m, self.spread_z_m]) * s)

    def _hold_still(
        self, t: np.ndarray, planar: np.ndarray, rate: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Blend the planar motion ``P`` to ``P(start)`` in the still holds: ``(1-b) P + b A``."""
        starts = np.asarray(self.still_starts_s, dtype=float)
        if starts.size == 0:
            return planar, rate
        ends = np.asarray(self.still_ends_s, dtype=float)
        k = np.searchsorted(starts, t, side="right") - 1
        active = k >= 0
        k = np.maximum(k, 0)
        ramp = self.still_ramp_s
        rise = np.clip((t - starts[k]) / ramp, 0.0, 1.0)
        fall = np.clip((t - ends[k]) / ramp, 0.0, 1.0)
        up, d_up = rise**3 * (10 - 15 * rise + 6 * rise**2), 30 * rise**2 * (1 - rise) ** 2 / ramp
        down, d_down = (
            fall**3 * (10 - 15 * fall + 6 * fall**2),
            30 * fall**2 * (1 - fall) ** 2 / ramp,
        )
        b = np.where(active, up * (1.0 - down), 0.0)
        db = np.where(active, d_up * (1.0 - down) - up * d_down, 0.0)
        anchor = self._planar(starts)[k]
        held = (1.0 - b)[:, None] * planar + b[:, None] * anchor
        held_rate = (1.0 - b)[:, None] * rate + db[:, None] * (anchor - planar)
        return held, held_rate

    def tip_sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tip position and velocity references (N, 3) at times ``t_s`` (N,)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise DataError("time must be a finite float or 1-D array")
        angle = 2.0 * math.pi * self.frequencies_hz[None] * t[:, None, None] + self.phases_rad
        s = np.sum(self.amplitudes * np.sin(angle), axis=2)  # (N, 2)
        ds = np.sum(self.amplitudes * 2.0 * math.pi * self.frequencies_hz * np.cos(angle), axis=2)
        if self.fade_in_s > 0.0:
            x = np.clip(t / self.fade_in_s, 0.0, 1.0)
            w = 0.5 - 0.5 * np.cos(math.pi * x)
            dw = np.where(
                (t > 0.0) & (t < self.fade_in_s),
                0.5 * math.pi / self.fade_in_s * np.sin(math.pi * x),
                0.0,
            )
        else:
            w, dw = np.ones_like(t), np.zeros_like(t)
        spread = np.array([self.spread_x_m, self.spread_z_m])
        planar = w[:, None] * spread * s
        planar_rate = dw[:, None] * spread * s + w[:, None] * spread * ds
        planar, planar_rate = self._hold_still(t, planar, planar_rate)
        height, height_rate = self._height(t)
        p = np.stack(
            [planar[:, 0], self.surface_y_m + height, self.centre_z_m + planar[:, 1]], axis=1
        )
        v = np.stack([planar_rate[:, 0], height_rate, planar_rate[:, 1]], axis=1)
        return p, v

    def sample(self, t_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (see :class:`Trajectory`)."""
        p, v = self.tip_sample(t_s)
        q = omni_inverse_kinematics(p)
        if np.any(q < omni.Q_MIN_RAD) or np.any(q > omni.Q_MAX_RAD):
            raise ConfigurationError("the floor-touch reference leaves the Omni's joint ranges")
        jac = np.stack([omni.tip_jacobian_formula(row) for row in q])
        qd = np.linalg.solve(jac, v[..., None])[..., 0]
        return (q[0], qd[0]) if np.ndim(t_s) == 0 else (q, qd)


def floor_touch_trajectory(
    seed: int = 0,
    *,
    duration_s: float = 600.0,
    surface_y_m: float = -0.06,
    bandwidth_hz: float = 0.5,
) -> FloorTouchTrajectory:
    """Draw a :class:`FloorTouchTrajectory` (module docstring) pressing until ``duration_s``."""
    if not (math.isfinite(bandwidth_hz) and 0.05 < bandwidth_hz <= 5.0):
        raise ConfigurationError(f"bandwidth_hz must be in (0.05, 5], got {bandwidth_hz}")
    if not (math.isfinite(duration_s) and duration_s > 0.0):
        raise ConfigurationError(f"duration_s must be > 0, got {duration_s}")
    rng = np.random.default_rng(np.random.SeedSequence([3, int(seed)]))
    shape = (2, _N_COMPONENTS)
    frequencies = rng.uniform(0.03, bandwidth_hz, size=shape)
    amplitudes = rng.rayleigh(1.0, size=shape)
    amplitudes /= np.sqrt(0.5 * np.sum(amplitudes**2, axis=1, keepdims=True))
    phases = rng.uniform(0.0, 2.0 * math.pi, size=shape)
    hover = rng.uniform(0.006, 0.012)
    times, heights = [0.0, _FIRST_PRESS_S], [hover, hover]
    still_starts, still_ends = [], []
    t = _FIRST_PRESS_S
    while t < duration_s:
        depth = -rng.uniform(0.0035, 0.0085)
        hover = rng.uniform(0.006, 0.012)
        still = rng.uniform() < 0.5
        stay = rng.uniform(0.8, 1.4) if still else rng.uniform(0.3, 0.7)
        t += rng.uniform(0.5, 0.9)
        if still:
            still_starts.append(t)
            still_ends.append(t + stay)
        for step, height in (
            (0.0, depth),
            (stay, depth),
            (rng.uniform(0.5, 0.9), hover),
            (rng.uniform(1.0, 2.0), hover),
        ):
            t += step
            times.append(t)
            heights.append(height)
    return FloorTouchTrajectory(
        frequencies, amplitudes, phases, np.array(times), np.array(heights),
        np.array(still_starts), np.array(still_ends), surface_y_m=surface_y_m,
    )  # fmt: skip


def floor_touch_protocol(
    duration_s: float = 60.0,
    seed: int = 0,
    *,
    surface_y_m: float = -0.06,
    contact: PlaneContact | HuntCrossleyFloor | None = None,
    **options: Unpack[SessionOptions],
) -> SimulatedSession:
    """Teleoperation touching a soft floor (module docstring) on either plant family.

    ``contact`` defaults to the family's surface at ``surface_y_m``
    (:func:`~teleop_force.simulation.families.default_contact`); ``options``
    (:class:`~teleop_force.simulation.session.SessionOptions`) go to
    :func:`~teleop_force.simulation.session.simulate_session`.
    """
    family = options.get("family", PlantFamily.ONE)
    floor = contact if contact is not None else default_contact(family, surface_y_m)
    return simulate_session(
        floor_touch_trajectory(seed, duration_s=duration_s, surface_y_m=surface_y_m),
        duration_s,
        seed,
        contact=floor,
        name="floor-touch",
        **options,
    )
