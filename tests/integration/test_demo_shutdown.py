"""``teleop-force demo`` starts everything and leaves no process behind.

Each demo gets a Zenoh port of its own (``--zenoh-port``): it starts its router there, a child
like the others, and no other demo on the machine (7447 is the default) is joined.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest
from ros2_traffic import put
from teleop_helpers import STARTUP_TIMEOUT_S, alive, python_module, started_pids, wait_for

from teleop_force.cli import demo
from teleop_force.ros2 import codec, topics
from teleop_force.ros2.node import Node
from teleop_force.service.accuracy import AccuracyConfig
from teleop_force.transport import messages as m
from teleop_force.transport.session import free_tcp_port

CHILDREN = {"router", "recorder", "service", "slave", "master"}

pytestmark = pytest.mark.zenoh  # the demo's processes talk over Zenoh on loopback


def run_demo(tmp_path, *extra: str) -> subprocess.Popen:
    command = python_module(
        "teleop_force.cli.main", "demo", "--headless", "--record-dir", str(tmp_path),
        "--summary-json", str(tmp_path / "summary.json"), "--zenoh-port", str(free_tcp_port()),
        *extra,
    )  # fmt: skip
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)  # fmt: skip


def finish(process: subprocess.Popen, timeout_s: float) -> str:
    try:
        out, _ = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        out, _ = process.communicate()
        raise AssertionError(f"demo did not stop:\n{out}") from None
    return out


def wait_until_up(
    process: subprocess.Popen, until: str = "all processes up"
) -> tuple[list[str], list[int]]:
    """Read the demo's output until the line with ``until``; return the lines and child pids."""
    assert process.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + STARTUP_TIMEOUT_S * 3
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        lines.append(line)
        if until in line or not line:
            break
    assert any(until in line for line in lines), "".join(lines)
    started = started_pids("".join(lines))
    assert set(started) == CHILDREN, "".join(lines)
    return lines, list(started.values())


def test_demo_runs_for_its_duration_and_leaves_nothing(tmp_path):
    process = run_demo(tmp_path, "--duration", "2")
    out = finish(process, STARTUP_TIMEOUT_S * 3 + 60)
    assert process.returncode == 0, out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ok"], out
    assert set(summary["pids"]) == CHILDREN
    port = summary["zenoh_endpoint"].rsplit(":", 1)[1]
    assert f"started router (pid {summary['pids']['router']}) on tcp/127.0.0.1:{port}" in out
    assert not [name for name, pid in summary["pids"].items() if alive(pid)]
    assert "== demo summary ==" in out and "messages lost:" in out
    assert "dashboard: not started (--headless)" in out
    assert summary["messages_lost"]["total"] == 0
    assert summary["slave_to_estimate_latency_ms"]["count"] > 500
    # the real-time figures (their values depend on the machine: printed, not asserted)
    for name in ("master", "slave"):
        loop = summary["loops"][name]
        assert loop["ticks"] > 500 and loop["expected_ticks"] > 500
        assert loop["ticks_fraction"] == pytest.approx(loop["ticks"] / loop["expected_ticks"], 1e-3)
        assert loop["overruns"] == summary["loop_overruns"][name] <= loop["ticks"]
        assert summary["loop_overrun_fraction"][name] == loop["overrun_fraction"]
        assert loop["missed_ticks"] >= 0
        print(f"{name} loop: {loop}")
    assert summary["slave_holds"] is not None
    cpu = summary["cpu_percent"]
    assert set(cpu) == CHILDREN | {"supervisor", "total"}
    assert cpu["total"] == pytest.approx(sum(v for k, v in cpu.items() if k != "total"), abs=0.2)
    assert summary["cpu_percent_of_one_core"] == cpu
    assert (
        len(summary["machine_load_average"]) == len(summary["machine_load_average_at_start"]) == 3
    )
    assert set(summary["scheduling"]) == CHILDREN
    print(f"CPU {cpu}, scheduling {summary['scheduling']}")
    assert "slave loop:" in out and "master loop:" in out and "slave holds:" in out
    assert (tmp_path / summary["recording"].split("/")[-1]).stat().st_size > 10_000


