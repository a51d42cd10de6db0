"""A robot's kinematic tree in arrays, and its rigid-body terms over many samples (compiled).

The streaming estimator asks pinocchio for ``M``, ``C`` and ``g`` at every sample: four
calls of a few microseconds each, which is what a whole recording cannot afford
(:mod:`teleop_force.estimation.batch`). For trees of revolute and prismatic joints (every
robot of the project) the same terms are computed here in one compiled loop over the samples,
from the pinocchio model's own joint placements, axes and inertias (:func:`chain_tables`),
in the world frame (spatial vectors ``(linear at the world origin, angular)``)::

    S_i                 joint i's motion axis (world), v_i = v_parent + S_i qd_i
    h_i = I_i v_i       body i's momentum; H_i, F_i: sums over the subtree of i of h and
                        of the gravity force I (-g)
    (M qd)_i            = S_i . H_i
    g_i                 = S_i . F_i
    (C^T qd)_i          = d/dq_i (qd^T M qd / 2) = -S_i . (v_i x* H_i)

(``C`` in the Christoffel form, ``Mdot = C + C^T``, as pinocchio's
``computeCoriolisMatrix``), and the tip's translational Jacobian ``d p_tip / d q``
(``LOCAL_WORLD_ALIGNED``): ``J[:, i] = S_i.linear + S_i.angular x p_tip`` over the joints
that carry the tip. The numbers equal pinocchio's up to rounding (tested against it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from teleop_force.compiled import njit_cached, view_2d, view_3d

#: Joint kinds of the tables.
REVOLUTE, PRISMATIC = 0, 1
_AXES = {"X": (1.0, 0.0, 0.0), "Y": (0.0, 1.0, 0.0), "Z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True, eq=False)
class ChainTables:
    """A pinocchio model (and its tip frame) as arrays for the compiled loops.

    Attributes:
        parent: Per body (pinocchio joint 1..), its parent body, -1 for the base.
        kind: :data:`REVOLUTE` or :data:`PRISMATIC`.
        axis: Joint axis in the joint frame (B, 3).
        rotation: Joint placement in the parent's frame, rotation (B, 3, 3).
        translation: Joint placement in the parent's frame, translation (B, 3).
        velocity_index: The body's velocity index ``idx_v``.
        mass: Body mass [kg].
        com: Centre of mass in the body frame (B, 3) [m].
        inertia: Rotational inertia about the centre of mass, body frame (B, 3, 3).
        gravity: Gravity's linear acceleration in the world frame (3,).
        tip_body: Body carrying the tip frame (-1: no tip).
        tip_translation: Tip frame origin in that body's frame (3,).
        tip_support: 1 for the bodies whose joints move the tip, else 0 (B,).

    """

    parent: np.ndarray
    kind: np.ndarray
    axis: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    velocity_index: np.ndarray
    mass: np.ndarray
    com: np.ndarray
    inertia: np.ndarray
    gravity: np.ndarray
    tip_body: int
    tip_translation: np.ndarray
    tip_support: np.ndarray

    @property
    def n_bodies(self) -> int:
        """Number of moving bodies (one joint each)."""
        return int(self.parent.size)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """Return the tables in the argument order of the compiled functions."""
        return (
            self.parent, self.kind, self.axis, self.rotation, self.translation,
            self.velocity_index, self.mass, self.com, self.inertia, self.gravity,
        )  # fmt: skip


def _joint_axis(joint: pin.JointModel) -> tuple[int, tuple[float, ...]] | None:
    """``(kind, axis)`` of a one-dof revolute or prismatic joint; None for any other joint."""
    name = joint.shortname()
    if joint.nq != 1 or joint.nv != 1:
        return None
    for prefix, kind in (("JointModelR", REVOLUTE), ("JointModelP", PRISMATIC)):
        suffix = name[len(prefix) :]
        if name.startswith(prefix) and suffix in _AXES:
            return kind, _AXES[suffix]
    if name == "JointModelRevoluteUnaligned":
        return REVOLUTE, tuple(float(x) for x in joint.extract().axis)
    if name == "JointModelPrismaticUnaligned":
        return PRISMATIC, tuple(float(x) for x in joint.extract().axis)
    return None


def chain_tables(model: pin.Model, tip_frame: str | None) -> ChainTables | None:
    """Encode ``model`` (and ``tip_frame``) for the compiled loops.

    Return None if a joint is not a one-dof revolute or prismatic joint (mimic, spherical,
    free-flyer...): the caller then asks pinocchio.
    """
    n_bodies = model.njoints - 1
    if model.nq != model.nv:
        return None
    parent = np.empty(n_bodies, dtype=np.int64)
    kind = np.empty(n_bodies, dtype=np.int64)
    axis = np.empty((n_bodies, 3))
    rotation = np.empty((n_bodies, 3, 3))
    translation = np.empty((n_bodies, 3))
    velocity_index = np.empty(n_bodies, dtype=np.int64)
    mass = np.empty(n_bodies)
    com = np.empty((n_bodies, 3))
    inertia = np.empty((n_bodies, 3, 3))
    for b in range(n_bodies):
        joint = model.joints[b + 1]
        encoded = _joint_axis(joint)
        if encoded is None:
            return None
        kind[b], axis[b] = encoded
        parent[b] = model.parents[b + 1] - 1
        placement = model.jointPlacements[b + 1]
        rotation[b] = placement.rotation
        translation[b] = placement.translation
        velocity_index[b] = joint.idx_v
        body = model.inertias[b + 1]
        mass[b] = body.mass
        com[b] = body.lever
        inertia[b] = body.inertia
    tip_body = -1
    tip_translation = np.zeros(3)
    tip_support = np.zeros(n_bodies, dtype=np.int64)
    if tip_frame is not None:
        frame = model.frames[model.getFrameId(tip_frame)]
        tip_body = int(frame.parentJoint) - 1
        tip_translation = np.array(frame.placement.translation, dtype=float)
        b = tip_body
        while b >= 0:
            tip_support[b] = 1
            b = int(parent[b])
    return ChainTables(
        parent, kind, axis, rotation, translation, velocity_index, mass, com, inertia,
        np.array(model.gravity.linear, dtype=float), tip_body, tip_translation, tip_support,
    )  # fmt: skip


@njit_cached()
def _forward_kinematics(
    q: np.ndarray,
    parent: np.ndarray,
    kind: np.ndarray,
    axis: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    velocity_index: np.ndarray,
    pose_r: np.ndarray,
    pose_p: np.ndarray,
    motion: np.ndarray,
    m: np.ndarray,
    o: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Body poses (world) ``pose_r`` (B, 3, 3), ``pose_p`` (B, 3) and motion axes (B, 6).

    ``m`` (3, 3) and ``o`` (3,) are scratch.
    """
    for b in range(parent.size):
        lam = parent[b]
        # m = R_parent R_placement, o = p_parent + R_parent p_placement
        for r in range(3):
            if lam < 0:
                for c in range(3):
                    m[r, c] = rotation[b, r, c]
                o[r] = translation[b, r]
            else:
                s = pose_p[lam, r]
                for c in range(3):
                    m[r, c] = (
                        pose_r[lam, r, 0] * rotation[b, 0, c]
                        + pose_r[lam, r, 1] * rotation[b, 1, c]
                        + pose_r[lam, r, 2] * rotation[b, 2, c]
                    )
                    s += pose_r[lam, r, c] * translation[b, c]
                o[r] = s
        ax, ay, az = axis[b, 0], axis[b, 1], axis[b, 2]
        # the axis in the world
        ux = m[0, 0] * ax + m[0, 1] * ay + m[0, 2] * az
        uy = m[1, 0] * ax + m[1, 1] * ay + m[1, 2] * az
        uz = m[2, 0] * ax + m[2, 1] * ay + m[2, 2] * az
        angle = q[velocity_index[b]]
        if kind[b] == REVOLUTE:
            # Rodrigues: R_j = cos I + sin [a]x + (1 - cos) a a^T
            c = np.cos(angle)
            s = np.sin(angle)
            t = 1.0 - c
            j00, j01, j02 = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
            j10, j11, j12 = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
            j20, j21, j22 = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
            for r in range(3):
                a0, a1, a2 = m[r, 0], m[r, 1], m[r, 2]
                pose_r[b, r, 0] = a0 * j00 + a1 * j10 + a2 * j20
                pose_r[b, r, 1] = a0 * j01 + a1 * j11 + a2 * j21
                pose_r[b, r, 2] = a0 * j02 + a1 * j12 + a2 * j22
                pose_p[b, r] = o[r]
            px, py, pz = o[0], o[1], o[2]
            # linear part at the world origin: p x u
            motion[b, 0] = py * uz - pz * uy
            motion[b, 1] = pz * ux - px * uz
            motion[b, 2] = px * uy - py * ux
            motion[b, 3] = ux
            motion[b, 4] = uy
            motion[b, 5] = uz
        else:
            pose_p[b, 0] = o[0] + ux * angle
            pose_p[b, 1] = o[1] + uy * angle
            pose_p[b, 2] = o[2] + uz * angle
            for r in range(3):
                for c in range(3):
                    pose_r[b, r, c] = m[r, c]
            motion[b, 0] = ux
            motion[b, 1] = uy
            motion[b, 2] = uz
            motion[b, 3] = 0.0
            motion[b, 4] = 0.0
            motion[b, 5] = 0.0


