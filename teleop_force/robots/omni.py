"""The PHANTOM Omni: the kinematics of docs/conventions.md as a pinocchio model.

Model coordinates are a serial chain (yaw, shoulder pitch, relative elbow pitch); motor
coordinates use the absolute forearm angle ``q3``: ``q_model = T @ q_motor`` with
``T = [[1, 0, 0], [0, 1, 0], [0, -1, 1]]``.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from teleop_force.robots.description import JointSpring, RobotDescription

UPPER_ARM_LENGTH_M = 0.135
FOREARM_LENGTH_M = 0.135
GRAVITY_MPS2 = 9.81
#: Rest angle of the gravity-compensation spring on joint 2.
SPRING_REST_ANGLE_RAD = np.pi / 2
#: Stiffness of the gravity-compensation spring of the simulated Omni.
SPRING_STIFFNESS_NM_PER_RAD = 0.15
MOTOR_TORQUE_LIMIT_NM = 0.6
TIP_FORCE_LIMIT_N = 3.3
ENCODER_RESOLUTION_RAD = 4.0e-4
Q_MIN_RAD = np.array([-0.98, 0.0, -0.8])
Q_MAX_RAD = np.array([0.98, 1.75, 1.25])
OMNI_COUPLING = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 1.0]])

#: Link inertias of the simulated Omni (mass [kg], centre of mass [m] and rotational inertia
#: about the centre of mass [kg m^2], each in its joint frame). Chosen so the identified base
#: parameters have the magnitudes of the paper's Table I.
_LINKS = (
    # turret: turns with q1
    (0.25, (0.0, 0.02, -0.012), ((4.0e-4, 0, 0), (0, 6.5e-4, 0), (0, 0, 4.2e-4))),
    # upper arm (link 1): along local +z, pitches about -x
    (0.11, (0.0, 0.006, 0.085), ((2.1e-4, 0, 0), (0, 2.0e-4, 1.0e-6), (0, 1.0e-6, 1.6e-5))),
    # forearm (link 2) with the gimbal: along local -y
    (0.08, (0.0, -0.09, 0.004), ((1.7e-4, 0, 0), (0, 1.3e-5, 0), (0, 0, 1.6e-4))),
)
ROTOR_INERTIA_KGM2 = np.array([2.6e-4, 1.8e-4, 1.8e-4])


def tip_position_formula(q: np.ndarray) -> np.ndarray:
    """Tip position in the base frame from the closed-form formula of docs/conventions.md [m]."""
    q1, q2, q3 = q
    r = UPPER_ARM_LENGTH_M * np.cos(q2) + FOREARM_LENGTH_M * np.sin(q3)
    return np.array(
        [
            -np.sin(q1) * r,
            UPPER_ARM_LENGTH_M * np.sin(q2) - FOREARM_LENGTH_M * np.cos(q3),
            np.cos(q1) * r,
        ]
    )


def tip_jacobian_formula(q: np.ndarray) -> np.ndarray:
    """Analytic ``d p / d q`` of :func:`tip_position_formula` (3 x 3)."""
    q1, q2, q3 = q
    l1, l2 = UPPER_ARM_LENGTH_M, FOREARM_LENGTH_M
    r = l1 * np.cos(q2) + l2 * np.sin(q3)
    dr2, dr3 = -l1 * np.sin(q2), l2 * np.cos(q3)
    return np.array(
        [
            [-np.cos(q1) * r, -np.sin(q1) * dr2, -np.sin(q1) * dr3],
            [0.0, l1 * np.cos(q2), l2 * np.sin(q3)],
            [-np.sin(q1) * r, np.cos(q1) * dr2, np.cos(q1) * dr3],
        ]
    )


def build_omni_model() -> pin.Model:
    """Build the Omni's pinocchio model in model coordinates (relative elbow angle)."""
    model = pin.Model()
    model.name = "phantom_omni"
    model.gravity = pin.Motion(np.array([0.0, -GRAVITY_MPS2, 0.0]), np.zeros(3))
    minus_y = np.array([0.0, -1.0, 0.0])
    minus_x = np.array([-1.0, 0.0, 0.0])
    placements = (
        pin.SE3.Identity(),
        pin.SE3.Identity(),
        pin.SE3(np.eye(3), np.array([0.0, 0.0, UPPER_ARM_LENGTH_M])),
    )
    axes = (minus_y, minus_x, minus_x)
    names = ("waist", "shoulder", "elbow")
    parent = 0
    for (mass, com, inertia), placement, axis, name in zip(
        _LINKS, placements, axes, names, strict=True
    ):
        joint_id = model.addJoint(parent, pin.JointModelRevoluteUnaligned(axis), placement, name)
        model.appendBodyToJoint(
            joint_id, pin.Inertia(mass, np.array(com), np.array(inertia)), pin.SE3.Identity()
        )
        parent = joint_id
    model.addFrame(
        pin.Frame(
            "tip",
            parent,
            pin.SE3(np.eye(3), np.array([0.0, -FOREARM_LENGTH_M, 0.0])),
            pin.FrameType.OP_FRAME,
        )
    )
    return model


def omni_description() -> RobotDescription:
    """Return the built-in PHANTOM Omni description (motor coordinates, absolute q3)."""
    return RobotDescription(
        name="omni",
        model=build_omni_model(),
        n_joints=3,
        coupling=OMNI_COUPLING,
        tip_frame="tip",
        rotor_inertia_kgm2=ROTOR_INERTIA_KGM2,
        springs=(JointSpring(joint=1, rest_angle_rad=SPRING_REST_ANGLE_RAD),),
        friction_inputs=((0,), (1, 2), (1, 2)),
        q_min_rad=Q_MIN_RAD,
        q_max_rad=Q_MAX_RAD,
        joint_names=("waist q1", "shoulder q2", "elbow q3 (absolute)"),
    )
