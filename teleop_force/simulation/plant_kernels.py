"""The simulated Omni's per-tick work, compiled: one control tick, the rigid-body refresh, clipping.

:class:`~teleop_force.simulation.plant.SimulatedOmni` keeps its whole state in one float
workspace (offsets below) and calls, per tick, :func:`integrate_tick` (actuator noise, the
semi-implicit sub-steps with linearly implicit friction, springs, contact and effects), then
pinocchio once at the new state, then :func:`refresh_terms` (the motor-coordinate ``M``,
``C qd + N``, tip Jacobian and position, the encoder reading and the contact force a
:meth:`~teleop_force.simulation.plant.SimulatedOmni.read` returns). Formulas and their order of
operations are those of the plant's documented dynamics; the friction, contact and effect terms
are the single compiled definitions in their own modules.
"""

from __future__ import annotations

import math

import numpy as np

from teleop_force.compiled import njit_cached
from teleop_force.simulation.contact import plane_contact_force
from teleop_force.simulation.effects import effects_torque_slope
from teleop_force.simulation.true_friction import true_friction_floats

# Workspace offsets (each a 3-vector unless noted). A reading (encoder angles, commanded torque,
# contact force) is adjacent: READING, 9 floats, copied at once.
Q = 0
QD = 3
Q_MODEL = 6
QD_MODEL = 9
TAU_APPLIED = 12
MASS = 15  # 3 x 3, row-major
BIAS = 24
JACOBIAN = 27  # 3 x 3, row-major
TIP = 36
READING = 39
Q_MEASURED = 39
TAU_COMMANDED = 42
FORCE = 45
TIME = 48  # one float
WORKSPACE_SIZE = 49

# Constant offsets.
SUBSTEP_S = 0
SUBSTEPS = 1
PERIOD_S = 2
RESOLUTION_RAD = 3
SPRINGS = 4  # stiffness, rest angle per joint (6 floats)
FILLS_BOTH_TRIANGLES = 10
COUPLING = 11  # 3 x 3, row-major
ROTOR = 20  # 3 floats
CONSTANTS_SIZE = 23


