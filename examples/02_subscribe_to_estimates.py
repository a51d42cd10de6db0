"""Subscribe to the force estimates over Zenoh and decode their CDR bytes, without teleop_force.

The estimates are ROS 2 ``geometry_msgs/msg/WrenchStamped`` messages on rmw_zenoh's key
``<domain>/<device>/estimated_cf/geometry_msgs::msg::dds_::WrenchStamped_/<type hash>``, with
rmw_zenoh's 33-byte attachment (sequence number, source time, publisher GID): see
docs/wire_format.md. This client imports only ``zenoh`` and ``struct``, so a client in any
language does the same with a Zenoh binding.

Start something that publishes estimates, with a known endpoint, then this client::

    uv run teleop-force demo --headless --zenoh-port 7447
    uv run python examples/02_subscribe_to_estimates.py --connect tcp/127.0.0.1:7447

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
from typing import NamedTuple

import zenoh

ATTACHMENT = struct.Struct("<qqB16s")  # sequence number, source time [ns], 16, GID: 33 bytes


class Wrench(NamedTuple):
    """A decoded WrenchStamped: header stamp, frame, force [N] and torque [N m]."""

    stamp_sec: int
    stamp_nanosec: int
    frame_id: str
    force_n: tuple[float, float, float]  # NaN: no estimate (Jacobian near singular)
    torque_nm: tuple[float, float, float]


def decode_wrench_stamped(payload: bytes) -> Wrench | None:
    """Decode a CDR ``geometry_msgs/msg/WrenchStamped``, or return None if it is not one.

    CDR: a 4-byte encapsulation header (``00 01``: little endian, ``00 00``: big endian, then
    two option bytes), then the fields, each aligned to its own size counted from byte 4:
    ``int32 sec``, ``uint32 nanosec``, the frame_id as a ``uint32`` length that counts the
    NUL, its bytes and the NUL, padding to 8, then six ``float64`` (force x y z, torque x y z).
    Bytes after the last field are ignored (some serializers leave slack there).
    """
    if len(payload) < 16 or payload[0] != 0 or payload[1] not in (0, 1):
        return None
    order = "<" if payload[1] == 1 else ">"
    sec, nanosec, length = struct.unpack_from(order + "iII", payload, 4)
    text_end = 16 + length
    values_at = 4 + (text_end - 4 + 7) // 8 * 8  # the doubles start 8-aligned (from byte 4)
    if length == 0 or values_at + 48 > len(payload) or payload[text_end - 1] != 0:
        return None
    try:
        frame_id = payload[16 : text_end - 1].decode("utf-8")
    except UnicodeDecodeError:
        return None
    values = struct.unpack_from(order + "6d", payload, values_at)
    return Wrench(sec, nanosec, frame_id, values[:3], values[3:])


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
    # `*` in the hash chunk: any type hash (Humble's rmw_zenoh puts TypeHashNotSupported there)
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
            wrench = decode_wrench_stamped(payload)
            if wrench is None or extra is None or len(extra) != ATTACHMENT.size:
                continue  # not a WrenchStamped with rmw_zenoh's attachment: drop it
            seq, source_ns, gid_length, _gid = ATTACHMENT.unpack(extra)
            if gid_length != 16:
                continue
            received += 1
            if received % 100 == 1:
                fx, fy, fz = wrench.force_n
                text = "none" if math.isnan(fx) else f"({fx:+.3f}, {fy:+.3f}, {fz:+.3f}) N"
                latency_ms = (arrived_ns - source_ns) / 1e6
                print(f"estimate {seq}: F = {text}, latency {latency_ms:.2f} ms", flush=True)
        print(f"received {received} estimates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
