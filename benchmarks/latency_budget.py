"""The latency budget of a joint state's way to its force estimate.

    uv run python benchmarks/latency_budget.py [--duration 30] [--zenoh-port P]

Runs ``teleop-force demo --headless`` (a Zenoh router on loopback, the processes its peers,
linked to each other directly) and splits the slave -> estimate latency into its parts:

* network: the joint state from the slave to the service, waiting for the receive thread
  included (the service's latency minus its processing);
* decode, estimate, publish: the service's processing of one joint state, split by timing the
  CDR decode of a ``sensor_msgs/msg/JointState`` (:func:`teleop_force.ros2.codec.
  decode_joint_state`), the compiled estimator step, and the estimate's two CDR messages
  encoded and put with their attachments by the service's ROS 2 node, in this process, on the
  same model (median of 20,000 calls each).

The master -> slave latency (setpoint stamp to the slave's receipt) is the other network hop.
Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _median_us(fn, n: int = 20_000) -> float:
    samples = np.empty(n)
    clock = time.perf_counter_ns
    for k in range(n):
        start = clock()
        fn(k)
        samples[k] = clock() - start
    return float(np.median(samples)) / 1e3


def processing_split_us() -> dict[str, float]:
    """Median cost of decode, estimate and publish of one joint state [µs], in this process."""
    from teleop_force.bench.data import palpation_arrays
    from teleop_force.estimation.estimator import ForceEstimator
    from teleop_force.identification.dynamic_model import DynamicModel
    from teleop_force.models import DEFAULT_MODEL_PATH
    from teleop_force.ros2 import codec, topics
    from teleop_force.service.ros2_edge import Ros2Edge
    from teleop_force.transport import messages as m
    from teleop_force.transport.session import (
        ZenohOptions,
        free_tcp_port,
        listen_endpoint,
        open_session,
    )

    arrays = palpation_arrays(5.0)
    q, tau = arrays["q_rad"].tolist(), arrays["tau_nm"].tolist()
    rows = len(q)
    names = topics.OMNI_MODEL_JOINT_NAMES
    payloads = [
        codec.encode_joint_state(m.JointState(k, k, q[k], (0.0,) * 3, tau[k]), names)
        for k in range(rows)
    ]
    estimator = ForceEstimator(DynamicModel.load(DEFAULT_MODEL_PATH))
    decode = _median_us(lambda k: codec.decode_joint_state(payloads[k % rows], k))

    def step(k: int) -> None:
        if k % rows == 0:
            estimator.reset()
        estimator.step((k % rows) * 1e-3, q[k % rows], tau[k % rows])

    estimate = _median_us(step)
    v = (0.1, 0.1, 0.1)
    endpoint = listen_endpoint(free_tcp_port())
    session = open_session(ZenohOptions(listen=(endpoint,), multicast_scouting=False))
    listener = open_session(ZenohOptions(connect=(endpoint,), multicast_scouting=False))
    edge = Ros2Edge(session, "bench", 3, lambda *_: None, lambda *_: None)
    subscriber = listener.declare_subscriber(edge.estimates.key, lambda sample: None)
    time.sleep(0.5)
    try:
        publish = _median_us(
            lambda k: edge.publish_estimate(k, k, v, v, v, (True, True, False), v, v)
        )
    finally:
        subscriber.undeclare()
        edge.close()
        listener.close()
        session.close()
    return {"decode": decode, "estimate": estimate, "publish": publish}


def run_demo(duration_s: float, zenoh_port: int | None) -> dict:
    """Run the headless demo; return its summary."""
    with tempfile.TemporaryDirectory(prefix="teleop-latency-") as tmp:
        summary = Path(tmp) / "summary.json"
        argv = [
            sys.executable, "-m", "teleop_force.cli.main", "demo", "--headless",
            "--duration", f"{duration_s:g}", "--record-dir", tmp, "--summary-json", str(summary),
        ]  # fmt: skip
        if zenoh_port is not None:
            argv += ["--zenoh-port", str(zenoh_port)]
        subprocess.run(argv, check=True, capture_output=True)
        return json.loads(summary.read_text())


def main() -> int:
    """Run the demo, time the parts, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, help="demo seconds (default 30)")
    parser.add_argument("--zenoh-port", type=int, default=None, help="the demo's router port")
    args = parser.parse_args()
    summary = run_demo(args.duration, args.zenoh_port)
    split = processing_split_us()
    service = summary["stats"]["service"]
    latency = summary["slave_to_estimate_latency_ms"]
    processing = service["processing_ms"]
    setpoint = summary["master_to_slave_latency_ms"]
    topology = "a router on loopback, the processes its peers"
    print(f"demo {args.duration:g} s, {topology}; load average {summary['machine_load_average']}")
    print("| part | p50 | p99 |")
    print("|---|---:|---:|")
    print(f"| master -> slave (network) | {setpoint['p50']:.3f} ms | {setpoint['p99']:.3f} ms |")
    network = [latency[p] - processing[p] for p in ("p50", "p99")]
    print(f"| slave -> service (network, queueing) | {network[0]:.3f} ms | {network[1]:.3f} ms |")
    for part in ("decode", "estimate", "publish"):
        print(f"| service: {part} (median, in-process) | {split[part]:.1f} µs | |")
    print(f"| service: processing (all of it) | {processing['p50']:.3f} ms "
          f"| {processing['p99']:.3f} ms |")  # fmt: skip
    print(f"| slave -> estimate published | {latency['p50']:.3f} ms | {latency['p99']:.3f} ms |")
    print(f"CPU % of one core: {summary['cpu_percent']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
