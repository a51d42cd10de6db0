"""The 3D scene: slave Omni, translucent master ghost, tissue plane and force arrows.

Everything is computed in the Omni base frame (y up, z toward the user) and mapped to viser's
z-up world with :func:`web.geometry.base_to_world`; the camera starts in front of the arm, to
the user's right, so motion toward the user and up/down (the base y-z plane) reads well.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import viser

from teleop_force.robots.omni import FOREARM_LENGTH_M, UPPER_ARM_LENGTH_M
from web.geometry import (
    R_WORLD_BASE,
    arm_frame_quats,
    base_to_world,
    force_arrow,
    omni_joint_points,
)

LINK_RADIUS_M: Final = 0.009
JOINT_RADIUS_M: Final = 0.013
TIP_RADIUS_M: Final = 0.011
#: Arrow length per newton of force.
METRES_PER_NEWTON: Final = 0.04
TISSUE_SIZE_M: Final = (0.32, 0.22)
#: Centre of the tissue plane in the base frame (x, z): in front of the arm, toward the user.
TISSUE_CENTRE_XZ_M: Final = (0.0, 0.17)
SLAVE_RGB: Final = (150, 156, 168)
MASTER_RGB: Final = (66, 133, 244)
EST_FORCE_RGB: Final = (242, 153, 0)
TRUE_FORCE_RGB: Final = (30, 142, 62)
UNTRUSTED_FORCE_RGB: Final = (217, 48, 37)
TISSUE_RGB: Final = (234, 140, 150)
#: Quaternion of :data:`R_WORLD_BASE` (+90 degrees about x).
BASE_FRAME_WXYZ: Final = (np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0)


@dataclass
class _Arm:
    """Scene handles of one drawn arm: a root in the base frame and three joint frames."""

    root: viser.FrameHandle
    frames: tuple[viser.FrameHandle, viser.FrameHandle, viser.FrameHandle]
    last_q: np.ndarray | None = None


def _add_arm(
    scene: viser.SceneApi, name: str, rgb: tuple[int, int, int], opacity: float | None
) -> _Arm:
    """Add an arm as a kinematic tree (root -> yaw -> shoulder -> elbow), links along +z."""
    flat: dict[str, Any] = {"opacity": opacity, "cast_shadow": False, "receive_shadow": False}
    root = scene.add_frame(f"/{name}", show_axes=False, wxyz=BASE_FRAME_WXYZ)
    yaw = scene.add_frame(f"/{name}/yaw", show_axes=False)
    shoulder = scene.add_frame(f"/{name}/yaw/shoulder", show_axes=False)
    elbow = scene.add_frame(
        f"/{name}/yaw/shoulder/elbow", show_axes=False, position=(0.0, 0.0, UPPER_ARM_LENGTH_M)
    )
    base = f"/{name}/yaw/shoulder"
    scene.add_icosphere(f"{base}/joint", radius=JOINT_RADIUS_M, color=rgb, subdivisions=2, **flat)
    scene.add_cylinder(
        f"{base}/upper_arm", radius=LINK_RADIUS_M, height=UPPER_ARM_LENGTH_M, color=rgb,
        position=(0.0, 0.0, UPPER_ARM_LENGTH_M / 2), **flat,
    )  # fmt: skip
    scene.add_icosphere(
        f"{base}/elbow/joint", radius=JOINT_RADIUS_M, color=rgb, subdivisions=2, **flat
    )
    scene.add_cylinder(
        f"{base}/elbow/forearm", radius=LINK_RADIUS_M, height=FOREARM_LENGTH_M, color=rgb,
        position=(0.0, 0.0, FOREARM_LENGTH_M / 2), **flat,
    )  # fmt: skip
    scene.add_icosphere(
        f"{base}/elbow/tip", radius=TIP_RADIUS_M, color=rgb, subdivisions=2,
        position=(0.0, 0.0, FOREARM_LENGTH_M), **flat,
    )  # fmt: skip
    arm = _Arm(root, (yaw, shoulder, elbow))
    _pose_arm(arm, np.array([0.0, 0.6, 0.3]))
    return arm


def _pose_arm(arm: _Arm, q: np.ndarray) -> None:
    for frame, wxyz in zip(arm.frames, arm_frame_quats(q), strict=True):
        frame.wxyz = wxyz
    arm.last_q = np.asarray(q, dtype=float).copy()


class OmniScene:
    """Scene handles of the dashboard and their per-frame update."""

    def __init__(self, server: viser.ViserServer, tissue_y_m: float) -> None:
        """Build the static scene (base, tissue), the two arms and the initial camera."""
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
        self.master.root.visible = False
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
        self.verdict_label = scene.add_label(
            "/verdict", "waiting", position=base_to_world(np.array([0.0, 0.09, 0.0])),
            anchor="bottom-center", font_screen_scale=1.4,
        )  # fmt: skip
        self._verdict: tuple[str, bool] | None = None
        self.show_true_force = True
        self.show_ghost = True
        server.initial_camera.position = (0.5, -0.42, 0.2)
        server.initial_camera.look_at = (0.0, -0.1, -0.04)
        server.initial_camera.up = (0.0, 0.0, 1.0)

    def set_verdict(self, text: str, trusted: bool) -> None:
        """Show the trust verdict in the 3D view; the estimated force turns red if untrusted."""
        if self._verdict == (text, trusted):
            return
        self._verdict = (text, trusted)
        self.verdict_label.text = text if trusted else f"DO NOT TRUST: {text}"
        rgb = EST_FORCE_RGB if trusted else UNTRUSTED_FORCE_RGB
        self.est_arrow.colors = np.array(rgb, dtype=np.uint8)

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
        if self.master.root.visible != ghost:
            self.master.root.visible = ghost
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
