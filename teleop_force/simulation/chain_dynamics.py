"""Plant family two's own rigid-body dynamics: a compiled Newton-Euler pass over a revolute chain.

Independent of pinocchio's algorithms (pinocchio only supplies the description's numbers, once)
and of the estimator's :mod:`~teleop_force.estimation.rigid_chain`, so a model identified on
plant family two is not checked against the code it was built with. In world-frame vectors,
joint ``i`` with unit axis ``z_i``, origin ``o_i``, centre of mass ``c_i``::

    w_i = w_{i-1} + z_i qd_i
    a_i = a_{i-1} + z_i qdd_i + w_{i-1} x z_i qd_i                   angular acceleration
    A_i = A_{i-1} + a_{i-1} x r_i + w_{i-1} x (w_{i-1} x r_i)        origin, r_i = o_i - o_{i-1}
    f_i = m_i (A_i + a_i x s_i + w_i x (w_i x s_i))                  s_i = c_i - o_i
    n_i = I_i a_i + w_i x I_i w_i                                    about c_i, world frame
    N_i = n_i + s_i x f_i + N_{i+1} + r_{i+1} x F_{i+1},  F_i = f_i + F_{i+1},  tau_i = z_i . N_i

with ``A_0 = -g`` (gravity as a base acceleration). ``tau(q, qd, 0)`` is the bias ``C qd + N``;
the mass matrix's column ``j`` is ``tau(q, 0, e_j)`` without gravity. The tip position is
``o_n + R_n p_tip`` and its Jacobian column ``z_i x (p - o_i)``. Motor coordinates follow
:mod:`~teleop_force.robots.description`: ``M = T' M T + rotor``, ``h = T' h``, ``J = J T``.

:func:`chain_table` packs a 3-joint serial
:class:`~teleop_force.robots.description.RobotDescription` (revolute joints, any axes and
placements) into the flat table the kernels read.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from teleop_force.compiled import njit_cached
from teleop_force.errors import ModelError
from teleop_force.robots.description import RobotDescription

#: Per-joint row of the table: placement rotation (9), translation (3), axis (3), mass (1),
#: centre of mass (3), rotational inertia about it (9), all in the joint's own frame.
_ROW = 28
#: After the joint rows: the tip translation in the last joint's frame (3), gravity (3),
#: coupling T (9, row-major) and rotor inertias (3).
_TAIL = 18
N_JOINTS = 3
TABLE_SIZE = N_JOINTS * _ROW + _TAIL


def chain_table(description: RobotDescription, *, gravity: bool = True) -> np.ndarray:
    """Pack a 3-joint serial revolute description for :func:`motor_terms` (read-only vector).

    Raises:
        ModelError: for a description that is not a 3-joint serial chain of revolute joints
            with a tip frame on its last joint.

    """
    model = description.model
    if model is None or description.n_joints != N_JOINTS or model.nv != N_JOINTS:
        raise ModelError("plant family two needs a 3-joint serial description with a model")
    if description.tip_frame is None:
        raise ModelError(f"{description.name}: plant family two needs a tip frame")
    table = np.zeros(TABLE_SIZE)
    for i in range(1, model.njoints):
        if model.parents[i] != i - 1:
            raise ModelError(f"{description.name}: joint {i} is not in a serial chain")
        joint = model.joints[i]
        axis = _revolute_axis(joint)
        placement = model.jointPlacements[i]
        inertia = model.inertias[i]
        row = (i - 1) * _ROW
        table[row : row + 9] = np.asarray(placement.rotation).ravel()
        table[row + 9 : row + 12] = placement.translation
        table[row + 12 : row + 15] = axis
        table[row + 15] = inertia.mass
        table[row + 16 : row + 19] = inertia.lever
        table[row + 19 : row + 28] = np.asarray(inertia.inertia).ravel()
    frame = model.frames[model.getFrameId(description.tip_frame)]
    if frame.parentJoint != N_JOINTS:
        raise ModelError(f"{description.name}: the tip frame must be on the last joint")
    tail = N_JOINTS * _ROW
    table[tail : tail + 3] = frame.placement.translation
    if gravity:
        table[tail + 3 : tail + 6] = model.gravity.linear
    table[tail + 6 : tail + 15] = np.asarray(description.coupling, dtype=float).ravel()
    table[tail + 15 : tail + 18] = description.rotor_inertia_kgm2
    table.flags.writeable = False
    return table


def _revolute_axis(joint: pin.JointModel) -> np.ndarray:
    name = joint.shortname()
    axes = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0)}
    axes["JointModelRZ"] = (0.0, 0.0, 1.0)
    if name in axes:
        return np.array(axes[name])
    if name == "JointModelRevoluteUnaligned":
        axis = np.array(joint.extract().axis, dtype=float)
        return axis / np.linalg.norm(axis)
    raise ModelError(f"plant family two supports revolute joints only, got {name}")


@njit_cached()
def _cross_into(
    a0: float, a1: float, a2: float, b0: float, b1: float, b2: float, out: np.ndarray, row: int
) -> None:  # pragma: no cover - compiled
    out[row, 0] = a1 * b2 - a2 * b1
    out[row, 1] = a2 * b0 - a0 * b2
    out[row, 2] = a0 * b1 - a1 * b0


@njit_cached()
def _kinematics(
    table: np.ndarray,
    q_model: np.ndarray,
    rotation: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    arms: np.ndarray,
    inertias: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """World rotation, origin, axis, centre-of-mass arm and inertia of every joint frame."""
    parent = np.eye(3)
    for i in range(N_JOINTS):
        row = i * _ROW
        angle = q_model[i]
        c, s = math.cos(angle), math.sin(angle)
        x, y, z = table[row + 12], table[row + 13], table[row + 14]
        k = 1.0 - c
        turn = np.empty((3, 3))  # Rodrigues' rotation about the axis
        turn[0, 0] = c + x * x * k
        turn[0, 1] = x * y * k - z * s
        turn[0, 2] = x * z * k + y * s
        turn[1, 0] = y * x * k + z * s
        turn[1, 1] = c + y * y * k
        turn[1, 2] = y * z * k - x * s
        turn[2, 0] = z * x * k - y * s
        turn[2, 1] = z * y * k + x * s
        turn[2, 2] = c + z * z * k
        placed = np.empty((3, 3))
        for a in range(3):
            total = 0.0
            for b in range(3):
                total += parent[a, b] * table[row + 9 + b]
            origin[i, a] = (origin[i - 1, a] if i > 0 else 0.0) + total
            for b in range(3):
                total = 0.0
                for m in range(3):
                    total += parent[a, m] * table[row + 3 * m + b]
                placed[a, b] = total
        for a in range(3):
            for b in range(3):
                total = 0.0
                for m in range(3):
                    total += placed[a, m] * turn[m, b]
                rotation[i, a, b] = total
        for a in range(3):
            axis = 0.0
            arm = 0.0
            for b in range(3):
                axis += rotation[i, a, b] * table[row + 12 + b]
                arm += rotation[i, a, b] * table[row + 16 + b]
            axes[i, a] = axis
            arms[i, a] = arm
        # I_world = R I R'
        for a in range(3):
            for b in range(3):
                total = 0.0
                for m in range(3):
                    for l in range(3):  # noqa: E741
                        total += rotation[i, a, m] * table[row + 19 + 3 * m + l] * rotation[i, b, l]
                inertias[i, a, b] = total
        for a in range(3):
            for b in range(3):
                parent[a, b] = rotation[i, a, b]


@njit_cached()
def _newton_euler(
    table: np.ndarray,
    origin: np.ndarray,
    axes: np.ndarray,
    arms: np.ndarray,
    inertias: np.ndarray,
    qd: np.ndarray,
    qdd: np.ndarray,
    base_acceleration: np.ndarray,
    scratch: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Joint torques (model coordinates) for ``qd``, ``qdd`` and a base acceleration.

    ``scratch`` is (4 + 2 n, 3): work rows.
    """
    n = N_JOINTS
    w = np.zeros(3)
    al = np.zeros(3)
    acc = np.empty(3)
    for a in range(3):
        acc[a] = base_acceleration[a]
    # scratch rows: 0, 1 temporaries; 2 .. 2+n forces; 2+n .. 2+2n moments about the com
    f_row, n_row = 2, 2 + n
    for i in range(n):
        r0 = origin[i, 0] - (origin[i - 1, 0] if i > 0 else 0.0)
        r1 = origin[i, 1] - (origin[i - 1, 1] if i > 0 else 0.0)
        r2 = origin[i, 2] - (origin[i - 1, 2] if i > 0 else 0.0)
        _cross_into(al[0], al[1], al[2], r0, r1, r2, scratch, 0)
        _cross_into(w[0], w[1], w[2], r0, r1, r2, scratch, 1)
        for a in range(3):
            acc[a] += scratch[0, a]
        _cross_into(w[0], w[1], w[2], scratch[1, 0], scratch[1, 1], scratch[1, 2], scratch, 0)
        for a in range(3):
            acc[a] += scratch[0, a]
        z0, z1, z2 = axes[i, 0], axes[i, 1], axes[i, 2]
        _cross_into(w[0], w[1], w[2], z0, z1, z2, scratch, 0)
        for a in range(3):
            al[a] += axes[i, a] * qdd[i] + scratch[0, a] * qd[i]
            w[a] += axes[i, a] * qd[i]
        s0, s1, s2 = arms[i, 0], arms[i, 1], arms[i, 2]
        mass = table[i * _ROW + 15]
        _cross_into(al[0], al[1], al[2], s0, s1, s2, scratch, 0)
        _cross_into(w[0], w[1], w[2], s0, s1, s2, scratch, 1)
        for a in range(3):
            scratch[f_row + i, a] = acc[a] + scratch[0, a]
        _cross_into(w[0], w[1], w[2], scratch[1, 0], scratch[1, 1], scratch[1, 2], scratch, 0)
        for a in range(3):
            scratch[f_row + i, a] = mass * (scratch[f_row + i, a] + scratch[0, a])
        spin0 = inertias[i, 0, 0] * w[0] + inertias[i, 0, 1] * w[1] + inertias[i, 0, 2] * w[2]
        spin1 = inertias[i, 1, 0] * w[0] + inertias[i, 1, 1] * w[1] + inertias[i, 1, 2] * w[2]
        spin2 = inertias[i, 2, 0] * w[0] + inertias[i, 2, 1] * w[1] + inertias[i, 2, 2] * w[2]
        _cross_into(w[0], w[1], w[2], spin0, spin1, spin2, scratch, 0)
        for a in range(3):
            scratch[n_row + i, a] = (
                inertias[i, a, 0] * al[0]
                + inertias[i, a, 1] * al[1]
                + inertias[i, a, 2] * al[2]
                + scratch[0, a]
            )
    f = np.zeros(3)
    m = np.zeros(3)
    for i in range(n - 1, -1, -1):
        if i < n - 1:
            _cross_into(
                origin[i + 1, 0] - origin[i, 0],
                origin[i + 1, 1] - origin[i, 1],
                origin[i + 1, 2] - origin[i, 2],
                f[0], f[1], f[2], scratch, 0,
            )  # fmt: skip
            for a in range(3):
                m[a] += scratch[0, a]
        _cross_into(
            arms[i, 0], arms[i, 1], arms[i, 2],
            scratch[f_row + i, 0], scratch[f_row + i, 1], scratch[f_row + i, 2], scratch, 1,
        )  # fmt: skip
        for a in range(3):
            m[a] += scratch[n_row + i, a] + scratch[1, a]
            f[a] += scratch[f_row + i, a]
        out[i] = axes[i, 0] * m[0] + axes[i, 1] * m[1] + axes[i, 2] * m[2]


