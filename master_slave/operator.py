"""The simulated operator: where the hand holding the master's stylus wants it to be.

Two scripts: ``palpation`` (approach a soft tissue, press into it, slide, release, repeated at
random spots: :func:`~teleop_force.simulation.palpation_trajectory`, whose tip positions are
meant for the slave's tissue at ``y = surface_y_m``) and ``random`` (band-limited random
teleoperation motion, :func:`~teleop_force.simulation.teleoperation_trajectory`). The
reference is sampled in blocks of ``block`` ticks (vectorised), so one tick costs an array
lookup instead of an inverse-kinematics solve. Blocks are short (100 ticks by default): the
tick that samples one pays for all of it, and a 1000-tick block of the random script costs
3.7 ms, several periods of the 1 kHz loop (100 ticks: 0.3 ms; palpation 0.5 vs 0.13 ms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from teleop_force.errors import ConfigurationError
from teleop_force.simulation import palpation_trajectory, teleoperation_trajectory
from teleop_force.simulation.trajectories import Trajectory, omni_inverse_kinematics

MOTIONS: Final = ("palpation", "random")
#: Length of the palpation script when the run has no duration (the hand holds still after).
UNBOUNDED_SCRIPT_S: Final = 3600.0
#: Surface of the slave's tissue the palpation script is written for [m] (base frame y).
DEFAULT_SURFACE_Y_M: Final = -0.06
#: Start of the palpation script: hovering 2 cm above the tissue, 12 cm in front of the base.
HOVER_HEIGHT_M: Final = 0.02
HOVER_Z_M: Final = 0.12


def palpation_start_rad(surface_y_m: float = DEFAULT_SURFACE_Y_M) -> np.ndarray:
    """Joint angles of the palpation script's start (hovering above the tissue)."""
    point = np.array([0.0, surface_y_m + HOVER_HEIGHT_M, HOVER_Z_M])
    return omni_inverse_kinematics(point)


@dataclass(frozen=True)
class OperatorConfig:
    """What the simulated operator does.

    Attributes:
        motion: ``palpation`` or ``random``.
        seed: Seed of the script (spots, headings, random motion).
        duration_s: Length of the run (``None``: unbounded).
        surface_y_m: Height of the tissue the palpation script presses into.
        depth_m: How far below the undeformed surface the hand aims.

    """

    motion: str = "palpation"
    seed: int = 0
    duration_s: float | None = None
    surface_y_m: float = DEFAULT_SURFACE_Y_M
    depth_m: float = 0.006

    def __post_init__(self) -> None:
        """Check the motion kind and the ranges."""
        if self.motion not in MOTIONS:
            raise ConfigurationError(f"motion must be one of {', '.join(MOTIONS)}: {self.motion!r}")
        if self.seed < 0:
            raise ConfigurationError(f"seed must be >= 0, got {self.seed}")
        if self.duration_s is not None and not (
            math.isfinite(self.duration_s) and self.duration_s > 0.0
        ):
            raise ConfigurationError(f"duration_s must be > 0, got {self.duration_s}")
        if not -0.15 < self.surface_y_m < 0.05:
            raise ConfigurationError(
                f"surface_y_m must be in (-0.15, 0.05), got {self.surface_y_m}"
            )

    def trajectory(self) -> Trajectory:
        """Return the joint reference of the hand."""
        if self.motion == "random":
            return teleoperation_trajectory(self.seed)
        length = UNBOUNDED_SCRIPT_S if self.duration_s is None else self.duration_s + 10.0
        return palpation_trajectory(
            length, self.seed, surface_y_m=self.surface_y_m, depth_m=self.depth_m
        )


class ScriptedOperator:
    """Joint reference ``(q, qd)`` of the operator's hand at tick ``k`` (period ``dt``)."""

    def __init__(self, config: OperatorConfig, period_s: float, block: int = 100) -> None:
        """Prepare the script; nothing is sampled until the first :meth:`reference`."""
        if not period_s > 0.0 or block < 1:
            raise ConfigurationError("period_s must be > 0 and block >= 1")
        self.config = config
        self.trajectory = config.trajectory()
        self._period_s = float(period_s)
        self._block = int(block)
        self._first = -1
        self._q = np.zeros((0, 3))
        self._qd = np.zeros((0, 3))

    def start_rad(self) -> np.ndarray:
        """Where the hand starts (tick 0)."""
        q, _ = self.trajectory.sample(0.0)
        return np.asarray(q, dtype=float)

    def reference(self, tick: int) -> tuple[np.ndarray, np.ndarray]:
        """Hand position and velocity at ``tick`` (non-decreasing ticks are cheapest)."""
        offset = tick - self._first
        if self._first < 0 or not 0 <= offset < self._q.shape[0]:
            t = (tick + np.arange(self._block)) * self._period_s
            self._q, self._qd = self.trajectory.sample(t)
            self._first = tick
            offset = 0
        return self._q[offset], self._qd[offset]
