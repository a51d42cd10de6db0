"""``teleop-force demo`` starts everything and leaves no process behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest
from teleop_helpers import STARTUP_TIMEOUT_S, alive, python_module, wait_for

pytestmark = pytest.mark.zenoh  # the demo's processes talk over Zenoh on loopback


def run_demo(tmp_path, *extra: str) -> subprocess.Popen:
    command = python_module(
        "teleop_force.cli.main", "demo", "--headless", "--record-dir", str(tmp_path),
        "--summary-json", str(tmp_path / "summary.json"), *extra,
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


def wait_until_up(process: subprocess.Popen) -> tuple[list[str], list[int]]:
    """Read the demo's output until every process is up; return the lines and child pids."""
    assert process.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + STARTUP_TIMEOUT_S * 3
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        lines.append(line)
        if "all processes up" in line or not line:
            break
    assert any("all processes up" in line for line in lines), "".join(lines)
    pids = [int(line.split("pid ")[1].rstrip(")\n")) for line in lines if "(pid " in line]
    assert len(pids) == 3, "".join(lines)
    return lines, pids


def test_demo_runs_for_its_duration_and_leaves_nothing(tmp_path):
    process = run_demo(tmp_path, "--duration", "2")
    out = finish(process, STARTUP_TIMEOUT_S * 3 + 60)
    assert process.returncode == 0, out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ok"], out
    assert set(summary["pids"]) == {"service", "slave", "master"}
    assert not [name for name, pid in summary["pids"].items() if alive(pid)]
    assert "== demo summary ==" in out and "messages lost:" in out
    assert "dashboard: not started (--headless)" in out
    assert summary["messages_lost"]["total"] == 0
    assert summary["slave_to_estimate_latency_ms"]["count"] > 500
    assert (tmp_path / summary["recording"].split("/")[-1]).stat().st_size > 10_000


def test_demo_stops_everything_on_sigterm(tmp_path):
    process = run_demo(tmp_path)  # no duration: runs until signalled
    lines, pids = wait_until_up(process)
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
