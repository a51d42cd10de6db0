"""``teleop-force check-driver`` against a fake sawSensablePhantom on real Zenoh (loopback).

The fake driver publishes measured_js made with the built-in description's ``to_driver`` from
the model's q along a motion, measured_cp from the model's kinematics plus a constant origin
offset, and measured_cf, the last force it was commanded on servo_cf; its efforts are
``1000 J^T F`` (mN m), as OpenHaptics' are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import teleop_force.robots
from teleop_force.cli.main import main
from teleop_force.transport.session import (
    ZenohOptions,
    open_session,
)
from tests.cli.fake_sensable import DEVICE, DOMAIN, ORIGIN_M, FakeDriver
from tests.integration.teleop_helpers import wait_for

pytestmark = pytest.mark.zenoh
BUILTIN = Path(teleop_force.robots.__file__).parent / "drivers" / "sensable_phantom.toml"


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
