"""The 3D scene: slave Omni, translucent master ghost, tissue plane and force arrows.

Everything is computed in the Omni base frame (y up, z toward the user) and mapped to viser's
z-up world with :func:`web.geometry.base_to_world`; the camera starts where the user sits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
import viser

from web.geometry import R_WORLD_BASE, base_to_world, force_arrow, link_pose, omni_joint_points

LINK_RADIUS_M: Final = 0.009
JOINT_RADIUS_M: Final = 0.013
TIP_RADIUS_M: Final = 0.011
#: Arrow length per newton of force.
METRES_PER_NEWTON: Final = 0.04
TISSUE_SIZE_M: Final = (0.36, 0.30)
#: Centre of the tissue plane in the base frame (x, z): in front of the arm, toward the user.
TISSUE_CENTRE_XZ_M: Final = (0.0, 0.14)
SLAVE_RGB: Final = (150, 156, 168)
MASTER_RGB: Final = (66, 133, 244)
EST_FORCE_RGB: Final = (242, 153, 0)
TRUE_FORCE_RGB: Final = (30, 142, 62)
TISSUE_RGB: Final = (234, 140, 150)
#: Quaternion of :data:`R_WORLD_BASE` (+90 degrees about x).
BASE_FRAME_WXYZ: Final = (np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0)


@dataclass
class _Arm:
    """Scene handles of one drawn arm."""

    links: tuple[viser.CylinderHandle, viser.CylinderHandle]
    joints: tuple[viser.IcosphereHandle, ...]
    last_q: np.ndarray | None = None


def _add_arm(
    scene: viser.SceneApi, name: str, rgb: tuple[int, int, int], opacity: float | None
) -> _Arm:
    q0 = np.array([0.0, 0.6, 0.3])
    points = base_to_world(omni_joint_points(q0))
    links = []
    for k, label in enumerate(("upper_arm", "forearm")):
        pos, wxyz, length = link_pose(points[k], points[k + 1])
        links.append(
            scene.add_cylinder(
                f"/{name}/{label}", radius=LINK_RADIUS_M, height=length, color=rgb,
                opacity=opacity, position=pos, wxyz=wxyz, cast_shadow=False,
                receive_shadow=False,
            )
        )  # fmt: skip
    joints = []
    for k, (label, radius) in enumerate(
        (("shoulder", JOINT_RADIUS_M), ("elbow", JOINT_RADIUS_M), ("tip", TIP_RADIUS_M))
    ):
        joints.append(
            scene.add_icosphere(
                f"/{name}/{label}", radius=radius, color=rgb, opacity=opacity,
                position=points[k], subdivisions=2, cast_shadow=False, receive_shadow=False,
            )
        )  # fmt: skip
    return _Arm((links[0], links[1]), tuple(joints))


def _pose_arm(arm: _Arm, q: np.ndarray) -> None:
    points = base_to_world(omni_joint_points(q))
    for k, link in enumerate(arm.links):
        pos, wxyz, _ = link_pose(points[k], points[k + 1])
        link.position = pos
        link.wxyz = wxyz
    for k, joint in enumerate(arm.joints):
        joint.position = points[k]
    arm.last_q = np.asarray(q, dtype=float).copy()


class OmniScene:
    """Scene handles of the dashboard and their per-frame update."""

    def __init__(self, server: viser.ViserServer, tissue_y_m: float) -> None:
        """Build the static scene (base, tissue) and the two arms, camera at the user."""
        scene = server.scene
        scene.set_up_direction("+z")
        # No shadow pass: the scene stays cheap to draw (software WebGL, laptops).
        scene.configure_default_lights(cast_shadow=False)
        scene.configure_environment_map(None)  # plain lights: far cheaper without a GPU
        scene.add_grid("/ground", width=0.6, height=0.6, cell_size=0.05, position=(0.0, -0.1, -0.2))
        # The Omni's base and turret, below the shoulder (base-frame origin).
        scene.add_box(
            "/base/plinth", color=(60, 64, 67), dimensions=(0.16, 0.16, 0.03),
            position=base_to_world(np.array([0.0, -0.185, -0.03])), cast_shadow=False,
        )  # fmt: skip
        scene.add_cylinder(
            "/base/turret", radius=0.03, height=0.17, color=(95, 99, 104),
            position=base_to_world(np.array([0.0, -0.09, 0.0])), cast_shadow=False,
        )  # fmt: skip
        # Base-frame axes (red x, green y up, blue z toward the user), rotated into the world.
        scene.add_frame("/base/frame", axes_length=0.05, axes_radius=0.002, wxyz=BASE_FRAME_WXYZ)
        self.tissue = scene.add_box(
            "/tissue", color=TISSUE_RGB, dimensions=(*TISSUE_SIZE_M, 0.004), opacity=0.55,
            position=self._tissue_position(tissue_y_m), cast_shadow=False, receive_shadow=False,
        )  # fmt: skip
        self.tissue_y_m = tissue_y_m
        self.slave = _add_arm(scene, "slave", SLAVE_RGB, None)
        self.master = _add_arm(scene, "master_ghost", MASTER_RGB, 0.3)
        for handle in (*self.master.links, *self.master.joints):
            handle.visible = False
        arrow0 = np.zeros((1, 2, 3))
        arrow0[0, 1, 2] = 0.01
        self.est_arrow = scene.add_arrows(
            "/force/estimated", arrow0, EST_FORCE_RGB, shaft_radius=0.004, head_radius=0.009,
            head_length=0.018, visible=False,
        )  # fmt: skip
        self.true_arrow = scene.add_arrows(
            "/force/true", arrow0, TRUE_FORCE_RGB, shaft_radius=0.0025, head_radius=0.007,
            head_length=0.015, visible=False,
        )  # fmt: skip
        self.show_true_force = True
        self.show_ghost = True
        server.initial_camera.position = (0.32, -0.62, 0.24)
        server.initial_camera.look_at = (0.0, -0.1, -0.05)
        server.initial_camera.up = (0.0, 0.0, 1.0)

    @staticmethod
    def _tissue_position(tissue_y_m: float) -> np.ndarray:
        x, z = TISSUE_CENTRE_XZ_M
        return base_to_world(np.array([x, tissue_y_m - 0.002, z]))

    def set_tissue_height(self, tissue_y_m: float) -> None:
        """Move the tissue surface to base-frame height ``y = tissue_y_m``."""
        if tissue_y_m != self.tissue_y_m:
            self.tissue_y_m = tissue_y_m
            self.tissue.position = self._tissue_position(tissue_y_m)

    def update(
        self,
        q_slave: np.ndarray | None,
        q_master: np.ndarray | None,
        force_est: np.ndarray | None,
        force_true: np.ndarray | None,
    ) -> None:
        """Pose the arms and arrows (only what changed by a visible amount)."""
        if q_slave is not None and _moved(self.slave.last_q, q_slave):
            _pose_arm(self.slave, q_slave)
        ghost = self.show_ghost and q_master is not None
        for handle in (*self.master.links, *self.master.joints):
            if handle.visible != ghost:
                handle.visible = ghost
        if ghost and q_master is not None and _moved(self.master.last_q, q_master):
            _pose_arm(self.master, q_master)
        tip = None if self.slave.last_q is None else omni_joint_points(self.slave.last_q)[2]
        _set_arrow(self.est_arrow, tip, force_est)
        _set_arrow(self.true_arrow, tip, force_true if self.show_true_force else None)


def _moved(previous: np.ndarray | None, q: np.ndarray, tol_rad: float = 2e-4) -> bool:
    return previous is None or bool(np.max(np.abs(previous - q)) > tol_rad)


def _set_arrow(
    handle: viser.ArrowsHandle, tip: np.ndarray | None, force: np.ndarray | None
) -> None:
    points = None if tip is None or force is None else force_arrow(tip, force, METRES_PER_NEWTON)
    if points is None:
        if handle.visible:
            handle.visible = False
        return
    if not np.allclose(handle.points, points, atol=5e-4):
        handle.points = points.astype(np.float32)
    if not handle.visible:
        handle.visible = True


__all__ = ["METRES_PER_NEWTON", "R_WORLD_BASE", "OmniScene"]
