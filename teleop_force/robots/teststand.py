"""The ODRI single-leg test stand (one Solo leg on a vertical slider), built in code.

Kinematic and inertial values are those of ``teststand.urdf`` (open-dynamic-robot-initiative/
robot_properties_teststand, BSD-3-Clause) as published beside the data in
``../shared/datasets/teststand/``; the project ships no copy of that file. The base slides on a
passive vertical prismatic joint (``joint_z``) that is not measured: the description is the leg
alone on a fixed base (hip ``HFE`` and knee ``KFE``, axes along ``y``, foot frame ``contact``,
gravity ``-z``), and the slider's acceleration enters the leg's joint torques exactly as a change
of gravity (``tau_slider = N(q) a_z / g``), handled by :mod:`teleop_force.estimation.teststand`.

:func:`teleop_force.io.teststand_logs.read_teststand_folder` reads the lab's native logs
(whitespace-separated ``.dat`` files, column 0 the 1 kHz controller tick) and aligns them on the
tick.

Sign conventions: the ATI sensor reports the force of the ground on the foot (its ``F_z`` is
positive while the foot presses down; its ``F_x`` has the sign of the force the ground exerts
along world ``x``, checked against the joint torques: see ``docs/robots.md``). The project's
tip force is the force of the robot on the environment, world ``z`` up, so it is the
negative of all three ATI components. The lab's own estimate (``dg_est_f_hopper-sout.dat``)
uses the ATI convention and is negated the same way.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from teleop_force.robots.description import RobotDescription

NAME = "teststand"
N_JOINTS = 2
GRAVITY_MPS2 = 9.81
TICK_S = 1e-3
TRANSMISSION_RATIO = 9.0
MOTOR_TORQUE_CONSTANT_NM_PER_A = 0.025
#: Knee joint origin in the upper leg frame [m].
KNEE_OFFSET_M = (0.0, 0.03745, -0.16)
#: Foot (``contact``) origin in the shank frame [m].
FOOT_OFFSET_M = (0.0, 0.008, -0.16)
#: Base link of the slider (not part of the fixed-base leg model): mass [kg], CoM [m].
BASE_MASS_KG = 0.485
BASE_COM_M = (0.0, 0.0, 0.05)
#: (mass [kg], CoM [m], inertia about the CoM [kg m^2] as xx, xy, yy, xz, yz, zz) per link.
UPPER_LEG = (
    0.14853845,
    (0.00001377, 0.01935853, -0.07870700),
    (0.00041107, 0.0, 0.00041193, 0.0, 0.00004671, 0.00003024),
)
SHANK = (
    0.03070001,
    (0.0, 0.00787644, -0.08928215),
    (0.00012024, 0.0, 0.00012029, 0.0, 0.00000305, 0.00000216),
)
FOOT = (0.00693606, (0.0, 0.0, 0.00035767), (0.00000057, 0.0, 0.00000084, 0.0, 0.0, 0.00000053))
JOINT_NAMES = ("hip HFE", "knee KFE")
Q_MIN_RAD = np.array([-np.pi, -np.pi])
Q_MAX_RAD = np.array([np.pi, np.pi])


def _inertia(link: tuple[float, tuple[float, ...], tuple[float, ...]]) -> pin.Inertia:
    mass, com, (ixx, ixy, iyy, ixz, iyz, izz) = link
    rotational = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return pin.Inertia(mass, np.array(com), rotational)


def build_teststand_model() -> pin.Model:
    """Build the leg's fixed-base pinocchio model (``joint_z`` locked at 0)."""
    model = pin.Model()
    model.name = "teststand"
    model.gravity = pin.Motion(np.array([0.0, 0.0, -GRAVITY_MPS2]), np.zeros(3))
    hip = model.addJoint(0, pin.JointModelRY(), pin.SE3.Identity(), "HFE")
    model.appendBodyToJoint(hip, _inertia(UPPER_LEG), pin.SE3.Identity())
    knee_placement = pin.SE3(np.eye(3), np.array(KNEE_OFFSET_M))
    knee = model.addJoint(hip, pin.JointModelRY(), knee_placement, "KFE")
    foot_placement = pin.SE3(np.eye(3), np.array(FOOT_OFFSET_M))
    model.appendBodyToJoint(knee, _inertia(SHANK), pin.SE3.Identity())
    model.appendBodyToJoint(knee, _inertia(FOOT), foot_placement)
    model.addFrame(pin.Frame("contact", knee, foot_placement, pin.FrameType.OP_FRAME))
    return model


def teststand_description() -> RobotDescription:
    """Return the built-in test-stand leg (motor = model coordinates: HFE, KFE)."""
    return RobotDescription(
        name=NAME,
        model=build_teststand_model(),
        n_joints=N_JOINTS,
        coupling=np.eye(N_JOINTS),
        tip_frame="contact",
        rotor_inertia_kgm2=np.zeros(N_JOINTS),
        q_min_rad=Q_MIN_RAD,
        q_max_rad=Q_MAX_RAD,
        joint_names=JOINT_NAMES,
    )
