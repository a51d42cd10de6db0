"""The examples and the README's Python snippets run and print what they promise.

Each example runs as a user would run it (``python examples/NN_*.py``), in a subprocess. The
Zenoh client of ``02`` and of the README connect over 127.0.0.1 to a real replay of
``recordings/palpation_demo.mcap`` through the service (multicast scouting off).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from teleop_force.transport.session import free_tcp_port

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
README = ROOT / "README.md"
RECORDING = ROOT / "recordings" / "palpation_demo.mcap"


def run_python(args: list[str], timeout_s: float = 300.0) -> subprocess.CompletedProcess[str]:
    result = subprocess.run(
        [sys.executable, *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    assert result.returncode == 0, f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    return result


def readme_python_block(marker: str) -> str:
    """The README's ```python block that contains ``marker``."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
    matching = [b for b in blocks if marker in b]
    assert len(matching) == 1, f"expected one README python block with {marker!r}"
    return matching[0]


def test_every_example_is_tested() -> None:
    names = sorted(p.name for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert names == [
        "01_identify_and_estimate.py",
        "02_subscribe_to_estimates.py",
        "03_close_the_loop.py",
    ]


def test_identify_and_estimate() -> None:
    out = run_python([str(EXAMPLES / "01_identify_and_estimate.py")]).stdout
    errors = {a: float(e) for a, e in re.findall(r"f_([xyz]): RMS error ([0-9.]+) N", out)}
    true = {a: float(t) for a, t in re.findall(r"f_([xyz]):.*true force RMS ([0-9.]+) N", out)}
    assert set(errors) == {"x", "y", "z"}, out
    # Pressing down: f_y carries the force (~1.7 N); the estimate is within 15 % of it.
    assert true["y"] > 1.0, out
    assert errors["y"] < 0.15 * true["y"], out


def test_close_the_loop_names_the_planted_cogging() -> None:
    out = run_python([str(EXAMPLES / "03_close_the_loop.py")]).stdout
    found = re.findall(r"found: joint (\d+): (\S+)\(([^)]*)\)", out)
    assert found, out
    assert found[0][0] == "1" and found[0][2] == "q1", out  # first: joint 1, periodic in q1
    before, after = map(float, re.search(r"joint 1: .* ([0-9.]+)% -> ([0-9.]+)%", out).groups())
    assert after < 0.6 * before, out


def test_readme_identify_snippet_runs() -> None:
    run_python(["-c", readme_python_block("identify_model")])


@contextlib.contextmanager
def replay_with_service(port: int, log: Path) -> Iterator[str]:
    """A replay of the shipped recording through the service, listening on 127.0.0.1:port."""
    endpoint = f"tcp/127.0.0.1:{port}"
    argv = [
        sys.executable, "-m", "teleop_force.cli.main", "replay", str(RECORDING),
        "--with-service", "--no-multicast", "--listen", endpoint,
    ]  # fmt: skip
    with open(log, "wb") as out:
        process = subprocess.Popen(
            argv, cwd=ROOT, stdout=out, stderr=out, stdin=subprocess.DEVNULL,
            start_new_session=True,
        )  # fmt: skip
    try:
        yield endpoint
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(15.0)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(15.0)


@pytest.mark.zenoh
def test_subscribe_to_estimates(tmp_path: Path) -> None:
    with replay_with_service(free_tcp_port(), tmp_path / "replay.log") as endpoint:
        args = [str(EXAMPLES / "02_subscribe_to_estimates.py"), "--connect", endpoint]
        result = run_python([*args, "--count", "300", "--timeout", "90"])
    out = result.stdout
    assert "received 300 estimates" in out, out
    forces = re.findall(r"F = \(([-+0-9.]+), ([-+0-9.]+), ([-+0-9.]+)\) N", out)
    assert len(forces) == 3, out  # estimates 1, 101, 201 printed
    assert all(abs(float(f)) < 5.0 for row in forces for f in row), out


@pytest.mark.zenoh
def test_readme_zenoh_client_runs(tmp_path: Path) -> None:
    code = readme_python_block("estimated_cf")
    assert "tcp/127.0.0.1:7447" in code
    with replay_with_service(free_tcp_port(), tmp_path / "replay.log") as endpoint:
        # the README client listens for a fixed time: start it once estimates flow
        probe = [str(EXAMPLES / "02_subscribe_to_estimates.py"), "--connect", endpoint]
        run_python([*probe, "--count", "1", "--timeout", "90"])
        result = run_python(["-c", code.replace("tcp/127.0.0.1:7447", endpoint)])
    assert re.search(r"seq \d+: F = \(", result.stdout), result.stdout
