"""CPU of a session recorder under different Zenoh thread layouts (``ZENOH_RUNTIME``).

A publisher process sends six 1 kHz topics (rmw_zenoh keys, 33-byte attachments, 160-byte
payloads, as in the demo) on loopback; a session recorder
(``python -m teleop_force.service.session_recorder``) records them, once per layout, in
alternating rounds. Each run's CPU is read from ``/proc`` per thread over ``--measure-s``
after a settling time; the publisher always runs the project's default layout::

    uv run python benchmarks/zenoh_threads.py [--rounds 2] [--measure-s 8] [--batching]
                                              [--topics-per-tick 1,3,6]

Prints one JSON line per run: the layout, the recorder's CPU in % of one core, by thread name.
``--batching`` instead compares, under the project's layout, a publisher whose six messages
of a tick are all express with one whose tick's last message alone is express (the
project's publishers: the others wait in Zenoh's batch and leave with it).
``--topics-per-tick`` instead varies the topics of a tick (one batch a tick, the last
express): what a receiver pays per batch and per sample.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LAYOUTS = {
    "zenoh default": None,
    "one receive thread": "(rx: (worker_threads: 1))",
    "project default": "(rx: (worker_threads: 1), net: (handover: rx), acc: (handover: rx), "
    "app: (handover: rx))",
}
_TOPICS = 6
_HZ = 1000.0


def publish(port: int, seconds: float, batched: bool = False, n_topics: int = _TOPICS) -> None:
    """Publish ``n_topics`` topics at ``_HZ`` for ``seconds`` (run in a child process).

    ``batched``: only each tick's last message is express.
    """
    from teleop_force.transport.session import ZenohOptions, open_session

    session = open_session(
        ZenohOptions(listen=(f"tcp/127.0.0.1:{port}",), multicast_scouting=False)
    )
    import zenoh

    publishers = [
        session.declare_publisher(
            f"0/bench/topic{i}/sensor_msgs::msg::dds_::JointState_/RIHS01_{'0' * 64}",
            congestion_control=zenoh.CongestionControl.BLOCK,
            express=not batched or i == n_topics - 1,
        )
        for i in range(n_topics)
    ]
    time.sleep(2.0)
    payload = bytes(160)
    start = next_s = time.monotonic()
    sequence = 0
    while time.monotonic() - start < seconds:
        next_s += 1.0 / _HZ
        sequence += 1
        attachment = struct.pack("<qqB16s", sequence, time.time_ns(), 16, b"g" * 16)
        for publisher in publishers:
            publisher.put(payload, attachment=attachment)
        delay = next_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    session.close()


def _thread_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) of each thread of ``pid``, summed by thread name."""
    tick = os.sysconf("SC_CLK_TCK")
    by_name: dict[str, float] = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        by_name[name] = by_name.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return by_name


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def run(
    layout: str | None,
    settle_s: float,
    measure_s: float,
    batched: bool = False,
    n_topics: int = _TOPICS,
) -> dict[str, object]:
    """One publisher and one recorder; return the recorder's CPU over ``measure_s``."""
    port = _free_port()
    total_s = settle_s + measure_s + 3.0
    env = dict(os.environ)
    env.pop("ZENOH_RUNTIME", None)
    publisher_argv = [sys.executable, __file__, "--publish", str(port), str(total_s + 2.0)]
    publisher_argv += [str(int(batched)), str(n_topics)]
    publisher = subprocess.Popen(
        publisher_argv,
        env=env,
    )
    recorder_env = dict(env)
    if layout is not None:
        recorder_env["ZENOH_RUNTIME"] = layout
    else:
        # Zenoh's own default: a value the project's open_session will not override.
        recorder_env["ZENOH_RUNTIME"] = "()"
    with tempfile.TemporaryDirectory() as tmp:
        time.sleep(1.0)
        argv = [
            sys.executable, "-m", "teleop_force.service.session_recorder",
            "--record", str(Path(tmp) / "bench.mcap"), "--duration", str(total_s),
            "--connect", f"tcp/127.0.0.1:{port}", "--no-multicast",
        ]  # fmt: skip
        recorder = subprocess.Popen(
            argv,
            env=recorder_env,
            stderr=subprocess.DEVNULL,
        )
        time.sleep(settle_s)
        before = _thread_cpu_s(recorder.pid)
        time.sleep(measure_s)
        after = _thread_cpu_s(recorder.pid)
        recorder.wait()
        publisher.wait()
    by_thread = {
        name: round(100.0 * (after[name] - before.get(name, 0.0)) / measure_s, 1)
        for name in after
        if after[name] - before.get(name, 0.0) > 0
    }
    return {"recorder_cpu_percent": round(sum(by_thread.values()), 1), "by_thread": by_thread}


def main() -> None:
    """Run the rounds (or, as the child, publish)."""
    if len(sys.argv) == 6 and sys.argv[1] == "--publish":
        publish(int(sys.argv[2]), float(sys.argv[3]), sys.argv[4] == "1", int(sys.argv[5]))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--settle-s", type=float, default=4.0)
    parser.add_argument("--measure-s", type=float, default=8.0)
    parser.add_argument("--batching", action="store_true", help="express per message vs tick")
    parser.add_argument(
        "--topics-per-tick", default=None, metavar="N[,N]", help="one batch a tick of N topics"
    )
    args = parser.parse_args()
    if args.topics_per_tick:
        counts = [int(n) for n in args.topics_per_tick.split(",")]
        for round_index in range(args.rounds):
            for n_topics in counts:
                figures = run(
                    LAYOUTS["project default"], args.settle_s, args.measure_s, True, n_topics
                )
                print(json.dumps({"round": round_index, "topics_per_tick": n_topics, **figures}))
        return
    if args.batching:
        for round_index in range(args.rounds):
            for batched in (False, True):
                figures = run(LAYOUTS["project default"], args.settle_s, args.measure_s, batched)
                express = "the tick's last" if batched else "every message"
                print(json.dumps({"round": round_index, "express": express, **figures}), flush=True)
        return
    for round_index in range(args.rounds):
        for name, layout in LAYOUTS.items():
            figures = run(layout, args.settle_s, args.measure_s)
            print(json.dumps({"round": round_index, "layout": name, **figures}), flush=True)


if __name__ == "__main__":
    main()
