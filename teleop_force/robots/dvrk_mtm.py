"""The da Vinci Research Kit master tool manipulator (MTM), from its published parameters.

Kinematics: the standard DH table written out in ``docs/robots.md`` (dVRK joint values,
lengths ``l_arm = 0.2794``, ``l_forearm = 0.3645``, ``h = 0.1506`` m), seven revolute joints
(outer yaw, shoulder pitch, elbow pitch, wrist platform, wrist pitch, wrist yaw, wrist roll).

Coordinates: motor coordinates are the dataset's (its identification model's, the "file"
coordinates); the DH joint values are the dVRK's. With
``C = [[1, 0, 0], [-1, 1, 0], [0.6697, -0.6697, 1]]`` acting on ``(q2, q3, q4)``,
``q_dvrk = C q_file`` (:func:`mtm_coupling`). ``q3`` in the file is the absolute elbow angle
(the parallelogram), and joint 4's cable angle ``0.6697 (q2 - q3) + q4`` couples it to 2 and 3.

The parallelogram: the real arm is a closed chain. Besides the upper arm (absolute angle
``q2``) and the forearm (absolute angle ``q3``, pivoting at the elbow), two links close it, as
in the data authors' model (Wang et al., RA-L 2019, links 3' and 3''): the back link, pivoting
on the shoulder-pitch axis with the absolute elbow angle ``q3`` (whatever turns that way, such
as a counterweight balancing the forearm, is part of it), and the top link, parallel to the
upper arm (absolute angle ``q2``), pivoting on the back link ``PARALLELOGRAM_LINK_M`` from the
shoulder axis. A serial chain cannot carry them: the back link turns with the forearm but about
the shoulder, so its gravity moment enters joint 3 without the ``l_arm``-times-first-moment
inertial coupling to joint 2 that any body on the forearm has (the counterweight balances the
forearm's gravity, not its coupling). The pinocchio model is therefore a tree: the seven DH
joints plus two branch joints, the back link hanging from link 1 at the shoulder-pitch joint's
placement (angle ``q3_file``) and the top link from the back link (relative angle
``q2 - q3_file``). The coupling is ``9 x 7`` (:func:`mtm_model_coupling`):
``q_model = T q_file``, and as everywhere in the project ``tau_file = T^T tau_model``.

Gravity is along ``-z0`` of DH frame 0 (the MTM base frame: ``z0`` is the outer yaw axis,
vertical, pointing up). Of the six axis directions it is the one whose identified model fits
the training torques of joints 2 and 3 (the gravity-loaded ones) best (see ``docs/robots.md``).

Link inertias are not published with the data: the nominal links are light placeholders
(identification finds the base parameters, the nominal values only fill the unidentifiable
directions). The joint-5 gravity spring and the cable stiffness are *not* modelled: they are
effects for the residual loop to find.

The native data files (``mtm_traj_*_results.csv``) are read by
:func:`teleop_force.io.dvrk_mtm_csv.read_mtm_csv`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from teleop_force.robots.description import RobotDescription
from teleop_force.robots.dh import DHLink, DHRow, build_dh_model

NAME = "dvrk-mtm"
N_JOINTS = 7
ARM_LENGTH_M = 0.2794
FOREARM_LENGTH_M = 0.3645
WRIST_PLATFORM_OFFSET_M = 0.1506
#: Joint-4 cable coupling ratio of the dataset's coordinates.
CABLE_RATIO = 0.6697
#: ``q_dvrk[1:4] = PARALLELOGRAM_CABLE_COUPLING @ q_file[1:4]``.
PARALLELOGRAM_CABLE_COUPLING = np.array(
    [[1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [CABLE_RATIO, -CABLE_RATIO, 1.0]]
)
#: Distance from the shoulder-pitch axis to the top link's pivot on the back link [m] (the
#: authors' ``l_back2front``; any value gives the same base parameters, tested).
PARALLELOGRAM_LINK_M = 0.1
#: Pinocchio names of the two closing links' joints (branches of the tree).
PARALLELOGRAM_JOINTS = ("parallelogram_back", "parallelogram_top")
GRAVITY_MPS2 = (0.0, 0.0, -9.81)
SAMPLE_RATE_HZ = 200.0
#: Columns of a native file: q1..q7, qd1..qd7, tau1..tau7.
NATIVE_COLUMNS = 3 * N_JOINTS
JOINT_NAMES = (
    "outer yaw q1",
    "shoulder pitch q2",
    "elbow pitch q3 (absolute)",
    "wrist platform q4",
    "wrist pitch q5",
    "wrist yaw q6",
    "wrist roll q7",
)
#: Reachable range in file coordinates [rad] (covers both published trajectories; joint 7
#: turns more than once).
Q_MIN_RAD = np.array([-0.8, -0.3, -0.3, -1.5, -1.6, -0.8, -8.0])
Q_MAX_RAD = np.array([1.1, 1.0, 0.8, 3.0, 3.0, 0.8, 8.0])
#: Joint 2 and 3 rub on the parallelogram (relative elbow velocity); joint 4's cable runs over
#: pulleys on the joint 2 and 3 axes, so joint 4's friction sees all three and, reacting, the
#: friction of joints 2 and 3 sees joint 4 (measured: docs/robots.md).
FRICTION_INPUTS = ((0,), (1, 2, 3), (1, 2, 3), (1, 2, 3), (4,), (5,), (6,))


def dh_rows() -> tuple[DHRow, ...]:
    """Return the MTM's standard DH table (dVRK joint values), with light nominal links."""
    half = np.pi / 2
    table = (
        (half, 0.0, 0.0, -half),
        (0.0, ARM_LENGTH_M, 0.0, -half),
        (-half, FOREARM_LENGTH_M, 0.0, half),
        (half, 0.0, WRIST_PLATFORM_OFFSET_M, 0.0),
        (-half, 0.0, 0.0, 0.0),
        (half, 0.0, 0.0, -half),
        (0.0, 0.0, 0.0, half),
    )
    # Nominal links: a point-ish mass halfway along each arm segment, small ones at the wrist.
    links = (
        DHLink(1.0, (0.0, 0.0, 0.0), _diag(1e-3)),
        DHLink(0.8, (-ARM_LENGTH_M / 2, 0.0, 0.0), _diag(2e-3)),
        DHLink(0.6, (-FOREARM_LENGTH_M / 2, 0.0, 0.0), _diag(2e-3)),
        DHLink(0.3, (0.0, 0.0, 0.0), _diag(5e-4)),
        DHLink(0.1, (0.0, 0.0, 0.0), _diag(1e-4)),
        DHLink(0.1, (0.0, 0.0, 0.0), _diag(1e-4)),
        DHLink(0.05, (0.0, 0.0, 0.0), _diag(5e-5)),
    )
    return tuple(
        DHRow(alpha, a, d, offset, "revolute", link)
        for (alpha, a, d, offset), link in zip(table, links, strict=True)
    )


