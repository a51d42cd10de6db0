"""``teleop-force excite``: the plan, the driver's frame, and a run against a fake driver.

The fake driver is check-driver's (tests/cli/fake_sensable.py): sawSensablePhantom's
topics, measured_cp with an origin offset; it moves on its own, so what is checked here is
what excite sends and records, not how an arm follows it (tests/integration/
test_excite_identify.py does that against the simulated driver).
"""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

from teleop_force.cli.excite import (
    ExcitationConfig,
    driver_frame,
    excite,
    plan_excitation,
)
from teleop_force.cli.main import build_parser
from teleop_force.errors import ConfigurationError, DataError, TransportError
from teleop_force.io.mcap_session import SessionReader
from teleop_force.io.recordings import read_recording_with_notes
from teleop_force.robots.omni import Q_MAX_RAD, Q_MIN_RAD, tip_position_formula
from teleop_force.robots.registry import builtin_driver
from teleop_force.ros2 import codec, interfaces
from teleop_force.ros2.node import Node
from teleop_force.transport.session import (
    ZenohOptions,
    open_session,
)
from tests.cli.fake_sensable import DEVICE, DOMAIN, ORIGIN_M

pytestmark = pytest.mark.zenoh


def test_the_plan_ramps_from_the_arm_into_the_trajectory_inside_the_limits():
    config = ExcitationConfig(duration_s=20.0, ramp_s=1.0, margin_rad=0.2)
    q_start = np.array([0.5, 0.1, -0.5])
    plan = plan_excitation(config, q_start)
    assert plan.ramp_samples == 500 and plan.rate_hz == 500.0
    np.testing.assert_array_equal(plan.q_rad[0], q_start)
    steps = np.abs(np.diff(plan.q_rad, axis=0)) * plan.rate_hz
    assert steps.max() < 3.0  # rad/s: no jump at the ramp's end either
    trajectory = plan.q_rad[plan.ramp_samples :]
    assert np.all(trajectory >= Q_MIN_RAD + 0.2 - 1e-9)
    assert np.all(trajectory <= Q_MAX_RAD - 0.2 + 1e-9)
    speed = np.abs(np.diff(trajectory, axis=0)).max(axis=0) * plan.rate_hz
    assert np.all(speed > 0.5 * np.array(config.velocity_rad_s))  # the region is reached
    np.testing.assert_allclose(plan.tip_in_base_m()[7], tip_position_formula(plan.q_rad[7]))


def test_the_driver_frame_takes_the_origin_from_one_pose():
    interface = builtin_driver("sensable-phantom")
    q = np.array([0.2, 0.9, 0.3])
    cp = tip_position_formula(q) + ORIGIN_M  # the driver's origin elsewhere
    frame = driver_frame(interface, q, cp)
    np.testing.assert_allclose(frame.to_driver(tip_position_formula(q)[None, :])[0], cp)


@pytest.mark.parametrize(
    "field",
    [{"duration_s": 0.0}, {"velocity_rad_s": (0.5, -1.0, 0.5)}, {"margin_rad": -0.1},
     {"ramp_s": float("nan")}, {"seed": -1}],
)  # fmt: skip
def test_bad_settings_are_refused(field):
    with pytest.raises(ConfigurationError):
        ExcitationConfig(**field)


def test_a_region_too_fast_or_the_limits_cannot_hold_is_refused():
    with pytest.raises(ConfigurationError, match="rad/s"):
        ExcitationConfig(velocity_rad_s=(0.5, 2.5, 0.5))
    with pytest.raises(ConfigurationError, match="range smaller"):
        plan_excitation(ExcitationConfig(margin_rad=1.0), np.zeros(3))


