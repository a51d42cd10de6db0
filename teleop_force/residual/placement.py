"""Where a found effect acts: on its motor joint alone, or at a model joint through the coupling.

With friction in model coordinates the robot's physics is taken to act at its model joints
first: an effect found on motor ``j`` is tried as a torque at model joint ``j``, reaching the
motors through the coupling, ``T^T e_j`` (row ``j`` of the coupling,
:attr:`~teleop_force.identification.effects.FoundEffect.reach`), like the friction.
"""

from __future__ import annotations

import numpy as np

from teleop_force.robots.description import RobotDescription


def placed_columns(cols: np.ndarray, joint: int, reach: np.ndarray | None, n: int) -> np.ndarray:
    """Candidate columns ``(rows, k)`` on ``joint``, or spread by ``reach``: ``(rows, n, k)``."""
    weights = np.eye(n)[joint] if reach is None else reach
    return cols[:, None, :] * weights[None, :, None]


def effect_reaches(description: RobotDescription) -> list[np.ndarray | None]:
    """Per motor ``j``, the reach of a torque at model joint ``j``: row ``j`` of the coupling.

    Scaled so the weight on motor ``j`` is 1; None where that torque lands on motor ``j`` alone
    (or the coupling has no row ``j`` with a weight on it).
    """
    coupling = description.coupling
    out: list[np.ndarray | None] = []
    for j in range(description.n_joints):
        if j >= coupling.shape[0] or coupling[j, j] == 0.0:
            out.append(None)
            continue
        row = coupling[j] / coupling[j, j]
        out.append(row if np.count_nonzero(row) > 1 else None)
    return out
