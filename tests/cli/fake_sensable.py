"""A fake sawSensablePhantom on real Zenoh, for the live-driver commands' tests.

It publishes measured_js made with the built-in description's ``to_driver`` from the model's q
along a motion of its own, measured_cp from the model's kinematics plus a constant origin
offset, and measured_cf, the last force it was commanded on servo_cf; its efforts are
``1000 J^T F`` (mN m), as OpenHaptics' are.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from teleop_force.robots.omni import tip_jacobian_formula, tip_position_formula
from teleop_force.robots.registry import builtin_driver
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node

DEVICE = "omni_driver"
DOMAIN = 9
#: OpenHaptics' origin in the model's base frame (any constant: the check fits it).
ORIGIN_M = np.array([0.012, -0.087, -0.064])
PERIOD_S = 0.005
T0_NS = 1_764_158_400_000_000_000


def model_q(t: float) -> np.ndarray:
    """A motion through the workspace: every joint moves, no pose repeats within seconds."""
    return np.array(
        [
            0.45 * np.sin(2.1 * t + 0.3),
            0.85 + 0.4 * np.sin(2.9 * t + 1.0),
            0.25 + 0.45 * np.sin(3.7 * t + 2.0),
        ]
    )


class FakeDriver:
    """sawSensablePhantom's ROS 2 topics, played at 200 Hz on a thread."""

    def __init__(self, session: object) -> None:
        self.truth = builtin_driver("sensable-phantom")
        self.node = Node(session, "sensable_phantom", domain_id=DOMAIN)  # type: ignore[arg-type]
        name = lambda kind: f"/{DEVICE}/{kind}"  # noqa: E731
        self.js = self.node.publisher(name("measured_js"), topics.MEASURED_JS.ros_type)
        self.cp = self.node.publisher(name("measured_cp"), "geometry_msgs/msg/PoseStamped")
        self.cf = self.node.publisher(name("measured_cf"), "geometry_msgs/msg/WrenchStamped")
        self.force_n = np.zeros(3)
        self.servo: list[np.ndarray] = []
        self._lock = threading.Lock()
        self.node.subscription(name("servo_cf"), "geometry_msgs/msg/WrenchStamped", self._on_cf)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _on_cf(self, payload: bytes, attachment: Attachment) -> None:
        force = np.asarray(codec.decode_wrench(payload).force_n)
        with self._lock:
            self.force_n = force
            self.servo.append(force)

    def _run(self) -> None:
        k = 0
        start = time.monotonic()
        while not self._stop.is_set():
            t = k * PERIOD_S
            t_ns = T0_NS + k * int(PERIOD_S * 1e9)
            with self._lock:
                force = self.force_n.copy()
            q = model_q(t)
            tau_nm = tip_jacobian_formula(q).T @ force
            names, position, effort = self.truth.to_driver(q, tau_nm)
            assert effort is not None
            self.js.publish(codec.encode_joint_state_parts(t_ns, names, "", position, (), effort))
            self.cp.publish(codec.encode_pose(t_ns, tip_position_formula(q) + ORIGIN_M, "base"))
            self.cf.publish(codec.encode_wrench(t_ns, force, "base"))
            k += 1
            self._stop.wait(max(0.0, start + k * PERIOD_S - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.node.close()
