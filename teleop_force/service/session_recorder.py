"""The session recorder as a process of its own: every message on the wire, to an MCAP session.

    python -m teleop_force.service.session_recorder --record PATH --device slave --connect ...

Recording is not on the 1 kHz path, so it need not share a process with it: converting,
compressing and writing thousands of messages a second in the force service's process
competes with the estimator for the interpreter lock and adds milliseconds to the estimates'
latency. This process subscribes to every device's joint states, setpoints, true and
estimated contact forces and status (the keys :mod:`teleop_force.service.force_service`
records with ``--record``, plus the estimates it publishes) and writes them with the same
:class:`~teleop_force.service.recorder.BackgroundRecorder`: CDR channels, batches,
crash-safe chunks, malformed payloads counted and dropped. ``teleop-force demo`` records
with it.

It answers ``omni/<device>/stats/recorder`` (JSON: the recorder's counters, the malformed
messages by key) and holds the token ``omni/<device>/alive/recorder``; it stops on SIGINT /
SIGTERM or ``--duration`` and closes the file (what was queued is written first).
"""

from __future__ import annotations

import argparse
import gc
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, TeleopForceError
from teleop_force.io.mcap_session import DEFAULT_FLUSH_INTERVAL_S, SessionWriter
from teleop_force.process.lifetime import StopSignal, log, write_json
from teleop_force.service.controls import create_exclusively
from teleop_force.service.counters import MalformedCounter
from teleop_force.service.recorder import BackgroundRecorder
from teleop_force.transport import keys
from teleop_force.transport.pubsub import (
    declare_json_queryable,
    declare_subscriber,
    declare_token,
    undeclare_all,
)
from teleop_force.transport.session import open_session, options_from_args

ROLE: Final = "recorder"
#: The kinds recorded, for every device.
RECORDED_KINDS: Final = (
    keys.MEASURED_JS, keys.SETPOINT_JS, keys.MEASURED_CF, keys.ESTIMATED_CF, keys.STATUS,
)  # fmt: skip


class SessionRecorder:
    """Zenoh subscriptions feeding a :class:`BackgroundRecorder` (module docstring)."""

    def __init__(self, session: zenoh.Session, writer: SessionWriter, device: str) -> None:
        """Prepare the recorder on ``writer``; nothing is subscribed until :meth:`start`."""
        self.session = session
        self.device = keys.validate_chunk(device)
        self.malformed = MalformedCounter()
        self._lock = threading.Lock()
        self.recorder = BackgroundRecorder(writer, self._count_malformed)
        self._entities: list[Any] = []
        self.received = 0

    def _count_malformed(self, key: str, exc: Exception) -> None:
        with self._lock:
            self.malformed.count(key, exc)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        """Hand one sample to the recorder's thread (decoded and checked there)."""
        arrival_ns = time.time_ns()
        self.received += 1
        self.recorder.submit(str(sample.key_expr), sample.payload.to_bytes(), arrival_ns)

    def start(self) -> SessionRecorder:
        """Subscribe to the recorded keys, answer statistics, declare the token; return self."""
        for kind in RECORDED_KINDS:
            self._entities.append(
                declare_subscriber(
                    self.session, keys.any_device(kind), self._on_sample, direct=True
                )
            )
        self._entities.append(
            declare_json_queryable(self.session, keys.process_stats(self.device, ROLE), self.stats)
        )
        self._entities.append(declare_token(self.session, keys.alive(self.device, ROLE)))
        return self

    def close(self) -> None:
        """Unsubscribe, then write what is queued and close the file."""
        entities, self._entities = self._entities, []
        undeclare_all(*reversed(entities))
        self.recorder.close()

    def stats(self) -> dict[str, Any]:
        """JSON statistics: samples received, the recorder's counters, malformed by key."""
        with self._lock:
            malformed = self.malformed.to_dict()
        return {
            "role": ROLE,
            "device": self.device,
            "received": self.received,
            "recorder": self.recorder.stats(),
            "malformed": malformed,
        }


def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``python -m teleop_force.service.session_recorder``."""
    from teleop_force.transport.session import add_zenoh_arguments

    parser = argparse.ArgumentParser(
        prog="python -m teleop_force.service.session_recorder",
        description=__doc__.splitlines()[0],
    )
    parser.add_argument("--record", type=Path, required=True, metavar="PATH", help="MCAP file")
    parser.add_argument("--device", default="slave", help="primary device (default slave)")
    parser.add_argument("--master", default=None, help="master device id (metadata)")
    parser.add_argument("--model", default="", help="model the service runs (metadata)")
    parser.add_argument(
        "--record-flush-s", type=float, default=DEFAULT_FLUSH_INTERVAL_S, metavar="S",
        help=f"hand chunks to the OS at least every S s (default {DEFAULT_FLUSH_INTERVAL_S:g})",
    )  # fmt: skip
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S s")
    parser.add_argument(
        "--stats-json", default=None, metavar="PATH", help="final stats (- = stdout)"
    )
    add_zenoh_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Record until SIGINT / SIGTERM or ``--duration``; return the exit status."""
    args = build_parser().parse_args(argv)
    stop = StopSignal().install().watch_supervisor()
    try:
        if args.duration is not None and not args.duration > 0:
            raise ConfigurationError(f"--duration must be > 0, got {args.duration}")
        path: Path = args.record
        path.parent.mkdir(parents=True, exist_ok=True)
        create_exclusively(path)
        metadata = {
            "primary_device": keys.validate_chunk(args.device),
            "source": "live",
            "model": args.model,
            "recorder": "teleop_force.service.session_recorder",
        }
        if args.master is not None:
            metadata["master_device"] = keys.validate_chunk(args.master, "master device id")
        writer = SessionWriter(path, metadata, flush_interval_s=args.record_flush_s)
        session = open_session(options_from_args(args))
    except (TeleopForceError, OSError) as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        recorder = SessionRecorder(session, writer, args.device).start()
        gc.collect()
        gc.freeze()
        log(ROLE, f"recording to {path}")
        try:
            stop.wait(args.duration)
        finally:
            recorder.close()
        stats = recorder.stats()
    finally:
        session.close()
    if args.stats_json:
        write_json(args.stats_json, stats)
    written = stats["recorder"].get("written")
    log(ROLE, f"stopped: {written} messages written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