@njit_cached()
def motor_terms(
    table: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    mass: np.ndarray,
    bias: np.ndarray,
    jacobian: np.ndarray,
    tip: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Fill ``M`` (3, 3), ``C qd + N`` (3,), tip ``J`` (3, 3) and ``p`` (3,) at motor ``q``, ``qd``.

    Everything in motor coordinates (module docstring); written into the given arrays.
    """
    n = N_JOINTS
    tail = n * _ROW
    c = tail + 6  # coupling, row-major
    q_model = np.empty(n)
    qd_model = np.empty(n)
    for i in range(n):
        total_q = 0.0
        total_v = 0.0
        for j in range(n):
            total_q += table[c + n * i + j] * q[j]
            total_v += table[c + n * i + j] * qd[j]
        q_model[i] = total_q
        qd_model[i] = total_v
    rotation = np.empty((n, 3, 3))
    origin = np.empty((n, 3))
    axes = np.empty((n, 3))
    arms = np.empty((n, 3))
    inertias = np.empty((n, 3, 3))
    _kinematics(table, q_model, rotation, origin, axes, arms, inertias)
    scratch = np.empty((2 + 2 * n, 3))
    base = np.empty(3)
    for a in range(3):
        base[a] = -table[tail + 3 + a]
    zeros = np.zeros(n)
    h_model = np.empty(n)
    _newton_euler(table, origin, axes, arms, inertias, qd_model, zeros, base, scratch, h_model)
    m_model = np.empty((n, n))
    column = np.empty(n)
    unit = np.zeros(n)
    no_gravity = np.zeros(3)
    for j in range(n):
        unit[:] = 0.0
        unit[j] = 1.0
        _newton_euler(table, origin, axes, arms, inertias, zeros, unit, no_gravity, scratch, column)
        for i in range(n):
            m_model[i, j] = column[i]
    for i in range(n):
        for j in range(n):
            total = 0.0
            for a in range(n):
                for b in range(n):
                    total += table[c + n * a + i] * m_model[a, b] * table[c + n * b + j]
            mass[i, j] = total + (table[tail + 15 + i] if i == j else 0.0)
        total = 0.0
        for a in range(n):
            total += table[c + n * a + i] * h_model[a]
        bias[i] = total
    last = n - 1
    for a in range(3):
        total = origin[last, a]
        for b in range(3):
            total += rotation[last, a, b] * table[tail + b]
        tip[a] = total
    jac_model = np.empty((3, n))
    for i in range(n):
        _cross_into(
            axes[i, 0], axes[i, 1], axes[i, 2],
            tip[0] - origin[i, 0], tip[1] - origin[i, 1], tip[2] - origin[i, 2], scratch, 0,
        )  # fmt: skip
        for a in range(3):
            jac_model[a, i] = scratch[0, a]
    for a in range(3):
        for j in range(n):
            total = 0.0
            for i in range(n):
                total += jac_model[a, i] * table[c + n * i + j]
            jacobian[a, j] = total
