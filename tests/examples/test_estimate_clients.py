"""The estimate clients (examples 02 and 04, the README's two) print the forces published.

Each client runs as a user would run it, in a subprocess, and imports nothing of this
project. It connects over 127.0.0.1 (multicast scouting off) to a peer that publishes known
estimates as the service does: a :class:`teleop_force.ros2.node.Node` putting
:func:`teleop_force.ros2.codec.encode_estimate`'s WrenchStamped and EstimateDiagnostics on
rmw_zenoh's keys, with its attachment. Estimate ``k`` (attachment sequence number ``k + 1``)
has the force :func:`published_force`, so every force a client prints is checked against the
one published under the sequence number it prints.

The plain client's hand-written CDR parse is checked against ``rosbags``' ``deserialize_cdr``
(and rclpy's serializer) on generated values, frame_id strings of 0 to 20 characters included.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import re
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teleop_force.ros2 import codec, interfaces, topics
from teleop_force.ros2.node import Node
from teleop_force.transport import messages as m
from teleop_force.transport.session import (
    ZenohOptions,
    free_tcp_port,
    listen_endpoint,
    open_session,
)

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
README = ROOT / "README.md"
PLAIN = EXAMPLES / "02_subscribe_to_estimates.py"
RCLPY = EXAMPLES / "04_subscribe_with_rclpy.py"
ESTIMATE_LINE = re.compile(
    r"estimate (\d+): F = \(([-+0-9.]+), ([-+0-9.]+), ([-+0-9.]+)\) N, latency -?[0-9.]+ ms"
)
README_LINE = re.compile(r"^(\d+): F = \(([-+0-9.]+), ([-+0-9.]+), ([-+0-9.]+)\) N", re.M)


def published_force(seq: int) -> tuple[float, float, float]:
    """The force [N] published with attachment sequence number ``seq`` (exact in 3 decimals)."""
    k = seq - 1
    return (0.25 * (k % 8), -0.125 * (k % 16), 1.5 + 0.5 * (k % 4))


def load_plain_client() -> ModuleType:
    spec = importlib.util.spec_from_file_location("plain_estimate_client", PLAIN)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@contextlib.contextmanager
def estimate_publisher() -> Iterator[str]:
    """A peer on 127.0.0.1 publishing estimates of device ``slave`` at ~1 kHz; its endpoint."""
    endpoint = listen_endpoint(free_tcp_port())
    session = open_session(ZenohOptions(mode="peer", listen=(endpoint,), multicast_scouting=False))
    node = Node(session, "test_estimator", domain_id=0)
    wrenches = node.publisher(
        topics.topic_name("slave", topics.ESTIMATED_CF), interfaces.WRENCH_STAMPED
    )
    diagnostics = node.publisher(
        topics.topic_name("slave", topics.ESTIMATE_DIAGNOSTICS), interfaces.ESTIMATE_DIAGNOSTICS
    )
    stop = threading.Event()
    failures: list[BaseException] = []

    def run() -> None:
        seq = 1
        try:
            while not stop.is_set():
                estimate = m.ForceEstimateMessage(
                    seq, time.time_ns(), seq, published_force(seq), (0.01, 0.02, 0.03),
                    (True, True, False), (1.0, 0.5, 0.0), (0.1, 0.2, 0.3), (0.1, 0.2, 0.3),
                )  # fmt: skip
                wrench, diag = codec.encode_estimate(
                    estimate, topics.OMNI_MODEL_JOINT_NAMES, topics.BASE_FRAME
                )
                sent = wrenches.publish(wrench)
                diagnostics.publish(diag)
                assert sent.sequence_number == seq
                seq += 1
                time.sleep(0.001)
        except BaseException as exc:  # reported by the test, not lost in the thread
            failures.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield endpoint
    finally:
        stop.set()
        thread.join(10.0)
        node.close()
        session.close()
    assert not failures, failures


def client_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}  # domain 0


def run_client(args: list[str], timeout_s: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout_s,
        check=False, env=client_env(),
    )  # fmt: skip


def assert_forces_published(rows: list[tuple[str, str, str, str]], out: str) -> None:
    assert rows, out
    for seq, fx, fy, fz in rows:
        assert (float(fx), float(fy), float(fz)) == published_force(int(seq)), out


def readme_block(marker: str) -> str:
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)
    matching = [b for b in blocks if marker in b]
    assert len(matching) == 1, f"expected one README python block with {marker!r}"
    return matching[0]


def test_examples_import_nothing_of_the_project() -> None:
    for path in (PLAIN, RCLPY):
        text = path.read_text()
        assert "teleop_force" not in text.replace("without teleop_force", ""), path
    for marker in ('"<3d"', "deserialize_message"):
        assert "teleop_force" not in readme_block(marker)


@pytest.mark.zenoh
@pytest.mark.parametrize("example", [PLAIN, RCLPY], ids=["zenoh+struct", "zenoh+rclpy"])
def test_example_client_prints_the_published_forces(example: Path) -> None:
    if example == RCLPY:
        pytest.importorskip("rclpy.serialization")
    with estimate_publisher() as endpoint:
        result = run_client([str(example), "--connect", endpoint, "--count", "300",
                             "--timeout", "90"])  # fmt: skip
    out = result.stdout
    assert result.returncode == 0, f"{out}\n{result.stderr}"
    assert "received 300 estimates" in out, out
    rows = ESTIMATE_LINE.findall(out)
    assert len(rows) == 3, out  # estimates 1, 101 and 201 of the client are printed
    assert_forces_published(rows, out)
    seqs = [int(row[0]) for row in rows]
    assert seqs[1] - seqs[0] >= 100 and seqs[2] - seqs[1] >= 100, out  # attachment seqs


@pytest.mark.zenoh
@pytest.mark.parametrize("example", [PLAIN, RCLPY], ids=["zenoh+struct", "zenoh+rclpy"])
def test_example_client_exits_1_without_estimates(example: Path) -> None:
    if example == RCLPY:
        pytest.importorskip("rclpy.serialization")
    endpoint = listen_endpoint(free_tcp_port())
    session = open_session(ZenohOptions(mode="peer", listen=(endpoint,), multicast_scouting=False))
    try:
        result = run_client([str(example), "--connect", endpoint, "--timeout", "1"])
    finally:
        session.close()
    assert result.returncode == 1, result.stdout + result.stderr
    assert "no estimate within 1 s" in result.stderr


@pytest.mark.zenoh
@pytest.mark.parametrize("marker", ['"<3d"', "deserialize_message"], ids=["struct", "rclpy"])
def test_readme_client_prints_the_published_forces(marker: str) -> None:
    if marker == "deserialize_message":
        pytest.importorskip("rclpy.serialization")
    code = readme_block(marker)
    assert "tcp/127.0.0.1:7447" in code and "time.sleep(10.0)" in code
    with estimate_publisher() as endpoint:
        code = code.replace("tcp/127.0.0.1:7447", endpoint).replace("10.0", "4.0")
        result = run_client(["-c", code])
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    rows = README_LINE.findall(result.stdout)
    assert len(rows) > 100, result.stdout[-2000:]
    assert_forces_published(rows, result.stdout[-2000:])


# --------------------------------------------------------------------------- the hand parse

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
stamps = st.tuples(st.integers(-(2**31), 2**31 - 1), st.integers(0, 2**32 - 1))
# a ROS 2 string is UTF-8: no NUL, no lone surrogate (which no UTF-8 encoder takes)
frame_ids = st.text(
    st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)), max_size=20
)


def same_floats(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return struct.pack(f"<{len(a)}d", *a) == struct.pack(f"<{len(b)}d", *b)


@settings(max_examples=300, deadline=None)
@given(stamp=stamps, frame_id=frame_ids, values=st.tuples(*[floats] * 6),
       little_endian=st.booleans())  # fmt: skip
def test_plain_parse_equals_rosbags(
    stamp: tuple[int, int], frame_id: str, values: tuple[float, ...], little_endian: bool
) -> None:
    store = interfaces.typestore()
    t = store.types
    vector = t["geometry_msgs/msg/Vector3"]
    message = t[interfaces.WRENCH_STAMPED](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=stamp[0], nanosec=stamp[1]),
            frame_id=frame_id,
        ),
        wrench=t["geometry_msgs/msg/Wrench"](force=vector(*values[:3]), torque=vector(*values[3:])),
    )
    payload = bytes(store.serialize_cdr(message, interfaces.WRENCH_STAMPED,
                                        little_endian=little_endian))  # fmt: skip
    expected = store.deserialize_cdr(payload, interfaces.WRENCH_STAMPED)
    parsed = PLAIN_CLIENT.decode_wrench_stamped(payload)
    assert parsed is not None
    assert (parsed.stamp_sec, parsed.stamp_nanosec) == (
        expected.header.stamp.sec,
        expected.header.stamp.nanosec,
    )
    assert parsed.frame_id == expected.header.frame_id == frame_id
    f, tq = expected.wrench.force, expected.wrench.torque
    assert same_floats(parsed.force_n, (f.x, f.y, f.z))
    assert same_floats(parsed.torque_nm, (tq.x, tq.y, tq.z))


@settings(max_examples=100, deadline=None)
@given(frame_id=frame_ids, values=st.tuples(*[floats] * 3))
def test_plain_parse_reads_rclpy_payloads(frame_id: str, values: tuple[float, ...]) -> None:
    serialization = pytest.importorskip("rclpy.serialization")
    geometry_msgs = pytest.importorskip("geometry_msgs.msg")
    ros = geometry_msgs.WrenchStamped()
    ros.header.frame_id = frame_id
    ros.header.stamp.sec, ros.header.stamp.nanosec = 1_764_158_400, 123_456_789
    ros.wrench.force.x, ros.wrench.force.y, ros.wrench.force.z = values
    parsed = PLAIN_CLIENT.decode_wrench_stamped(serialization.serialize_message(ros))
    assert parsed is not None
    assert parsed.frame_id == frame_id
    assert (parsed.stamp_sec, parsed.stamp_nanosec) == (1_764_158_400, 123_456_789)
    assert same_floats(parsed.force_n, values)


@pytest.mark.parametrize(
    "payload",
    [b"", b"\x00\x01\x00\x00", b"\x01\x01\x00\x00" + bytes(72), b"\x00\x01\x00\x00" + bytes(72)],
    ids=["empty", "header only", "bad encapsulation", "zero string length"],
)
def test_plain_parse_refuses_what_is_no_wrench(payload: bytes) -> None:
    assert PLAIN_CLIENT.decode_wrench_stamped(payload) is None


def test_plain_parse_refuses_a_truncated_wrench() -> None:
    wrench = codec.encode_wrench(1, (1.0, 2.0, 3.0), "base")
    assert PLAIN_CLIENT.decode_wrench_stamped(wrench) is not None
    assert PLAIN_CLIENT.decode_wrench_stamped(wrench[:-1]) is None


PLAIN_CLIENT = load_plain_client()
