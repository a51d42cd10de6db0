"""Subscribe to the force estimates over Zenoh and decode them with rclpy, without teleop_force.

The same client as ``02_subscribe_to_estimates.py``, but ROS 2's own deserializer
(``rclpy.serialization.deserialize_message``) decodes the ``geometry_msgs/msg/WrenchStamped``
payloads: no ROS graph, no rmw_zenoh and no ROS installation are needed, only the wheels
(``pip install eclipse-zenoh ros-rclpy ros-rmw-fastrtps-cpp ros-geometry-msgs``; they are in
this project's dev dependencies). The 33-byte rmw_zenoh attachment (sequence number, source
time, publisher GID) is read with ``struct``: docs/wire_format.md.

    uv run teleop-force demo --headless --zenoh-port 7447
    uv run python examples/04_subscribe_with_rclpy.py --connect tcp/127.0.0.1:7447

It prints every 100th estimate (its sequence number, force and latency) and stops after
``--count`` estimates (exit 0), or exits 1 if none arrives within ``--timeout`` seconds. The
latency is this host's clock minus the publisher's: across hosts it means something only with
synchronised clocks (chrony, PTP).
"""

from __future__ import annotations

import argparse
import math
import os
import queue
import struct
import sys
import time

import zenoh
from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import deserialize_message

ATTACHMENT = struct.Struct("<qqB16s")  # sequence number, source time [ns], 16, GID: 33 bytes


def main() -> int:
    """Subscribe, print, stop after ``--count`` estimates."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", default="tcp/127.0.0.1:7447", help="Zenoh endpoint")
    parser.add_argument("--device", default="slave", help="device id of the slave")
    parser.add_argument("--count", type=int, default=1000, help="stop after N estimates")
    parser.add_argument("--timeout", type=float, default=30.0, help="give up after S s of silence")
    args = parser.parse_args()

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", f'["{args.connect}"]')
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')  # loopback only
    config.insert_json5("scouting/multicast/enabled", "false")

    domain = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    key = f"{domain}/{args.device}/estimated_cf/geometry_msgs::msg::dds_::WrenchStamped_/*"
    inbox: queue.Queue[tuple[bytes, bytes | None, int]] = queue.Queue()

    def on_sample(sample: zenoh.Sample) -> None:
        extra = None if sample.attachment is None else sample.attachment.to_bytes()
        inbox.put((sample.payload.to_bytes(), extra, time.time_ns()))

    with zenoh.open(config) as session:
        session.declare_subscriber(key, on_sample)
        print(f"listening on {key} via {args.connect}", flush=True)
        received = 0
        while received < args.count:
            try:
                payload, extra, arrived_ns = inbox.get(timeout=args.timeout)
            except queue.Empty:
                print(f"no estimate within {args.timeout:g} s", file=sys.stderr)
                return 1
            if extra is None or len(extra) != ATTACHMENT.size:
                continue  # no rmw_zenoh attachment: drop it
            seq, source_ns, gid_length, _gid = ATTACHMENT.unpack(extra)
            try:
                wrench = deserialize_message(payload, WrenchStamped)
            except RuntimeError:  # rclpy's RMWError: not a WrenchStamped, drop it
                continue
            if gid_length != 16:
                continue
            received += 1
            if received % 100 == 1:
                f = wrench.wrench.force
                text = "none" if math.isnan(f.x) else f"({f.x:+.3f}, {f.y:+.3f}, {f.z:+.3f}) N"
                latency_ms = (arrived_ns - source_ns) / 1e6
                print(f"estimate {seq}: F = {text}, latency {latency_ms:.2f} ms", flush=True)
        print(f"received {received} estimates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