def _diag(value: float) -> tuple[tuple[float, float, float], ...]:
    return ((value, 0.0, 0.0), (0.0, value, 0.0), (0.0, 0.0, value))


def mtm_coupling() -> np.ndarray:
    """``T = blockdiag(1, C, 1, 1, 1)`` with ``q_dvrk = T @ q_file`` (the seven DH joints)."""
    coupling = np.eye(N_JOINTS)
    coupling[1:4, 1:4] = PARALLELOGRAM_CABLE_COUPLING
    return coupling


def mtm_model_coupling(parallelogram: bool = True) -> np.ndarray:
    """Return the description's coupling ``T`` (``q_model = T @ q_file``).

    :func:`mtm_coupling` and, with the parallelogram, two rows more for its closing links
    (``9 x 7``): the back link's angle ``q3`` and the top link's ``q2 - q3`` (file coordinates).
    """
    coupling = mtm_coupling()
    if not parallelogram:
        return coupling
    back = np.zeros(N_JOINTS)
    back[2] = 1.0
    top = np.zeros(N_JOINTS)
    top[1], top[2] = 1.0, -1.0
    return np.vstack((coupling, back, top))


def _add_parallelogram(model: pin.Model, link_m: float = PARALLELOGRAM_LINK_M) -> None:
    """Add the back and top links of the parallelogram as two branches of the tree.

    The back link's joint sits where the shoulder-pitch joint does (same axis, child of link
    1); at angle 0 its x axis is the forearm's direction at ``q3_file = 0``, so its angle is
    the absolute elbow angle. The top link's joint sits ``link_m`` along the back link's x axis,
    turned so that its x axis runs along the upper arm: its angle relative to the back link is
    ``q2 - q3_file``.
    """
    shoulder = model.getJointId("shoulder_pitch")
    back = model.addJoint(
        model.parents[shoulder],
        pin.JointModelRZ(),
        model.jointPlacements[shoulder],
        PARALLELOGRAM_JOINTS[0],
    )
    # Nominal: a light bar ending in the counterweight behind the shoulder.
    model.appendBodyToJoint(
        back,
        pin.Inertia(0.3, np.array([-0.05, 0.0, 0.0]), np.diag([2e-4, 2e-3, 2e-3])),
        pin.SE3.Identity(),
    )
    placement = pin.SE3(np.eye(3), np.array([link_m, 0.0, 0.0])) * pin.SE3(
        pin.utils.rotate("z", -np.pi / 2), np.zeros(3)
    )
    top = model.addJoint(back, pin.JointModelRZ(), placement, PARALLELOGRAM_JOINTS[1])
    model.appendBodyToJoint(
        top,
        pin.Inertia(0.1, np.array([ARM_LENGTH_M / 2, 0.0, 0.0]), np.diag([1e-5, 7e-4, 7e-4])),
        pin.SE3.Identity(),
    )


def dvrk_mtm_description(
    gravity_mps2: tuple[float, float, float] = GRAVITY_MPS2,
    parallelogram: bool = True,
) -> RobotDescription:
    """Return the built-in dVRK MTM description (motor = file coordinates).

    ``parallelogram=False`` gives the serial chain of the DH table alone (``7 x 7`` coupling),
    kept for comparison.
    """
    model = build_dh_model(
        dh_rows(),
        gravity_mps2=gravity_mps2,
        tip_frame="tip",
        joint_names=[
            "outer_yaw",
            "shoulder_pitch",
            "elbow_pitch",
            "wrist_platform",
            "wrist_pitch",
            "wrist_yaw",
            "wrist_roll",
        ],
        name="dvrk_mtm",
    )
    if parallelogram:
        _add_parallelogram(model)
    return RobotDescription(
        name=NAME,
        model=model,
        n_joints=N_JOINTS,
        coupling=mtm_model_coupling(parallelogram),
        tip_frame="tip",
        rotor_inertia_kgm2=np.zeros(N_JOINTS),
        friction_inputs=FRICTION_INPUTS,
        q_min_rad=Q_MIN_RAD,
        q_max_rad=Q_MAX_RAD,
        joint_names=JOINT_NAMES,
    )