def test_demo_stops_everything_on_sigterm(tmp_path):
    process = run_demo(tmp_path)  # no duration: runs until signalled
    # SIGTERM before the first estimate is a failed run (exit 1): signal a running demo
    lines, pids = wait_until_up(process, until="first estimate ")
    time.sleep(0.5)
    process.send_signal(signal.SIGTERM)
    out = "".join(lines) + finish(process, 60)
    assert process.returncode == 0, out
    wait_for(lambda: not any(alive(pid) for pid in pids), 5.0, "children to be gone")


@pytest.mark.slow  # opt-in (-m slow): a third demo start-up costs ~10 s on a busy machine
def test_children_go_when_the_supervisor_is_killed(tmp_path):
    process = run_demo(tmp_path)
    _, pids = wait_until_up(process)
    process.send_signal(signal.SIGKILL)  # no clean-up by the supervisor: PR_SET_PDEATHSIG
    process.communicate(timeout=30)
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and any(alive(pid) for pid in pids):
        time.sleep(0.05)
    left = [pid for pid in pids if alive(pid)]
    for pid in left:  # do not leave them behind if the test fails
        os.kill(pid, signal.SIGKILL)
    logs = "".join(p.read_text() for p in tmp_path.glob("*.log"))
    assert not left, f"children still alive 30 s after the supervisor died: {left}\n{logs}"


def test_monitor_drains_its_ring_channels(zenoh_pair):
    monitor = demo._Monitor("mon_slave", AccuracyConfig())
    subscribers = monitor.subscribe(zenoh_pair.listener)
    kept = monitor.session_monitor
    node = Node(zenoh_pair.connector, "test_slave")
    publishers = {
        topic: node.publisher(topics.topic_name("mon_slave", topic), topic.ros_type)
        for topic in (topics.TRUE_CF, topics.ESTIMATED_CF, topics.ESTIMATE_DIAGNOSTICS,
                      topics.STATUS)
    }  # fmt: skip
    try:
        for publisher in publishers.values():
            wait_for(
                lambda p=publisher.zenoh_publisher: p.matching_status.matching,
                10.0, "the monitor's subscriber",
            )  # fmt: skip
        time.sleep(0.2)  # let the routes settle
        for k in range(1, 301):
            true_force = m.ContactForce(k, 1000 + k, (0.0, -1.0, 0.0))
            put(publishers[topics.TRUE_CF], codec.encode_contact_force(true_force, "base"), k)
            estimate = m.ForceEstimateMessage(
                k, 1000 + k, k, (0.0, -1.1, 0.0), [0.0] * 3, [True] * 3, [1.0] * 3, [0.0] * 3,
                [0.0] * 3,
            )  # fmt: skip
            wrench, diagnostics = codec.encode_estimate(estimate, (), topics.BASE_FRAME)
            put(publishers[topics.ESTIMATED_CF], wrench, k)
            put(publishers[topics.ESTIMATE_DIAGNOSTICS], diagnostics, k)
        status = codec.encode_status(m.Status(0, 0, m.SafetyState.FOLLOWING, "ok"))
        put(publishers[topics.STATUS], status, 1)
        wait_for(lambda: kept.estimates.received == 300, 10.0, "the monitor to drain")
        wait_for(lambda: kept.state == "following", 10.0, "the status")
    finally:
        monitor.close()
        node.close()
        for subscriber in subscribers:
            subscriber.undeclare()
    assert kept.true_forces.received == 300 and kept.true_forces.lost == 0
    assert kept.estimates.lost == 0 and monitor.figures()["malformed"] == 0
    assert kept.accuracy.summary()["paired_samples"] == 300
