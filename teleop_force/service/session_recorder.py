"""The session recorder as a process of its own: every ROS 2 message of the domain, to MCAP.

    python -m teleop_force.service.session_recorder --record PATH --device slave --connect ...

Recording is not on the 1 kHz path, so it need not share a process with it: writing thousands
of messages a second in the force service's process competes with the estimator for the
interpreter lock and adds to the estimates' latency. This process records every ROS 2 message
of its domain (``<ROS_DOMAIN_ID>/**``: joint states, setpoints, true and estimated forces,
estimate diagnostics, statuses, the service's diagnostics) as it was received, with
:class:`~teleop_force.service.ros2_recorder.Ros2Recorder` (the estimation service's own
recording runs the same): the CDR bytes untouched on channels named by the ROS topics, the
MCAP sequence and publish time from rmw_zenoh's attachment, the MCAP profile ``ros2``, so
Foxglove's panels and rosbag2 read the session as a ROS 2 bag. A sample whose key is not a
topic key or that has no valid attachment is counted as malformed and dropped.
``teleop-force demo`` records with it.

With ``--monitor`` it also keeps the demo's live figures of ``--device``'s estimates (loss,
accuracy during contact, first estimate, the slave's state:
:class:`~teleop_force.service.session_monitor.SessionMonitor`) from the samples it records, so
the demo's supervisor need not receive the 1 kHz streams a second time.

It answers ``omni/<device>/stats/recorder`` (JSON: the recorder's counters, the malformed
messages by key, ``monitor``: the figures or ``None``; what has arrived is drained first) and
holds the token ``omni/<device>/alive/recorder``; it stops on SIGINT /
SIGTERM or ``--duration`` and closes the file (what arrived is written first).
"""

from __future__ import annotations

import argparse
import gc
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, TeleopForceError
from teleop_force.io.mcap_session import DEFAULT_FLUSH_INTERVAL_S, SessionWriter
from teleop_force.process.lifetime import StopSignal, log, write_json
from teleop_force.service.accuracy import AccuracyConfig
from teleop_force.service.controls import create_exclusively
from teleop_force.service.counters import MalformedCounter
from teleop_force.service.ros2_recorder import PROFILE, Ros2Recorder
from teleop_force.service.session_monitor import SessionMonitor
from teleop_force.transport import keys
from teleop_force.transport.pubsub import declare_json_queryable, declare_token, undeclare_all
from teleop_force.transport.session import open_session, options_from_args

ROLE: Final = "recorder"


class SessionRecorder:
    """A :class:`Ros2Recorder` with the process's statistics queryable and token.

    ``monitor``: also feed it the samples of its device's topics (module docstring).
    """

    def __init__(
        self,
        session: zenoh.Session,
        writer: SessionWriter,
        device: str,
        *,
        domain_id: int | None = None,
        monitor: SessionMonitor | None = None,
    ) -> None:
        """Prepare the recorder on ``writer``; nothing is subscribed until :meth:`start`."""
        self.session = session
        self.writer = writer
        self.device = keys.validate_chunk(device)
        self.malformed = MalformedCounter()
        self.monitor = monitor
        self._lock = threading.Lock()
        self._monitor_lock = threading.Lock()
        self.recorder = Ros2Recorder(
            session,
            writer,
            self._count_malformed,
            domain_id=domain_id,
            observer=None if monitor is None else self._observe,
        )
        self._entities: list[Any] = []

    def _observe(self, topic: str, payloads: list[bytes], attachments: list[bytes]) -> None:
        if self.monitor is not None:
            with self._monitor_lock:
                self.monitor.take_topic(topic, payloads, attachments)

    def _count_malformed(self, key: str, exc: Exception) -> None:
        with self._lock:
            self.malformed.count(key, exc)

    @property
    def received(self) -> int:
        """Samples taken from the subscription so far."""
        return self.recorder.received

    def drain(self) -> int:
        """Write every sample waiting; return how many were taken."""
        return self.recorder.drain()

    def start(self) -> SessionRecorder:
        """Subscribe, answer statistics, declare the token; return self."""
        self.recorder.start()
        self._entities.append(
            declare_json_queryable(self.session, keys.process_stats(self.device, ROLE), self.stats)
        )
        self._entities.append(declare_token(self.session, keys.alive(self.device, ROLE)))
        return self

    def close(self) -> None:
        """Write what arrived and close the file, then undeclare the queryable and token."""
        self.recorder.close()
        entities, self._entities = self._entities, []
        undeclare_all(*reversed(entities))

    def stats(self) -> dict[str, Any]:
        """JSON statistics: received, the recorder's counters, malformed by key, ``monitor``.

        What has arrived is drained first, so the figures include it.
        """
        self.recorder.drain()
        with self._lock:
            malformed = self.malformed.to_dict()
        monitor = None
        if self.monitor is not None:
            with self._monitor_lock:
                monitor = self.monitor.figures()
        return {
            "role": ROLE,
            "device": self.device,
            "received": self.recorder.received,
            "recorder": self.recorder.stats(),
            "malformed": malformed,
            "monitor": monitor,
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
    parser.add_argument(
        "--monitor", action="store_true",
        help="also keep the demo's live figures of --device's estimates (statistics: monitor)",
    )  # fmt: skip
    parser.add_argument(
        "--contact-threshold", type=float, default=AccuracyConfig().contact_threshold_n,
        metavar="N", help="with --monitor: true force above which a sample counts as contact",
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
        monitor = None
        if args.monitor:
            monitor = SessionMonitor(args.device, AccuracyConfig(args.contact_threshold))
        writer = SessionWriter(
            path, metadata, flush_interval_s=args.record_flush_s, profile=PROFILE
        )
        session = open_session(options_from_args(args))
    except (TeleopForceError, OSError) as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        recorder = SessionRecorder(session, writer, args.device, monitor=monitor).start()
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
    log(ROLE, final_line(stats))
    return 0


def final_line(stats: dict[str, Any]) -> str:
    """Return the last line: what was written, dropped and refused (from :meth:`stats`)."""
    recorder = stats["recorder"]
    return (
        f"stopped: {recorder['messages']} messages written to {recorder['path']} "
        f"({stats['received']} received, {recorder['dropped']} dropped, "
        f"{stats['malformed']['dropped']} malformed)"
    )


if __name__ == "__main__":
    sys.exit(main())
