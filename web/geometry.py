"""Omni geometry for drawing: joint positions, the base-to-viser frame map, link poses.

Frames (docs/conventions.md): the Omni *base* frame has y up, z toward the user and
x = y cross z. viser's world is z up. The dashboard draws in world coordinates

    world = R_WORLD_BASE @ base,   R_WORLD_BASE = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]

i.e. world x = base x, world y = -base z (the user stands at world -y), world z = base y (up).
It is a proper rotation (+90 degrees about x), so handedness and force directions are kept.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from teleop_force.robots.omni import FOREARM_LENGTH_M, UPPER_ARM_LENGTH_M

#: Rotation taking Omni base-frame vectors to viser world vectors.
R_WORLD_BASE: Final = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
R_WORLD_BASE.flags.writeable = False


def base_to_world(points: np.ndarray) -> np.ndarray:
    """Map base-frame points or vectors (..., 3) to viser world coordinates (..., 3)."""
    return np.asarray(points, dtype=float) @ R_WORLD_BASE.T


def omni_joint_points(
    q: np.ndarray,
    l1: float = UPPER_ARM_LENGTH_M,
    l2: float = FOREARM_LENGTH_M,
) -> np.ndarray:
    """Shoulder, elbow and tip positions in the base frame, shape (3, 3) [m].

    ``q = (q1, q2, q3)`` in motor coordinates (q3 is the absolute forearm angle). The shoulder
    is the base-frame origin; the tip is the same point as
    :func:`teleop_force.robots.omni.tip_position_formula`.
    """
    q1, q2, q3 = (float(v) for v in np.asarray(q, dtype=float)[:3])
    s1, c1 = np.sin(q1), np.cos(q1)
    elbow = np.array([-s1 * l1 * np.cos(q2), l1 * np.sin(q2), c1 * l1 * np.cos(q2)])
    forearm = np.array([-s1 * l2 * np.sin(q3), -l2 * np.cos(q3), c1 * l2 * np.sin(q3)])
    return np.stack((np.zeros(3), elbow, elbow + forearm))


def quat_z_to(direction: np.ndarray) -> np.ndarray:
    """Return the unit quaternion ``(w, x, y, z)`` rotating the +z axis onto ``direction``."""
    v = np.asarray(direction, dtype=float)
    norm = float(np.linalg.norm(v))
    if not np.isfinite(norm) or norm < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    v = v / norm
    q = np.array([1.0 + v[2], -v[1], v[0], 0.0])  # (1 + z.v, z x v), then normalised
    size = float(np.linalg.norm(q))
    if size < 1e-12:  # exactly opposite to +z: half a turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    return q / size


def rotate_by_quat(quat: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """Rotate ``vector`` (3,) by the unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = np.asarray(quat, dtype=float)
    u = np.array([x, y, z])
    v = np.asarray(vector, dtype=float)
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


def quat_about(axis: np.ndarray | tuple[float, float, float], angle: float) -> np.ndarray:
    """Return the unit quaternion ``(w, x, y, z)`` of a rotation by ``angle`` about ``axis``."""
    u = np.asarray(axis, dtype=float)
    u = u / np.linalg.norm(u)
    half = 0.5 * float(angle)
    return np.concatenate(([np.cos(half)], np.sin(half) * u))


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return the Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    w1, x1, y1, z1 = np.asarray(a, dtype=float)
    w2, x2, y2, z2 = np.asarray(b, dtype=float)
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def arm_frame_quats(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local rotations of the three frames of a drawn arm, in the Omni base frame.

    The arm is a kinematic tree whose links lie along their frame's +z axis:

    * ``yaw``: about base +y by ``-q1`` (the arm points along +z at ``q1 = 0``, toward -x for
      ``q1 > 0``);
    * ``shoulder`` (child of yaw): about +x by ``-q2`` (the upper arm rises with ``q2``);
    * ``elbow`` (child of shoulder, ``l1`` along its +z): about +x by ``pi/2 - q3 + q2``, so
      the forearm hangs straight down at ``q3 = 0`` whatever ``q2`` (q3 is absolute).

    Three rotations per arm and frame is all a pose update has to send.
    """
    q1, q2, q3 = (float(v) for v in np.asarray(q, dtype=float)[:3])
    return (
        quat_about((0.0, 1.0, 0.0), -q1),
        quat_about((1.0, 0.0, 0.0), -q2),
        quat_about((1.0, 0.0, 0.0), np.pi / 2 - q3 + q2),
    )


def link_pose(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Pose of a cylinder (axis along its local z, centred) spanning ``start`` to ``end``.

    Returns ``(position, wxyz, length)`` in the frame of the two points.
    """
    a = np.asarray(start, dtype=float)
    b = np.asarray(end, dtype=float)
    return (a + b) / 2.0, quat_z_to(b - a), float(np.linalg.norm(b - a))


def force_arrow(
    tip_base: np.ndarray, force_n: np.ndarray, metres_per_newton: float
) -> np.ndarray | None:
    """World-frame arrow ``(1, 2, 3)`` from the tip along the force, or ``None`` if not drawable.

    ``force_n`` is the tip force on the environment in the base frame; NaN (no estimate) or
    a force too small to see gives ``None``.
    """
    f = np.asarray(force_n, dtype=float)
    if f.shape != (3,) or not np.all(np.isfinite(f)):
        return None
    if float(np.linalg.norm(f)) * metres_per_newton < 1e-4:
        return None
    start = base_to_world(tip_base)
    return np.stack((start, start + base_to_world(f) * metres_per_newton))[None, :, :]


__all__ = [
    "R_WORLD_BASE",
    "arm_frame_quats",
    "base_to_world",
    "force_arrow",
    "link_pose",
    "omni_joint_points",
    "quat_about",
    "quat_mul",
    "quat_z_to",
    "rotate_by_quat",
]
