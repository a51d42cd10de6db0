"""Subscribe to the force estimates over Zenoh and decode their bytes, without teleop_force.

A client in any language does the same: open a Zenoh session, subscribe to
``omni/<device>/estimated_cf`` and unpack the little-endian layout of docs/wire_format.md.
This one imports only ``zenoh`` and ``struct``.

Start something that publishes estimates, with a known endpoint, then this client::

    uv run teleop-force demo --headless --zenoh-port 7447
    uv run teleop-force replay recordings/palpation_demo.mcap --with-service \
        --listen tcp/127.0.0.1:7447                      # (either one)

    uv run python examples/02_subscribe_to_estimates.py --connect tcp/127.0.0.1:7447

It prints every 100th estimate and stops after ``--count`` estimates (exit 0), or exits 1 if
none arrives within ``--timeout`` seconds.
"""

from __future__ import annotations

import argparse
import math
import queue
import struct
import sys
from typing import NamedTuple

import zenoh

HEADER = struct.Struct("<2sBBIq")  # magic "TF", version, type, seq, t_ns: 16 bytes
FORCE_ESTIMATE = 4


class Estimate(NamedTuple):
    """The fields of a ForceEstimate this client uses."""

    seq: int
    t_ns: int
    source_seq: int
    force_n: tuple[float, float, float]  # NaN: no estimate (Jacobian near singular)
    tau_ext_nm: tuple[float, ...]
    coverage_weight: tuple[float, ...]
    on_trained_ground: tuple[bool, ...]


def decode_force_estimate(payload: bytes) -> Estimate | None:
    """Decode a ForceEstimate v1, or return None if the bytes are anything else."""
    if len(payload) < 21:
        return None
    magic, version, kind, seq, t_ns = HEADER.unpack_from(payload, 0)
    if magic != b"TF" or version != 1 or kind != FORCE_ESTIMATE:
        return None
    source_seq, n = struct.unpack_from("<IB", payload, 16)
    mask_bytes = (n + 7) // 8
    if n == 0 or len(payload) != 45 + 32 * n + mask_bytes:
        return None
    force_n = struct.unpack_from("<3d", payload, 21)
    tau_ext_nm = struct.unpack_from(f"<{n}d", payload, 45)
    coverage = struct.unpack_from(f"<{n}d", payload, 45 + 8 * n)
    mask = int.from_bytes(payload[45 + 32 * n :], "little")
    on_ground = tuple(bool(mask >> j & 1) for j in range(n))
    return Estimate(seq, t_ns, source_seq, force_n, tau_ext_nm, coverage, on_ground)


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

    inbox: queue.Queue[bytes] = queue.Queue()
    key = f"omni/{args.device}/estimated_cf"
    with zenoh.open(config) as session:
        session.declare_subscriber(key, lambda sample: inbox.put(sample.payload.to_bytes()))
        print(f"listening on {key} via {args.connect}", flush=True)
        received = 0
        while received < args.count:
            try:
                estimate = decode_force_estimate(inbox.get(timeout=args.timeout))
            except queue.Empty:
                print(f"no estimate within {args.timeout:g} s", file=sys.stderr)
                return 1
            if estimate is None:
                continue  # not a ForceEstimate v1: drop it, as the project's receivers do
            received += 1
            if received % 100 == 1:
                fx, fy, fz = estimate.force_n
                ground = "on" if all(estimate.on_trained_ground) else "off"
                text = "none" if math.isnan(fx) else f"({fx:+.3f}, {fy:+.3f}, {fz:+.3f}) N"
                print(f"estimate {estimate.seq}: F = {text}, {ground} trained ground", flush=True)
        print(f"received {received} estimates")
    return 0


if __name__ == "__main__":
    sys.exit(main())
