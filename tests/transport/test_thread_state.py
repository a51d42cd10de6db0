"""The Zenoh thread that runs direct callbacks keeps one Python thread state (real sessions)."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from teleop_force.transport._thread_state import pin_thread_state, pinned_threads
from teleop_force.transport.pubsub import declare_subscriber, wait_for_subscribers
from teleop_force.transport.session import ZenohOptions, open_session

SAMPLES = 50


def _deliver(direct: bool) -> list[tuple[int, int]]:
    """Publish SAMPLES samples to a subscriber; return (thread id, calls seen) per sample.

    The count lives on a ``threading.local``, whose values belong to the thread state: it
    keeps counting only while the thread state survives from one sample to the next.
    """
    local = threading.local()
    seen: list[tuple[int, int]] = []

    def on_sample(sample: object) -> None:
        local.calls = getattr(local, "calls", 0) + 1
        seen.append((threading.get_ident(), local.calls))

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{probe.getsockname()[1]}"
    # Two sessions: a session's own publications are delivered on the publishing thread.
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    sender = open_session(ZenohOptions(connect=(endpoint,), multicast_scouting=False))
    try:
        subscriber = declare_subscriber(session, "0/thread_state/test", on_sample, direct=direct)
        publisher = sender.declare_publisher("0/thread_state/test")
        wait_for_subscribers(publisher, 5.0)
        for _ in range(SAMPLES):
            publisher.put(b"x")
            time.sleep(0.002)
        deadline = time.monotonic() + 5.0
        while len(seen) < SAMPLES and time.monotonic() < deadline:
            time.sleep(0.01)
        subscriber.undeclare()
        publisher.undeclare()
    finally:
        sender.close()
        session.close()
    assert all(ident != threading.get_ident() for ident, _ in seen)  # not the main thread
    return seen


@pytest.mark.parametrize("direct", [True, False])
def test_a_callback_thread_keeps_its_thread_state(direct: bool) -> None:
    seen = _deliver(direct)
    assert len(seen) == SAMPLES
    by_thread: dict[int, list[int]] = {}
    for ident, calls in seen:
        by_thread.setdefault(ident, []).append(calls)
    for calls in by_thread.values():
        assert calls == list(range(1, len(calls) + 1))  # never reset to 1
    if direct:
        assert pinned_threads() >= 1


def test_pinning_is_idempotent_on_a_python_thread() -> None:
    counts: list[int] = []

    def pin_twice() -> None:
        pin_thread_state()
        counts.append(pinned_threads())
        pin_thread_state()
        counts.append(pinned_threads())

    thread = threading.Thread(target=pin_twice)
    thread.start()
    thread.join()
    assert counts[0] == counts[1] >= 1


def test_a_process_with_pinned_zenoh_threads_exits_cleanly() -> None:
    code = (
        f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r});"
        "from test_thread_state import _deliver;"
        "from teleop_force.transport._thread_state import pinned_threads;"
        "assert len(_deliver(True)) == 50 and pinned_threads() >= 1; print('ok')"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"