@njit_cached()
def integrate_tick(
    ws: np.ndarray,
    constants: np.ndarray,
    friction: np.ndarray,
    contact: np.ndarray,
    effects: np.ndarray,
    noise: np.ndarray,
    noise_row: int,
) -> bool:  # pragma: no cover - compiled
    """Advance the workspace by one control tick; ``False`` (state kept) if it diverged.

    ``friction`` and ``contact`` are the packed parameters (empty: none), ``effects`` an
    effect table (0 rows: none) and ``noise[noise_row]`` the tick's actuator noise
    (``noise_row < 0``: none). The applied torque is written even when the tick diverges.
    """
    for i in range(3):
        extra = noise[noise_row, i] if noise_row >= 0 else 0.0
        ws[TAU_APPLIED + i] = ws[TAU_COMMANDED + i] + extra
    h = constants[SUBSTEP_S]
    m00, m01, m02 = ws[MASS], ws[MASS + 1], ws[MASS + 2]
    m10, m11, m12 = ws[MASS + 3], ws[MASS + 4], ws[MASS + 5]
    m20, m21, m22 = ws[MASS + 6], ws[MASS + 7], ws[MASS + 8]
    t0, t1, t2 = ws[TAU_APPLIED], ws[TAU_APPLIED + 1], ws[TAU_APPLIED + 2]
    # Everything that does not change within the tick: tau - (C qd + N).
    r0, r1, r2 = t0 - ws[BIAS], t1 - ws[BIAS + 1], t2 - ws[BIAS + 2]
    j00, j01, j02 = ws[JACOBIAN], ws[JACOBIAN + 1], ws[JACOBIAN + 2]
    j10, j11, j12 = ws[JACOBIAN + 3], ws[JACOBIAN + 4], ws[JACOBIAN + 5]
    j20, j21, j22 = ws[JACOBIAN + 6], ws[JACOBIAN + 7], ws[JACOBIAN + 8]
    px0, py0, pz0 = ws[TIP], ws[TIP + 1], ws[TIP + 2]
    s0, s1, s2 = ws[Q], ws[Q + 1], ws[Q + 2]
    q0, q1, q2 = s0, s1, s2
    v0, v1, v2 = ws[QD], ws[QD + 1], ws[QD + 2]
    spring0, rest0 = constants[SPRINGS], constants[SPRINGS + 1]
    spring1, rest1 = constants[SPRINGS + 2], constants[SPRINGS + 3]
    spring2, rest2 = constants[SPRINGS + 4], constants[SPRINGS + 5]
    has_friction = friction.size > 0
    has_contact = contact.size > 0
    has_effects = effects.shape[0] > 0
    t = ws[TIME]
    for _ in range(int(constants[SUBSTEPS])):
        a0, a1, a2 = r0, r1, r2
        d00 = d11 = d12 = d21 = d22 = 0.0
        if has_friction:
            f0, f1, f2, d00, d11, d12, d21, d22 = true_friction_floats(friction, v0, v1, v2)
            a0 -= f0
            a1 -= f1
            a2 -= f2
        a0 -= spring0 * (q0 - rest0)
        a1 -= spring1 * (q1 - rest1)
        a2 -= spring2 * (q2 - rest2)
        if has_contact:
            dq0, dq1, dq2 = q0 - s0, q1 - s1, q2 - s2
            fx, fy, fz = plane_contact_force(
                contact,
                px0 + j00 * dq0 + j01 * dq1 + j02 * dq2,
                py0 + j10 * dq0 + j11 * dq1 + j12 * dq2,
                pz0 + j20 * dq0 + j21 * dq1 + j22 * dq2,
                j00 * v0 + j01 * v1 + j02 * v2,
                j10 * v0 + j11 * v1 + j12 * v2,
                j20 * v0 + j21 * v1 + j22 * v2,
            )
            a0 += j00 * fx + j10 * fy + j20 * fz
            a1 += j01 * fx + j11 * fy + j21 * fz
            a2 += j02 * fx + j12 * fy + j22 * fz
        if has_effects:
            e0, e1, e2, g0, g1, g2 = effects_torque_slope(
                effects, t, q0, q1, q2, v0, v1, v2, t0, t1, t2
            )
            a0 -= e0
            a1 -= e1
            a2 -= e2
            d00 += g0
            d11 += g1
            d22 += g2
        # Solve (M + h D) qdd = a by Cramer's rule.
        c00, c01, c02 = m00 + h * d00, m01, m02
        c10, c11, c12 = m10, m11 + h * d11, m12 + h * d12
        c20, c21, c22 = m20, m21 + h * d21, m22 + h * d22
        k0 = c11 * c22 - c12 * c21
        k1 = c12 * c20 - c10 * c22
        k2 = c10 * c21 - c11 * c20
        inv_det = 1.0 / (c00 * k0 + c01 * k1 + c02 * k2)
        qdd0 = (a0 * k0 + c01 * (a2 * c12 - a1 * c22) + c02 * (a1 * c21 - a2 * c11)) * inv_det
        qdd1 = (c00 * (a1 * c22 - a2 * c12) + a0 * k1 + c02 * (a2 * c10 - a1 * c20)) * inv_det
        qdd2 = (c00 * (a2 * c11 - a1 * c21) + c01 * (a1 * c20 - a2 * c10) + a0 * k2) * inv_det
        v0 += h * qdd0
        v1 += h * qdd1
        v2 += h * qdd2
        q0 += h * v0
        q1 += h * v1
        q2 += h * v2
        t += h
    for x in (q0, q1, q2, v0, v1, v2):
        if not math.isfinite(x):
            return False
    ws[Q], ws[Q + 1], ws[Q + 2] = q0, q1, q2
    ws[QD], ws[QD + 1], ws[QD + 2] = v0, v1, v2
    ws[TIME] += constants[PERIOD_S]
    to_model_coordinates(ws, constants)
    return True