class Commands:
    """What excite sends the driver, in order: ('servo_cp', position), ('servo_cf', force)..."""

    def __init__(self, node: Node) -> None:
        self.sent: list[tuple[str, tuple[float, ...]]] = []
        self._lock = threading.Lock()
        for kind, ros_type in (("servo_cp", interfaces.POSE_STAMPED),
                               ("servo_cf", interfaces.WRENCH_STAMPED),
                               ("hold", interfaces.EMPTY)):  # fmt: skip
            node.subscription(f"/{DEVICE}/{kind}", ros_type, self._callback(kind))

    def _callback(self, kind):
        def on_message(payload, attachment):
            if kind == "servo_cp":
                value = codec.decode_pose(payload).position_m
            elif kind == "servo_cf":
                value = codec.decode_wrench(payload).force_n
            else:
                value = ()
            with self._lock:
                self.sent.append((kind, tuple(value)))

        return on_message

    def kinds(self) -> list[str]:
        with self._lock:
            return [kind for kind, _ in self.sent]


def _args(endpoint: str, output, *extra: str):
    return build_parser().parse_args(
        ["excite", "--device", DEVICE, "--ros-domain-id", str(DOMAIN), "--connect", endpoint,
         "--no-multicast", "-o", str(output), *extra]
    )  # fmt: skip


def test_excite_sends_servo_cp_records_and_ends_with_hold(driver, endpoint, tmp_path):
    watcher = Node(driver.node.session, "test_watcher", domain_id=DOMAIN)
    commands = Commands(watcher)
    output = tmp_path / "excited.mcap"
    try:
        status = excite(
            _args(endpoint, output, "--duration", "1", "--ramp-s", "0.5"), lambda: False
        )
        kinds = commands.kinds()
    finally:
        watcher.close()
    assert status == 0
    n_cp = kinds.count("servo_cp")
    assert 600 <= n_cp <= 751, n_cp  # 1.5 s at 500 Hz (the first may miss the route)
    assert kinds[-1] == "hold" and "servo_cf" in kinds[n_cp:]
    assert all(v == (0.0, 0.0, 0.0) for k, v in commands.sent if k == "servo_cf")
    # the ramp starts where the arm is: the model's tip there, in the driver's frame
    first = np.array(next(v for k, v in commands.sent if k == "servo_cp"))
    assert np.linalg.norm(first - ORIGIN_M) < 0.3 and np.linalg.norm(first) > 0.05
    reader = SessionReader(output)
    assert reader.metadata["source"] == "excite" and "driver_description" in reader.metadata
    counts = reader.message_counts
    assert counts[f"/{DEVICE}/servo_cp"] >= n_cp and counts[f"/{DEVICE}/hold"] >= 1
    recording, notes = read_recording_with_notes(output)
    assert recording.q_rad.shape[1] == 3 and recording.t_s[-1] > 1.5
    assert "sawSensablePhantom" in notes[0]


def test_interrupted_it_still_ends_with_hold_and_says_so(driver, endpoint, tmp_path):
    watcher = Node(driver.node.session, "test_watcher", domain_id=DOMAIN)
    commands = Commands(watcher)
    ticks = itertools.count()
    try:
        status = excite(_args(endpoint, tmp_path / "cut.mcap", "--duration", "5"),
                        lambda: next(ticks) > 200)  # fmt: skip
        kinds = commands.kinds()
    finally:
        watcher.close()
    assert status == 130
    assert kinds[-1] == "hold" and kinds.count("servo_cp") < 250


def test_no_driver_names_measured_js_and_moves_nothing(endpoint, tmp_path):
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    try:
        with pytest.raises(TransportError, match=f"no message on /{DEVICE}/measured_js"):
            excite(_args(endpoint, tmp_path / "x.mcap", "--wait-s", "0.5"), lambda: False)
    finally:
        session.close()
    assert not (tmp_path / "x.mcap").exists()


def test_an_existing_recording_is_not_overwritten(tmp_path):
    output = tmp_path / "kept.mcap"
    output.write_bytes(b"precious")
    with pytest.raises(DataError, match="not overwritten"):
        excite(_args("tcp/127.0.0.1:1", output), lambda: False)
    assert output.read_bytes() == b"precious"
