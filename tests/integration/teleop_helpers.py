"""Helpers of the integration tests: real processes on 127.0.0.1, started and stopped.

The Zenoh sessions of the tests themselves are fixtures of tests/conftest.py.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time

STARTUP_TIMEOUT_S = 90.0  # the machine is shared: imports can take long under load
#: A line of ``teleop-force demo``: ``started <name> (pid <pid>)`` (the router's ends
#: `` on <endpoint>``).
_STARTED = re.compile(r"started (\w+) \(pid (\d+)\)")


def started_pids(text: str) -> dict[str, int]:
    """The children a demo's output says it started: ``{name: pid}``."""
    return {name: int(pid) for name, pid in _STARTED.findall(text)}


def python_module(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def spawn(argv: list[str], log_path) -> subprocess.Popen:
    log = open(log_path, "ab")  # noqa: SIM115 - closed with the process
    return subprocess.Popen(
        argv, stdout=log, stderr=log, stdin=subprocess.DEVNULL, start_new_session=True
    )


def stop(process: subprocess.Popen, signum: int = signal.SIGTERM, timeout_s: float = 15.0) -> int:
    if process.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signum)
        try:
            process.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(timeout_s)
    return process.returncode


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is not alive
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def tcp_port_open(port: int, host: str = "127.0.0.1") -> bool:
    """Whether something accepts TCP connections on ``host:port`` (e.g. the dashboard)."""
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


def wait_for(predicate, timeout_s: float, what: str, interval_s: float = 0.01) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(interval_s)