@njit_cached()
def chain_kinematics_into(
    q: np.ndarray,
    parent: np.ndarray,
    kind: np.ndarray,
    axis: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    velocity_index: np.ndarray,
    work: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Body poses and motion axes at ``q`` into ``work`` (:func:`chain_work_size` floats).

    What :func:`chain_momentum_into` and :func:`chain_tip_jacobian_into` read.
    """
    nb = parent.size
    if work.size < chain_work_size(nb):
        raise ValueError("chain work buffer too small")
    _forward_kinematics(
        q, parent, kind, axis, rotation, translation, velocity_index, view_3d(work, 0, nb, 3, 3),
        view_2d(work, 9 * nb, nb, 3), view_2d(work, 12 * nb, nb, 6),
        view_2d(work, 36 * nb, 3, 3), work[36 * nb + 9 : 36 * nb + 12],
    )  # fmt: skip


@njit_cached()
def chain_momentum_into(
    v: np.ndarray,
    parent: np.ndarray,
    velocity_index: np.ndarray,
    mass: np.ndarray,
    com: np.ndarray,
    inertia: np.ndarray,
    gravity: np.ndarray,
    work: np.ndarray,
    momentum: np.ndarray,
    other: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``M(q) v`` into ``momentum`` and ``g(q) - C(q, v)^T v`` into ``other``.

    At the ``q`` of the last :func:`chain_kinematics_into` on ``work``. Model coordinates
    (pinocchio's), no rotor inertia, no spring.
    """
    nb = parent.size
    pose_r = view_3d(work, 0, nb, 3, 3)
    pose_p = view_2d(work, 9 * nb, nb, 3)
    motion = view_2d(work, 12 * nb, nb, 6)
    vel = view_2d(work, 18 * nb, nb, 6)
    mom = view_2d(work, 24 * nb, nb, 6)  # H: subtree momentum
    grav = view_2d(work, 30 * nb, nb, 6)  # F: subtree gravity force
    g0, g1, g2 = -gravity[0], -gravity[1], -gravity[2]
    for b in range(nb):
        lam = parent[b]
        qd_b = v[velocity_index[b]]
        for i in range(6):
            base = 0.0 if lam < 0 else vel[lam, i]
            vel[b, i] = base + motion[b, i] * qd_b
        vx, vy, vz = vel[b, 0], vel[b, 1], vel[b, 2]
        wx, wy, wz = vel[b, 3], vel[b, 4], vel[b, 5]
        # centre of mass in the world
        cx, cy, cz = pose_p[b, 0], pose_p[b, 1], pose_p[b, 2]
        for c in range(3):
            cx += pose_r[b, 0, c] * com[b, c]
            cy += pose_r[b, 1, c] * com[b, c]
            cz += pose_r[b, 2, c] * com[b, c]
        m_b = mass[b]
        # linear momentum m (v + w x c)
        lx = m_b * (vx + wy * cz - wz * cy)
        ly = m_b * (vy + wz * cx - wx * cz)
        lz = m_b * (vz + wx * cy - wy * cx)
        # rotational inertia about the com, world: R I R^T w
        bx = pose_r[b, 0, 0] * wx + pose_r[b, 1, 0] * wy + pose_r[b, 2, 0] * wz
        by = pose_r[b, 0, 1] * wx + pose_r[b, 1, 1] * wy + pose_r[b, 2, 1] * wz
        bz = pose_r[b, 0, 2] * wx + pose_r[b, 1, 2] * wy + pose_r[b, 2, 2] * wz
        ix = inertia[b, 0, 0] * bx + inertia[b, 0, 1] * by + inertia[b, 0, 2] * bz
        iy = inertia[b, 1, 0] * bx + inertia[b, 1, 1] * by + inertia[b, 1, 2] * bz
        iz = inertia[b, 2, 0] * bx + inertia[b, 2, 1] * by + inertia[b, 2, 2] * bz
        kx = pose_r[b, 0, 0] * ix + pose_r[b, 0, 1] * iy + pose_r[b, 0, 2] * iz
        ky = pose_r[b, 1, 0] * ix + pose_r[b, 1, 1] * iy + pose_r[b, 1, 2] * iz
        kz = pose_r[b, 2, 0] * ix + pose_r[b, 2, 1] * iy + pose_r[b, 2, 2] * iz
        # angular momentum about the origin: I_c w + c x l
        kx += cy * lz - cz * ly
        ky += cz * lx - cx * lz
        kz += cx * ly - cy * lx
        mom[b, 0], mom[b, 1], mom[b, 2] = lx, ly, lz
        mom[b, 3], mom[b, 4], mom[b, 5] = kx, ky, kz
        # gravity as the base accelerating by -g: force m a0 at the com
        fx, fy, fz = m_b * g0, m_b * g1, m_b * g2
        grav[b, 0], grav[b, 1], grav[b, 2] = fx, fy, fz
        grav[b, 3] = cy * fz - cz * fy
        grav[b, 4] = cz * fx - cx * fz
        grav[b, 5] = cx * fy - cy * fx
    for b in range(nb - 1, -1, -1):
        s = motion[b]
        vx, vy, vz = vel[b, 0], vel[b, 1], vel[b, 2]
        wx, wy, wz = vel[b, 3], vel[b, 4], vel[b, 5]
        lx, ly, lz = mom[b, 0], mom[b, 1], mom[b, 2]
        kx, ky, kz = mom[b, 3], mom[b, 4], mom[b, 5]
        # v_b x* H_b = (w x l, v x l + w x k): S . (v x* H) = -(C^T v)_b
        c0 = wy * lz - wz * ly
        c1 = wz * lx - wx * lz
        c2 = wx * ly - wy * lx
        c3 = vy * lz - vz * ly + wy * kz - wz * ky
        c4 = vz * lx - vx * lz + wz * kx - wx * kz
        c5 = vx * ly - vy * lx + wx * ky - wy * kx
        p = s[0] * lx + s[1] * ly + s[2] * lz + s[3] * kx + s[4] * ky + s[5] * kz
        g = s[0] * grav[b, 0] + s[1] * grav[b, 1] + s[2] * grav[b, 2]
        g += s[3] * grav[b, 3] + s[4] * grav[b, 4] + s[5] * grav[b, 5]
        ct = s[0] * c0 + s[1] * c1 + s[2] * c2 + s[3] * c3 + s[4] * c4 + s[5] * c5
        index = velocity_index[b]
        momentum[index] = p
        other[index] = g + ct
        lam = parent[b]
        if lam >= 0:
            for i in range(6):
                mom[lam, i] += mom[b, i]
                grav[lam, i] += grav[b, i]


@njit_cached()
def chain_terms_into(
    q: np.ndarray,
    v: np.ndarray,
    parent: np.ndarray,
    kind: np.ndarray,
    axis: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    velocity_index: np.ndarray,
    mass: np.ndarray,
    com: np.ndarray,
    inertia: np.ndarray,
    gravity: np.ndarray,
    work: np.ndarray,
    momentum: np.ndarray,
    other: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``M(q) v`` and ``g(q) - C(q, v)^T v`` at one sample (the two functions above)."""
    chain_kinematics_into(q, parent, kind, axis, rotation, translation, velocity_index, work)
    chain_momentum_into(
        v, parent, velocity_index, mass, com, inertia, gravity, work, momentum, other
    )


@njit_cached()
def chain_work_size(n_bodies: int) -> int:  # pragma: no cover - compiled
    """Scratch floats of the one-sample functions (poses, axes, velocities, momenta)."""
    return 36 * n_bodies + 12


@njit_cached()
def chain_tip_jacobian_into(
    parent: np.ndarray,
    velocity_index: np.ndarray,
    tip_body: int,
    tip_translation: np.ndarray,
    tip_support: np.ndarray,
    work: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Write the tip's translational Jacobian (world axes) into ``out`` (3, nv).

    At the ``q`` of the last :func:`chain_kinematics_into` on ``work``.
    """
    nb = parent.size
    pose_r = view_3d(work, 0, nb, 3, 3)
    pose_p = view_2d(work, 9 * nb, nb, 3)
    motion = view_2d(work, 12 * nb, nb, 6)
    px, py, pz = pose_p[tip_body, 0], pose_p[tip_body, 1], pose_p[tip_body, 2]
    for c in range(3):
        px += pose_r[tip_body, 0, c] * tip_translation[c]
        py += pose_r[tip_body, 1, c] * tip_translation[c]
        pz += pose_r[tip_body, 2, c] * tip_translation[c]
    for i in range(out.shape[1]):
        out[0, i] = 0.0
        out[1, i] = 0.0
        out[2, i] = 0.0
    for b in range(nb):
        if tip_support[b] == 0:
            continue
        index = velocity_index[b]
        wx, wy, wz = motion[b, 3], motion[b, 4], motion[b, 5]
        out[0, index] = motion[b, 0] + wy * pz - wz * py
        out[1, index] = motion[b, 1] + wz * px - wx * pz
        out[2, index] = motion[b, 2] + wx * py - wy * px


@njit_cached()
def chain_terms_batch(
    q: np.ndarray,
    v: np.ndarray,
    parent: np.ndarray,
    kind: np.ndarray,
    axis: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    velocity_index: np.ndarray,
    mass: np.ndarray,
    com: np.ndarray,
    inertia: np.ndarray,
    gravity: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """``M(q) v`` and ``g(q) - C(q, v)^T v`` at every sample: ``q``, ``v`` (N, nv) -> two (N, nv).

    Model coordinates (pinocchio's), no rotor inertia, no spring.
    """
    n_samples, nv = q.shape
    work = np.empty(36 * parent.size + 12)
    momentum = np.empty((n_samples, nv))
    other = np.empty((n_samples, nv))
    for k in range(n_samples):
        chain_terms_into(
            q[k], v[k], parent, kind, axis, rotation, translation, velocity_index, mass, com,
            inertia, gravity, work, momentum[k], other[k],
        )  # fmt: skip
    return momentum, other


@njit_cached()
def chain_jacobian_batch(
    q: np.ndarray,
    parent: np.ndarray,
    kind: np.ndarray,
    axis: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    velocity_index: np.ndarray,
    tip_body: int,
    tip_translation: np.ndarray,
    tip_support: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Return the tip's translational Jacobian (world axes): ``q`` (N, nv) -> (N, 3, nv)."""
    n_samples, nv = q.shape
    work = np.empty(36 * parent.size + 12)
    out = np.zeros((n_samples, 3, nv))
    for k in range(n_samples):
        chain_kinematics_into(q[k], parent, kind, axis, rotation, translation, velocity_index, work)
        chain_tip_jacobian_into(
            parent, velocity_index, tip_body, tip_translation, tip_support, work, out[k]
        )
    return out
