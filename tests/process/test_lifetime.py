"""StopSignal: a signal always stops the process, however often and whenever it arrives."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from teleop_force.process.lifetime import StopSignal

_WAITER = textwrap.dedent(
    """
    import signal
    from teleop_force.process.lifetime import StopSignal
    stop = StopSignal().install()
    print("ready", flush=True)
    # Many short waits: each enters and leaves the event's lock, where a handler that took
    # that lock would deadlock.
    while not stop.wait(0.0):
        pass
    # The test goes on signalling: ignore what comes during the interpreter's shutdown.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    print(stop.signal_name, flush=True)
    """
)


def test_a_stop_set_from_another_thread_ends_a_wait() -> None:
    stop = StopSignal()
    threading.Timer(0.05, stop.set).start()
    start = time.monotonic()
    assert stop.wait(5.0) is True
    assert time.monotonic() - start < 2.0
    assert stop.is_set()


def test_a_wait_with_a_timeout_returns_false_when_nothing_is_asked() -> None:
    stop = StopSignal()
    start = time.monotonic()
    assert stop.wait(0.05) is False
    assert time.monotonic() - start >= 0.05
    assert not stop.is_set()


def test_a_signal_in_this_process_is_seen_by_wait() -> None:
    stop = StopSignal()
    stop._handle(signal.SIGTERM, None)  # what the installed handler does, without a signal
    assert stop.is_set()
    assert stop.wait(0.0) is True
    assert stop.signal_name == "SIGTERM"


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_burst_of_signals_during_waits_stops_the_process(signum: int) -> None:
    child = subprocess.Popen(
        [sys.executable, "-c", _WAITER], stdout=subprocess.PIPE, text=True, env=os.environ.copy()
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        for _ in range(2000):  # signals land at random points of the waits
            if child.poll() is not None:
                break
            child.send_signal(signum)
            time.sleep(1e-5)
        out, _ = child.communicate(timeout=10.0)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0
    assert out.strip() == signal.Signals(signum).name
