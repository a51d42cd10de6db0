"""``teleop-force check-driver`` against a fake sawSensablePhantom on real Zenoh (loopback).

The fake driver publishes measured_js made with the built-in description's ``to_driver`` from
the model's q along a motion, measured_cp from the model's kinematics plus a constant origin
offset, and measured_cf, the last force it was commanded on servo_cf; its efforts are
``1000 J^T F`` (mN m), as OpenHaptics' are.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

import teleop_force.robots
from teleop_force.cli.main import main
from teleop_force.robots.omni import tip_jacobian_formula, tip_position_formula
from teleop_force.robots.registry import builtin_driver
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)
from tests.integration.teleop_helpers import wait_for

pytestmark = pytest.mark.zenoh
DEVICE = "omni_driver"
DOMAIN = 9
BUILTIN = Path(teleop_force.robots.__file__).parent / "drivers" / "sensable_phantom.toml"
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


@pytest.fixture
def endpoint() -> str:
    return listen_endpoint(free_tcp_port())


@pytest.fixture
def driver(endpoint: str) -> Iterator[FakeDriver]:
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    fake = FakeDriver(session)
    try:
        yield fake
    finally:
        fake.close()
        session.close()


def check_driver(endpoint: str, *extra: str, seconds: float = 1.5) -> int:
    return main(
        ["check-driver", "--device", DEVICE, "--ros-domain-id", str(DOMAIN), "--connect",
         endpoint, "--no-multicast", "--seconds", str(seconds), *extra]
    )  # fmt: skip


def file_with(tmp_path: Path, old: str, new: str) -> Path:
    text = BUILTIN.read_text()
    assert text.count(old) == 1, old
    path = tmp_path / "driver.toml"
    path.write_text(text.replace(old, new))
    return path


def test_the_builtin_description_passes(driver: FakeDriver, endpoint: str, capsys) -> None:
    status = check_driver(endpoint, "--driver", "sensable-phantom")
    out = capsys.readouterr().out
    assert status == 0, out
    assert "positions: pass" in out
    assert "names ['waist', 'shoulder', 'elbow']" in out
    assert "velocity absent" in out
    assert "model_q3_absolute (driver joint 'elbow')" in out
    origin = " ".join(f"{v:+.4f}" for v in ORIGIN_M)
    assert f"origins differ by {origin} m" in out
    assert driver.servo == []  # no probe: nothing commanded


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        (
            '{ joint = "shoulder", sign = 1,',
            '{ joint = "shoulder", sign = -1,',
            "positions[1].sign",
        ),
        (
            '{ joint = "elbow", sign = 1, offset_rad = 0.0 }',
            '{ joint = "elbow", sign = 1, offset_rad = 0.3 }',
            "positions[2].offset_rad",
        ),
    ],
)
def test_a_wrong_entry_fails_and_is_named(
    driver: FakeDriver, endpoint: str, tmp_path: Path, capsys, old: str, new: str, field: str
) -> None:
    status = check_driver(endpoint, "--driver", str(file_with(tmp_path, old, new)))
    out = capsys.readouterr().out
    assert status == 1, out
    assert "positions: FAIL" in out
    (finding,) = [line.strip() for line in out.splitlines() if line.startswith("  positions[")]
    assert finding.startswith(field)
    if field.endswith("offset_rad"):
        assert "by -0.3000 rad" in finding


def test_silence_names_measured_js(endpoint: str, capsys) -> None:
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    try:
        status = check_driver(endpoint, seconds=0.5)
    finally:
        session.close()
    assert status == 2
    err = capsys.readouterr().err
    assert f"no message on /{DEVICE}/measured_js" in err


def test_the_force_probe_checks_the_efforts_and_ends_at_zero(
    driver: FakeDriver, endpoint: str, capsys
) -> None:
    status = check_driver(endpoint, "--probe-force-n", "0.5")
    out = capsys.readouterr().out
    assert status == 0, out
    assert "efforts: pass" in out
    wait_for(lambda: len(driver.servo) > 0 and not np.any(driver.servo[-1]), 10.0, "zero force")
    assert np.max(np.abs(np.array(driver.servo))) == pytest.approx(0.5)
    assert not np.any(driver.servo[-1])


def test_a_wrong_effort_unit_is_named(
    driver: FakeDriver, endpoint: str, tmp_path: Path, capsys
) -> None:
    path = file_with(tmp_path, 'effort_unit = "mN m"', 'effort_unit = "N m"')
    status = check_driver(endpoint, "--driver", str(path), "--probe-force-n", "0.5")
    out = capsys.readouterr().out
    assert status == 1, out
    assert "positions: pass" in out
    assert "efforts: FAIL" in out
    assert "effort_unit looks wrong" in out
    wait_for(lambda: len(driver.servo) > 0 and not np.any(driver.servo[-1]), 10.0, "zero force")
    assert not np.any(driver.servo[-1])


def test_a_probe_force_above_one_newton_is_refused(endpoint: str, capsys) -> None:
    assert check_driver(endpoint, "--probe-force-n", "1.5") == 2
    assert "--probe-force-n must be > 0 and at most 1 N" in capsys.readouterr().err