@njit_cached()
def to_model_coordinates(ws: np.ndarray, constants: np.ndarray) -> None:  # pragma: no cover
    """Write ``q_model = T q`` and ``qd_model = T qd`` into the workspace (pinocchio's input)."""
    for i in range(3):
        row = COUPLING + 3 * i
        ws[Q_MODEL + i] = (
            constants[row] * ws[Q] + constants[row + 1] * ws[Q + 1] + constants[row + 2] * ws[Q + 2]
        )
        ws[QD_MODEL + i] = (
            constants[row] * ws[QD]
            + constants[row + 1] * ws[QD + 1]
            + constants[row + 2] * ws[QD + 2]
        )


@njit_cached()
def refresh_terms(
    ws: np.ndarray,
    constants: np.ndarray,
    contact: np.ndarray,
    mass_model: np.ndarray,
    bias_model: np.ndarray,
    jacobian_6: np.ndarray,
    tip: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """From pinocchio's terms at the current state, fill the tick's terms and reading.

    ``mass_model`` (3, 3), ``bias_model`` (3,), ``jacobian_6`` (6, 3, LOCAL_WORLD_ALIGNED) and
    ``tip`` (3,) are in model coordinates; the workspace gets ``M = T' M T + rotor``,
    ``C qd + N = T' nle``, ``J = J_lin T``, ``p``, the encoder reading (angles rounded to the
    resolution) and the force of the tip on the environment (zeros without ``contact``).
    """
    both = constants[FILLS_BOTH_TRIANGLES] != 0.0
    product = np.empty((3, 3))  # T' M
    for i in range(3):
        for j in range(3):
            total = 0.0
            for k in range(3):
                m_kj = mass_model[k, j] if (both or k <= j) else mass_model[j, k]
                total += constants[COUPLING + 3 * k + i] * m_kj
            product[i, j] = total
    for i in range(3):
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += product[i, k] * constants[COUPLING + 3 * k + j]
            if i == j:
                total += constants[ROTOR + i]
            ws[MASS + 3 * i + j] = total
    for i in range(3):
        total = 0.0
        for k in range(3):
            total += constants[COUPLING + 3 * k + i] * bias_model[k]
        ws[BIAS + i] = total
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += jacobian_6[i, k] * constants[COUPLING + 3 * k + j]
            ws[JACOBIAN + 3 * i + j] = total
        ws[TIP + i] = tip[i]
    resolution = constants[RESOLUTION_RAD]
    for i in range(3):
        q = ws[Q + i]
        ws[Q_MEASURED + i] = q if resolution == 0.0 else np.rint(q / resolution) * resolution
    contact_force_into(ws, contact)


@njit_cached()
def contact_force_into(ws: np.ndarray, contact: np.ndarray) -> None:  # pragma: no cover
    """Write the force of the tip on the environment at the workspace's state (``-F_env``)."""
    if contact.size == 0:
        ws[FORCE], ws[FORCE + 1], ws[FORCE + 2] = 0.0, 0.0, 0.0
        return
    v = np.empty(3)
    for i in range(3):
        row = JACOBIAN + 3 * i
        v[i] = ws[row] * ws[QD] + ws[row + 1] * ws[QD + 1] + ws[row + 2] * ws[QD + 2]
    fx, fy, fz = plane_contact_force(contact, ws[TIP], ws[TIP + 1], ws[TIP + 2], v[0], v[1], v[2])
    ws[FORCE], ws[FORCE + 1], ws[FORCE + 2] = -fx, -fy, -fz


@njit_cached()
def clip_command(
    tau: np.ndarray, limit: np.ndarray, ws: np.ndarray, out: np.ndarray, clipped: np.ndarray
) -> int:  # pragma: no cover - compiled
    """Clip a torque command to ``±limit`` into ``out`` and the workspace; flag ``clipped``.

    Returns -1 (nothing written) if a torque is not finite, else the number of clipped joints.
    """
    for i in range(3):
        if not math.isfinite(tau[i]):
            return -1
    count = 0
    for i in range(3):
        x = tau[i]
        over = abs(x) > limit[i]
        clipped[i] = over
        if over:
            count += 1
            x = min(max(x, -limit[i]), limit[i])
        out[i] = x
        ws[TAU_COMMANDED + i] = x
    return count
