"""CPU of a direct-callback subscriber with and without a kept Python thread state.

A publisher process sends one 1 kHz topic on loopback; a subscriber process takes it with a
``Callback(indirect=False)`` (the service's, the slave's and the master's 1 kHz paths), once
as zenoh-python runs it (a Python thread state created and destroyed per sample) and once with
:func:`teleop_force.transport._thread_state.pin_thread_state` (one thread state kept), in
alternating rounds. The subscriber's CPU is read from ``/proc`` over ``--measure-s``::

    uv run python benchmarks/thread_state.py [--rounds 3] [--measure-s 8]

Prints one JSON line per run: whether the thread state is kept, samples, CPU in % of a core.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time

_KEY = "0/bench/thread_state"


def _cpu_s() -> float:
    times = os.times()
    return times.user + times.system


def publish(port: int, seconds: float) -> None:
    """Publish ``_KEY`` at 1 kHz for ``seconds`` (the child process)."""
    import zenoh

    from teleop_force.transport.session import ZenohOptions, open_session

    session = open_session(
        ZenohOptions(listen=(f"tcp/127.0.0.1:{port}",), multicast_scouting=False)
    )
    publisher = session.declare_publisher(_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    payload = bytes(160)
    start = next_s = time.monotonic()
    while time.monotonic() - start < seconds:
        next_s += 0.001
        publisher.put(payload)
        delay = next_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    session.close()


def subscribe(port: int, keep: bool, settle_s: float, measure_s: float) -> dict[str, object]:
    """Subscribe with a direct callback; return the samples and CPU over ``measure_s``."""
    import zenoh

    from teleop_force.transport._thread_state import pin_thread_state
    from teleop_force.transport.session import ZenohOptions, open_session

    session = open_session(
        ZenohOptions(connect=(f"tcp/127.0.0.1:{port}",), multicast_scouting=False)
    )
    count = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        if keep:
            pin_thread_state()
        sample.payload.to_bytes()
        count[0] += 1

    subscriber = session.declare_subscriber(
        _KEY, zenoh.handlers.Callback(on_sample, indirect=False)
    )
    time.sleep(settle_s)
    cpu0, n0 = _cpu_s(), count[0]
    time.sleep(measure_s)
    cpu1, n1 = _cpu_s(), count[0]
    subscriber.undeclare()
    session.close()
    return {"samples": n1 - n0, "cpu_percent": round(100.0 * (cpu1 - cpu0) / measure_s, 1)}


def main() -> None:
    """Run the rounds (or, as a child, publish or subscribe)."""
    if len(sys.argv) == 4 and sys.argv[1] == "--publish":
        publish(int(sys.argv[2]), float(sys.argv[3]))
        return
    if len(sys.argv) == 6 and sys.argv[1] == "--subscribe":
        figures = subscribe(
            int(sys.argv[2]), sys.argv[3] == "1", float(sys.argv[4]), float(sys.argv[5])
        )
        print(json.dumps(figures))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--settle-s", type=float, default=2.0)
    parser.add_argument("--measure-s", type=float, default=8.0)
    args = parser.parse_args()
    for round_index in range(args.rounds):
        for keep in (False, True):
            with socket.socket() as probe:
                probe.bind(("127.0.0.1", 0))
                port = int(probe.getsockname()[1])
            seconds = args.settle_s + args.measure_s + 3.0
            publisher = subprocess.Popen(
                [sys.executable, __file__, "--publish", str(port), str(seconds)]
            )
            time.sleep(1.0)
            done = subprocess.run(
                [sys.executable, __file__, "--subscribe", str(port), str(int(keep)),
                 str(args.settle_s), str(args.measure_s)],
                capture_output=True, text=True, check=True,
            )  # fmt: skip
            publisher.wait()
            figures = json.loads(done.stdout.strip().splitlines()[-1])
            print(
                json.dumps({"round": round_index, "thread_state_kept": keep, **figures}), flush=True
            )


if __name__ == "__main__":
    main()
