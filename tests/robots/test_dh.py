import numpy as np
import pinocchio as pin
import pytest

from teleop_force.errors import ModelError
from teleop_force.robots.dh import DHLink, DHRow, build_dh_model, dh_forward_kinematics
from teleop_force.robots.dvrk_mtm import dh_rows


def _tip_pose(model: pin.Model, q: np.ndarray, frame: str = "tip") -> np.ndarray:
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[model.getFrameId(frame)].homogeneous


def _direct_product(rows, q):
    """Textbook standard DH: A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha), written out."""
    pose = np.eye(4)
    for (alpha, a, d, theta0, kind), qi in zip(rows, q, strict=True):
        theta = theta0 + (qi if kind == "revolute" else 0.0)
        d = d + (qi if kind == "prismatic" else 0.0)
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        pose = pose @ np.array(
            [
                [ct, -st * ca, st * sa, a * ct],
                [st, ct * ca, -ct * sa, a * st],
                [0, sa, ca, d],
                [0, 0, 0, 1],
            ]
        )
    return pose


TABLE = [
    (np.pi / 2, 0.0, 0.3, 0.1, "revolute"),
    (0.0, 0.25, 0.0, -np.pi / 2, "revolute"),
    (-np.pi / 2, 0.05, 0.1, 0.0, "prismatic"),
    (0.4, 0.0, 0.12, np.pi / 3, "revolute"),
]


def test_forward_kinematics_matches_the_direct_dh_product():
    rows = [DHRow(alpha, a, d, theta, kind) for alpha, a, d, theta, kind in TABLE]
    model = build_dh_model(rows)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.uniform(-2, 2, size=len(rows))
        expected = _direct_product(TABLE, q)
        np.testing.assert_allclose(_tip_pose(model, q), expected, atol=1e-12)
        np.testing.assert_allclose(dh_forward_kinematics(rows, q), expected, atol=1e-12)
        # every intermediate DH frame too
        for i in range(1, len(rows) + 1):
            np.testing.assert_allclose(
                _tip_pose(model, q, f"dh_{i}"), _direct_product(TABLE[:i], q[:i]), atol=1e-12
            )


def test_mtm_table_matches_the_direct_product():
    rows = dh_rows()
    model = build_dh_model(rows)
    table = [(r.alpha_rad, r.a_m, r.d_m, r.theta_offset_rad, r.joint_type) for r in rows]
    q = np.linspace(-1.0, 1.0, 7)
    np.testing.assert_allclose(_tip_pose(model, q), _direct_product(table, q), atol=1e-12)


def test_tip_offset_is_in_the_last_dh_frame():
    rows = [DHRow(0.0, 0.3, 0.0, 0.0)]
    model = build_dh_model(rows, tip_offset_m=(0.1, 0.0, 0.0))
    np.testing.assert_allclose(
        _tip_pose(model, np.array([np.pi / 2]))[:3, 3], [0.0, 0.4, 0.0], atol=1e-12
    )


def test_link_inertia_is_in_its_dh_frame():
    # One horizontal link of length L about z, mass at its middle: N(q) = m g L/2 cos q.
    length, mass, g = 0.4, 2.0, 9.81
    rows = [DHRow(0.0, length, 0.0, 0.0, link=DHLink(mass, (-length / 2, 0.0, 0.0)))]
    model = build_dh_model(rows, gravity_mps2=(0.0, -g, 0.0))
    data = model.createData()
    for q in (0.0, 0.7, 2.0):
        tau = pin.computeGeneralizedGravity(model, data, np.array([q]))
        assert tau[0] == pytest.approx(mass * g * length / 2 * np.cos(q))


@pytest.mark.parametrize(
    "build",
    [
        lambda: DHRow(0.0, 0.1, 0.0, joint_type="spherical"),
        lambda: DHRow(float("nan"), 0.1, 0.0),
        lambda: DHLink(-1.0),
        lambda: DHLink(1.0, inertia_kgm2=((1, 2, 0), (0, 1, 0), (0, 0, 1))),
        lambda: build_dh_model([]),
        lambda: build_dh_model([DHRow(0, 0, 0)], gravity_mps2=(0, 0)),
        lambda: build_dh_model([DHRow(0, 0, 0)], tip_frame="dh_1"),
    ],
)
def test_bad_dh_input_raises_model_error(build):
    with pytest.raises(ModelError):
        build()
