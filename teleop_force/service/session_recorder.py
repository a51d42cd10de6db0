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

The subscriptions are FIFO channels (:func:`~teleop_force.transport.pubsub.
declare_queue_subscriber`), not callbacks: Zenoh's receive thread queues each sample without
running Python or taking the interpreter lock, and the recorder's drain thread takes what has
arrived every :data:`DRAIN_INTERVAL_S` (20 ms) and hands it to the recorder in one go. A
message's MCAP log time is when it was received, known to within that interval: its source
stamp ``t_ns`` clamped into the interval in which it arrived: after the previous drain found
its FIFO empty, before this drain took it (a publisher on this clock stamps it a fraction of
a millisecond before it arrives). Log times therefore never decrease on a key, whatever clock
stamped the messages.

With ``--ros2`` it also records every ROS 2 message of its domain (``<ROS_DOMAIN_ID>/**``,
rmw_zenoh's keys) as it arrived: the CDR bytes untouched on a channel named by the ROS topic
(``/slave/measured_js``) with the type's ``ros2msg`` schema, the MCAP sequence and publish
time from rmw_zenoh's attachment (its sequence number and source time), the file's profile
``ros2`` (:meth:`~teleop_force.io.mcap_session.SessionWriter.write_ros2`), so Foxglove's
panels and ROS tools read those channels as a ROS 2 bag. A sample whose key is not a topic
key or that has no valid attachment is counted as malformed and dropped.

It answers ``omni/<device>/stats/recorder`` (JSON: the recorder's counters, the malformed
messages by key) and holds the token ``omni/<device>/alive/recorder``; it stops on SIGINT /
SIGTERM or ``--duration`` and closes the file (what was queued is written first).
"""

from __future__ import annotations

import argparse
import gc
import struct
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, DataError, MessageError, TeleopForceError
from teleop_force.io.mcap_session import DEFAULT_FLUSH_INTERVAL_S, SessionWriter
from teleop_force.process.lifetime import StopSignal, log, write_json
from teleop_force.ros2 import graph as ros2_graph
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.controls import create_exclusively
from teleop_force.service.counters import MalformedCounter
from teleop_force.service.recorder import BackgroundRecorder
from teleop_force.transport import keys
from teleop_force.transport.pubsub import (
    declare_json_queryable,
    declare_queue_subscriber,
    declare_token,
    undeclare_all,
)
from teleop_force.transport.session import open_session, options_from_args

ROLE: Final = "recorder"
#: The kinds recorded, for every device.
RECORDED_KINDS: Final = (
    keys.MEASURED_JS, keys.SETPOINT_JS, keys.MEASURED_CF, keys.ESTIMATED_CF, keys.STATUS,
)  # fmt: skip
#: How often the drain thread takes the samples waiting in the subscriptions' FIFOs [s].
DRAIN_INTERVAL_S: Final = 0.02
#: Samples a subscription's FIFO holds (60 s of one 1 kHz key): never reached while draining.
FIFO_CAPACITY: Final = 60_000
_STAMP: Final = struct.Struct("<q")  # t_ns in every message's header (docs/wire_format.md)
_STAMP_OFFSET: Final = 8


class SessionRecorder:
    """Zenoh subscriptions feeding a :class:`BackgroundRecorder` (module docstring)."""

    def __init__(
        self, session: zenoh.Session, writer: SessionWriter, device: str, *, ros2: bool = False
    ) -> None:
        """Prepare the recorder on ``writer``; nothing is subscribed until :meth:`start`.

        ``ros2``: also record the ROS 2 messages of the domain (module docstring).
        """
        self.session = session
        self.writer = writer
        self.ros2 = ros2
        self._ros2_queue: Any = None
        self._ros2_drained_ns = 0
        #: ROS 2 messages written.
        self.ros2_written = 0
        self.device = keys.validate_chunk(device)
        self.malformed = MalformedCounter()
        self._lock = threading.Lock()
        self.recorder = BackgroundRecorder(writer, self._count_malformed)
        self._entities: list[Any] = []
        self._queues: list[Any] = []
        self._drained_ns: list[int] = []  # per FIFO: when its last drain found it empty
        self._stop_drain = threading.Event()
        self._drain_thread = threading.Thread(
            target=self._drain_loop, name="recorder-drain", daemon=True
        )
        #: Samples taken from the subscriptions so far.
        self.received = 0

    def _count_malformed(self, key: str, exc: Exception) -> None:
        with self._lock:
            self.malformed.count(key, exc)

    def drain(self) -> int:
        """Hand every sample waiting in the subscriptions' FIFOs to the recorder; return how many.

        Log times: each sample's source stamp clamped into ``[end of this FIFO's previous
        drain, when it was taken]`` (module docstring).
        """
        submit = self.recorder.submit
        count = 0
        for i, subscriber in enumerate(self._queues):
            earliest_ns = self._drained_ns[i]
            while (sample := subscriber.try_recv()) is not None:
                taken_ns = time.time_ns()
                payload = sample.payload.to_bytes()
                stamp_ns = taken_ns
                if len(payload) >= _STAMP_OFFSET + _STAMP.size:
                    stamp_ns = _STAMP.unpack_from(payload, _STAMP_OFFSET)[0]
                submit(str(sample.key_expr), payload, min(max(stamp_ns, earliest_ns), taken_ns))
                count += 1
            self._drained_ns[i] = time.time_ns()
        if self._ros2_queue is not None:
            count += self._drain_ros2()
        self.received += count
        return count

    def _drain_ros2(self) -> int:
        """Write every ROS 2 sample waiting, as received; return how many were taken."""
        count = 0
        earliest_ns = self._ros2_drained_ns
        while (sample := self._ros2_queue.try_recv()) is not None:
            taken_ns = time.time_ns()
            count += 1
            key = str(sample.key_expr)
            try:
                topic, ros_type = ros2_graph.parse_topic_key(key)
                raw = sample.attachment
                if raw is None:
                    raise MessageError("sample without rmw_zenoh's attachment")
                attachment = Attachment.decode(raw.to_bytes())
                source_ns = attachment.source_timestamp_ns
                self.writer.write_ros2(
                    topic, ros_type, sample.payload.to_bytes(), attachment.sequence_number,
                    source_ns, min(max(source_ns, earliest_ns), taken_ns),
                )  # fmt: skip
            except (MessageError, DataError) as exc:
                self._count_malformed(key, exc)
                continue
            self.ros2_written += 1
        self._ros2_drained_ns = time.time_ns()
        return count

    def _drain_loop(self) -> None:
        while not self._stop_drain.wait(DRAIN_INTERVAL_S):
            self.drain()

    def start(self) -> SessionRecorder:
        """Subscribe to the recorded keys, answer statistics, declare the token; return self."""
        for kind in RECORDED_KINDS:
            subscriber = declare_queue_subscriber(
                self.session, keys.any_device(kind), FIFO_CAPACITY
            )
            self._queues.append(subscriber)
            self._drained_ns.append(time.time_ns())
            self._entities.append(subscriber)
        if self.ros2:
            domain = ros2_graph.domain_id_from_env()
            self._ros2_queue = declare_queue_subscriber(self.session, f"{domain}/**", FIFO_CAPACITY)
            self._ros2_drained_ns = time.time_ns()
            self._entities.append(self._ros2_queue)
        self._entities.append(
            declare_json_queryable(self.session, keys.process_stats(self.device, ROLE), self.stats)
        )
        self._entities.append(declare_token(self.session, keys.alive(self.device, ROLE)))
        self._drain_thread.start()
        return self

    def close(self) -> None:
        """Stop draining, take what arrived, unsubscribe, then write what is queued and close."""
        self._stop_drain.set()
        if self._drain_thread.is_alive():
            self._drain_thread.join()
        self.drain()
        entities, self._entities = self._entities, []
        undeclare_all(*reversed(entities))
        self._queues, self._drained_ns, self._ros2_queue = [], [], None
        self.recorder.close()

    def stats(self) -> dict[str, Any]:
        """JSON statistics: samples received, the recorder's counters, malformed by key."""
        with self._lock:
            malformed = self.malformed.to_dict()
        return {
            "role": ROLE,
            "device": self.device,
            "received": self.received,
            "ros2_written": self.ros2_written if self.ros2 else None,
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
    parser.add_argument(
        "--ros2", action="store_true",
        help="also record the ROS 2 messages of ROS_DOMAIN_ID as received (profile ros2)",
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
        writer = SessionWriter(
            path,
            metadata,
            flush_interval_s=args.record_flush_s,
            profile="ros2" if args.ros2 else "",
        )
        session = open_session(options_from_args(args))
    except (TeleopForceError, OSError) as exc:
        log(ROLE, f"error: {exc}")
        return 2
    try:
        recorder = SessionRecorder(session, writer, args.device, ros2=args.ros2).start()
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
