"""Identification through a driver: excite the simulated sawSensablePhantom, identify, estimate.

The shipped model was identified at 1 kHz on the simulated Omni's own stream (model
coordinates, this frame's torque). Through the driver the stream is 500 Hz, in the driver's
conventions, with the previous frame's torque, while the driver's own Cartesian PD moves the
arm. ``teleop-force excite`` plays the training trajectory through servo_cp and records what
the driver publishes; ``identify`` fits a model on that recording, and its free-space force
estimate on a second excitation (another seed: held out, not used for fitting) must be
smaller than the shipped model's on the same samples. The figures are printed (``-s``).
"""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop, wait_for

from teleop_force.cli.main import main
from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import interfaces
from teleop_force.ros2.node import Node

pytestmark = pytest.mark.zenoh
DEVICE = "sim_phantom"
TRAIN_S = 60.0
HELD_OUT_S = 20.0
RAMP_S = 2.0
EXCITE_TIMEOUT_S = 120.0


def _excite(connect: list[str], output, seconds: float, seed: int) -> subprocess.CompletedProcess:
    return subprocess.run(
        python_module("teleop_force.cli.main", "excite", "--device", DEVICE, "--duration",
                      str(seconds), "--ramp-s", str(RAMP_S), "--seed", str(seed), "--json",
                      "-o", str(output), *connect),
        capture_output=True, text=True, timeout=EXCITE_TIMEOUT_S + seconds, check=False,
    )  # fmt: skip


def _free_space_force_n(model, recording, tmp_path, name: str) -> np.ndarray:
    """|F| of ``estimate MODEL`` on the held-out recording, after the ramp, before the hold."""
    forces = tmp_path / f"{name}.csv"
    assert main(["estimate", str(model), str(recording), "-o", str(forces)]) == 0
    table = np.loadtxt(forces, delimiter=",", skiprows=1)
    t = table[:, 0]
    inside = (t > RAMP_S + 3.0) & (t < t[-1] - 1.5)  # the estimators settled, still moving
    norm = np.linalg.norm(table[inside, 1:4], axis=1)
    return norm[np.isfinite(norm)]


def test_excite_then_identify_beats_the_shipped_model_through_the_driver(
    tmp_path, zenoh_rendezvous, capsys
):
    connect = zenoh_rendezvous.process_args
    log = tmp_path / "driver.log"
    node = Node(zenoh_rendezvous.session, "test_watch")
    seen = []
    node.subscription(f"/{DEVICE}/measured_js", interfaces.JOINT_STATE,
                      lambda payload, attachment: seen.append(1))  # fmt: skip
    driver = spawn(python_module("master_slave.sensable_driver", "--name", DEVICE, *connect), log)
    train, held_out = tmp_path / "train.mcap", tmp_path / "held_out.mcap"
    try:
        wait_for(lambda: len(seen) > 0, STARTUP_TIMEOUT_S, "the simulated driver")
        for output, seconds, seed in ((train, TRAIN_S, 1), (held_out, HELD_OUT_S, 2)):
            done = _excite(connect, output, seconds, seed)
            assert done.returncode == 0, done.stderr
            assert '"interrupted": false' in done.stdout
        assert driver.poll() is None, log.read_text()
    finally:
        stop(driver)
        node.close()
    model = tmp_path / "identified.json"
    assert main(["identify", str(train), "-o", str(model)]) == 0
    assert "converted from driver sawSensablePhantom" in capsys.readouterr().err
    before = _free_space_force_n(DEFAULT_MODEL_PATH, held_out, tmp_path, "shipped")
    after = _free_space_force_n(model, held_out, tmp_path, "identified")
    figures = {
        name: (float(np.median(f)), float(np.percentile(f, 95)), f.size)
        for name, f in (("shipped omni_sim.json", before), ("identified through the driver", after))
    }
    with capsys.disabled():
        for name, (median, p95, n) in figures.items():
            print(f"\nfree-space |F| on the held-out excitation, {name}: median {median:.3f} N, "
                  f"p95 {p95:.3f} N ({n} samples)")  # fmt: skip
    assert before.size > 0.9 * (HELD_OUT_S - 4.5) * 500
    assert np.median(after) < np.median(before)
    assert np.percentile(after, 95) < np.percentile(before, 95)


def test_excite_without_a_driver_exits_2_naming_the_topic(tmp_path, zenoh_rendezvous):
    done = subprocess.run(
        python_module("teleop_force.cli.main", "excite", "--device", "nobody", "--wait-s", "1",
                      "-o", str(tmp_path / "none.mcap"), *zenoh_rendezvous.process_args),
        capture_output=True, text=True, timeout=STARTUP_TIMEOUT_S, check=False,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "no message on /nobody/measured_js" in done.stderr
    assert not (tmp_path / "none.mcap").exists()
