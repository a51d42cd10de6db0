import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.robots.omni import FOREARM_LENGTH_M, UPPER_ARM_LENGTH_M, tip_position_formula
from web.geometry import (
    R_WORLD_BASE,
    arm_frame_quats,
    base_to_world,
    force_arrow,
    link_pose,
    omni_joint_points,
    quat_about,
    quat_mul,
    quat_z_to,
    rotate_by_quat,
)
from web.scene import BASE_FRAME_WXYZ

angles = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(angles, angles, angles)
def test_tip_matches_the_conventions_formula_and_links_keep_their_length(q1, q2, q3):
    q = np.array([q1, q2, q3])
    shoulder, elbow, tip = omni_joint_points(q)
    np.testing.assert_allclose(shoulder, 0.0)
    np.testing.assert_allclose(tip, tip_position_formula(q), atol=1e-12)
    assert np.isclose(np.linalg.norm(elbow - shoulder), UPPER_ARM_LENGTH_M)
    assert np.isclose(np.linalg.norm(tip - elbow), FOREARM_LENGTH_M)


def test_home_pose_geometry():
    # q2 = 0 (upper arm horizontal toward the user), q3 = 0 (forearm straight down).
    _, elbow, tip = omni_joint_points(np.zeros(3))
    np.testing.assert_allclose(elbow, [0.0, 0.0, UPPER_ARM_LENGTH_M], atol=1e-15)
    np.testing.assert_allclose(tip, [0.0, -FOREARM_LENGTH_M, UPPER_ARM_LENGTH_M], atol=1e-15)
    # +q1 turns the arm toward -x.
    _, elbow, _ = omni_joint_points(np.array([0.5, 0.0, 0.0]))
    assert elbow[0] < 0


def test_base_to_world_is_a_proper_rotation_with_base_y_up():
    np.testing.assert_allclose(R_WORLD_BASE @ R_WORLD_BASE.T, np.eye(3))
    assert np.isclose(np.linalg.det(R_WORLD_BASE), 1.0)
    np.testing.assert_allclose(base_to_world([0.0, 1.0, 0.0]), [0.0, 0.0, 1.0])  # up is up
    np.testing.assert_allclose(base_to_world([0.0, 0.0, 1.0]), [0.0, -1.0, 0.0])  # user at -y
    np.testing.assert_allclose(base_to_world([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0])
    pts = np.arange(12.0).reshape(2, 2, 3)
    assert base_to_world(pts).shape == (2, 2, 3)


def test_base_frame_quaternion_matches_the_rotation():
    for axis in np.eye(3):
        np.testing.assert_allclose(
            rotate_by_quat(np.array(BASE_FRAME_WXYZ), axis), R_WORLD_BASE @ axis, atol=1e-12
        )


@settings(max_examples=80, deadline=None)
@given(
    st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3).filter(
        lambda v: np.linalg.norm(v) > 1e-3
    )
)
def test_quat_z_to_rotates_z_onto_the_direction(v):
    d = np.array(v) / np.linalg.norm(v)
    q = quat_z_to(np.array(v))
    assert np.isclose(np.linalg.norm(q), 1.0)
    np.testing.assert_allclose(rotate_by_quat(q, np.array([0.0, 0.0, 1.0])), d, atol=1e-8)


def test_quat_z_to_degenerate_cases():
    np.testing.assert_allclose(
        rotate_by_quat(quat_z_to(np.array([0, 0, -2.0])), np.array([0, 0, 1.0])), [0, 0, -1]
    )
    np.testing.assert_allclose(quat_z_to(np.zeros(3)), [1, 0, 0, 0])
    np.testing.assert_allclose(quat_z_to(np.array([np.nan, 0, 0])), [1, 0, 0, 0])


def test_link_pose_centres_and_orients_a_cylinder():
    a, b = np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.3, 0.4])
    pos, wxyz, length = link_pose(a, b)
    np.testing.assert_allclose(pos, [0.0, 0.15, 0.2])
    assert np.isclose(length, 0.5)
    np.testing.assert_allclose(rotate_by_quat(wxyz, np.array([0, 0, length])), b - a, atol=1e-12)


def test_force_arrow_points_along_the_force_in_world_coordinates():
    tip = np.array([0.0, -0.1, 0.15])
    arrow = force_arrow(tip, np.array([0.0, -2.0, 0.0]), 0.05)  # pressing down
    assert arrow.shape == (1, 2, 3)
    np.testing.assert_allclose(arrow[0, 0], base_to_world(tip))
    np.testing.assert_allclose(arrow[0, 1] - arrow[0, 0], [0.0, 0.0, -0.1])  # down in the world
    assert force_arrow(tip, np.array([np.nan, 0.0, 0.0]), 0.05) is None
    assert force_arrow(tip, np.zeros(3), 0.05) is None


@settings(max_examples=60, deadline=None)
@given(angles, angles, angles)
def test_the_drawn_kinematic_tree_reaches_the_same_elbow_and_tip(q1, q2, q3):
    q = np.array([q1, q2, q3])
    yaw, shoulder, elbow = arm_frame_quats(q)
    upper = quat_mul(yaw, shoulder)
    fore = quat_mul(upper, elbow)
    elbow_at = rotate_by_quat(upper, np.array([0.0, 0.0, UPPER_ARM_LENGTH_M]))
    tip_at = elbow_at + rotate_by_quat(fore, np.array([0.0, 0.0, FOREARM_LENGTH_M]))
    _, elbow_ref, tip_ref = omni_joint_points(q)
    np.testing.assert_allclose(elbow_at, elbow_ref, atol=1e-12)
    np.testing.assert_allclose(tip_at, tip_ref, atol=1e-12)
    # The root frame carries the base-to-world rotation.
    np.testing.assert_allclose(
        rotate_by_quat(np.array(BASE_FRAME_WXYZ), tip_at), base_to_world(tip_ref), atol=1e-12
    )


def test_quat_about_and_mul():
    q = quat_about((0.0, 0.0, 1.0), np.pi / 2)
    np.testing.assert_allclose(
        rotate_by_quat(q, np.array([1.0, 0.0, 0.0])), [0.0, 1.0, 0.0], atol=1e-15
    )
    qq = quat_mul(q, q)
    np.testing.assert_allclose(
        rotate_by_quat(qq, np.array([1.0, 0.0, 0.0])), [-1.0, 0.0, 0.0], atol=1e-15
    )
