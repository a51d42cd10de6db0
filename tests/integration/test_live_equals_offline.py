"""Live equals offline: ``teleop-force serve``'s estimates against ``estimate`` on a recording.

The recording is made by another process (the session recorder), as a lab would record a
session with its own tools; the recorded estimates are decoded by a third-party ROS 2 decoder
(``mcap-ros2-support``), not by the project.
"""

from __future__ import annotations

import csv
import time

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from teleop_helpers import STARTUP_TIMEOUT_S, python_module, spawn, stop, wait_for

from teleop_force.models import DEFAULT_MODEL_PATH
from teleop_force.ros2 import topics
from teleop_force.transport import keys
from teleop_force.transport.pubsub import query_json
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)
from tests.ros2_traffic import Collector, JointStatePublisher, joint_states_500hz

pytestmark = pytest.mark.zenoh
DEVICE = "lab_slave"
DOMAIN = 9
N = 400


def _recorded(path) -> dict[str, list[tuple[int, object]]]:
    """Every recorded message by topic: (MCAP sequence, decoded by mcap-ros2-support)."""
    by_topic: dict[str, list[tuple[int, object]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            by_topic.setdefault(channel.topic, []).append((message.sequence, decoded))
    return by_topic


def test_serve_equals_estimate_on_the_recorders_recording(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN))
    endpoint = listen_endpoint(free_tcp_port())
    recording = tmp_path / "session.mcap"
    zenoh_args = ("--connect", endpoint, "--listen", "tcp/127.0.0.1:0", "--no-multicast")
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    recorder = spawn(
        python_module(
            "teleop_force.service.session_recorder", "--record", str(recording),
            "--device", DEVICE, *zenoh_args,
        ),
        tmp_path / "recorder.log",
    )  # fmt: skip
    serve = spawn(
        python_module(
            "teleop_force.cli.main", "serve", "--model", str(DEFAULT_MODEL_PATH),
            "--device", DEVICE, "--ros-domain-id", str(DOMAIN), "--no-residual-watch",
            *zenoh_args,
        ),
        tmp_path / "serve.log",
    )  # fmt: skip
    driver = live = None
    stream = joint_states_500hz(N)
    try:
        wait_for(lambda: "no joint state yet" in (tmp_path / "serve.log").read_text(),
                 STARTUP_TIMEOUT_S, "the service")  # fmt: skip
        wait_for(lambda: query_json(session, keys.process_stats(DEVICE, "recorder"), 2.0),
                 STARTUP_TIMEOUT_S, "the recorder")  # fmt: skip
        driver = JointStatePublisher(session, DEVICE, "sensable_phantom")
        live = Collector(session, DEVICE, topics.ESTIMATED_CF)
        wait_for(lambda: driver.publisher.zenoh_publisher.matching_status.matching, 30.0,
                 "the subscriptions")  # fmt: skip
        time.sleep(0.5)  # the recorder's catch-all subscription too
        for js in stream:
            driver.send(js)
            time.sleep(0.001)
        wait_for(lambda: len(live) == N, 30.0, "the live estimates")
        time.sleep(0.5)  # the recorder's last drain takes what arrived
    finally:
        for entity in (live, driver):
            if entity is not None:
                entity.close()
        assert stop(serve) == 0, (tmp_path / "serve.log").read_text()
        assert stop(recorder) == 0, (tmp_path / "recorder.log").read_text()
        session.close()

    recorded = _recorded(recording)
    # the sequence coverage: every joint state and every estimate, in both
    js_recorded = recorded[f"/{DEVICE}/measured_js"]
    assert [seq for seq, _ in js_recorded] == [js.seq for js in stream]
    estimates_recorded = recorded[f"/{DEVICE}/estimated_cf"]
    assert len(estimates_recorded) == N
    assert [e.source_seq for e in live.messages] == [js.seq for js in stream]

    forces_csv = tmp_path / "forces.csv"
    import subprocess

    result = subprocess.run(
        python_module("teleop_force.cli.main", "estimate", str(DEFAULT_MODEL_PATH),
                      str(recording), "-o", str(forces_csv)),
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    with open(forces_csv, newline="") as f:
        rows = list(csv.DictReader(f))
    offline = np.array([[float(r["f_x"]), float(r["f_y"]), float(r["f_z"])] for r in rows])
    assert offline.shape == (N, 3)
    live_n = np.array([e.f_n for e in live.messages])
    third_party_n = np.array(
        [[d.wrench.force.x, d.wrench.force.y, d.wrench.force.z] for _, d in estimates_recorded]
    )
    scale = max(1.0, float(np.abs(offline).max()))
    np.testing.assert_allclose(live_n, offline, rtol=0, atol=1e-9 * scale)
    np.testing.assert_array_equal(third_party_n, live_n)  # the recorder kept the bytes
    assert all(d.header.frame_id == topics.BASE_FRAME for _, d in estimates_recorded)
