"""Record every ROS 2 message of a domain as it was received, to a session MCAP.

:class:`Ros2Recorder` is what the session recorder process and the estimation service's own
recording (``--record``, the ``record`` control) both run. One subscriber on
``<ROS_DOMAIN_ID>/**`` (every data key of rmw_zenoh in the domain; its liveliness tokens are
under ``@ros2_lv/``, not data) is a FIFO channel (:func:`~teleop_force.transport.pubsub.
declare_queue_subscriber`): Zenoh's receive thread queues each sample without running Python.
A thread of the recorder takes what has arrived every :data:`DRAIN_INTERVAL_S` (100 ms) and
writes it topic by topic, a topic's same-size payloads in one block
(:meth:`SessionWriter.write_ros2_block
<teleop_force.io.mcap_session.SessionWriter.write_ros2_block>`, no Python per message beyond
taking it from the FIFO; others one by one): the CDR bytes untouched on a channel
named by the ROS topic (``/slave/measured_js``, from the key) with the type's ``ros2msg``
schema, the MCAP sequence and publish time from rmw_zenoh's attachment (sequence number and
source time). The writer's profile is ``ros2``: Foxglove and rosbag2 read the file as a ROS 2
bag. A Zenoh session receives its own publications, so a service recording on its own session
records the estimates it publishes.

A message's MCAP log time is when it was received, known to within the drain interval: its
source time clamped into the interval in which it arrived (after the previous drain found the
FIFO empty, before this drain took it), so log times never decrease, whatever clock stamped
the messages. A sample whose key is no topic key, without a valid attachment, or that cannot
be written (a topic whose type changes) is counted as malformed (``on_malformed(key,
error)``) and dropped. After each drain the writer's chunks are closed once they are
``flush_interval_s - DRAIN_INTERVAL_S`` old, so a killed process loses at most the writer's
flush interval.
"""

from __future__ import annotations

import contextlib
import struct
import threading
import time
from collections.abc import Callable
from typing import Any, Final, Self

import numpy as np
import zenoh

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.io.mcap_session import SessionWriter
from teleop_force.ros2 import graph
from teleop_force.ros2.attachment import ATTACHMENT_SIZE
from teleop_force.ros2.graph import GID_SIZE
from teleop_force.transport.pubsub import declare_queue_subscriber, undeclare_all

#: How often the drain thread takes the samples waiting in the FIFO [s].
DRAIN_INTERVAL_S: Final = 0.1
#: Samples the FIFO holds (10 s of six 1 kHz topics): never reached while draining.
FIFO_CAPACITY: Final = 60_000
#: The MCAP profile of a session recorded by :class:`Ros2Recorder`.
PROFILE: Final = "ros2"
#: Keys whose parse is kept (topics of a session: a few dozen).
_MAX_KEYS: Final = 4096
#: rmw_zenoh's attachment: int64 sequence number, int64 source time [ns] (then the GID).
_ATTACHMENT_HEAD: Final = struct.Struct("<qq")


#: ``observer(topic, payloads, attachments)``: the samples of one topic a drain wrote.
Observer = Callable[[str, list[bytes], list[bytes]], None]


def recorded_key(domain_id: int) -> str:
    """Return the key expression recorded: every data key of the domain."""
    if not isinstance(domain_id, int) or domain_id < 0:
        raise ConfigurationError(f"ROS domain id must be an int >= 0, got {domain_id!r}")
    return f"{domain_id}/**"


class Ros2Recorder:
    """A FIFO subscriber on ``<domain>/**`` drained by a thread into a writer (module docstring).

    Args:
        session: The Zenoh session to subscribe on.
        writer: The session file (profile ``ros2``); closed by :meth:`close`.
        on_malformed: Called as ``on_malformed(key, error)`` (from the drain thread) for each
            sample dropped.
        domain_id: The ROS domain (default ``ROS_DOMAIN_ID``).
        observer: Called as ``observer(topic, payloads, attachments)`` (from the drain thread,
            one call per topic per drain, in arrival order) with the samples that have a valid
            attachment, before they are written: the payloads and the attachments' bytes.

    """

    def __init__(
        self,
        session: zenoh.Session,
        writer: SessionWriter,
        on_malformed: Callable[[str, Exception], None] | None = None,
        *,
        domain_id: int | None = None,
        observer: Observer | None = None,
    ) -> None:
        """Prepare the recorder; nothing is subscribed until :meth:`start`."""
        self.session = session
        self.writer = writer
        self.domain_id = graph.domain_id_from_env() if domain_id is None else domain_id
        self.key = recorded_key(self.domain_id)
        #: Samples taken from the FIFO.
        self.received = 0
        #: Messages written.
        self.written = 0
        #: Samples dropped (reported to ``on_malformed``).
        self.malformed = 0
        self._on_malformed = on_malformed
        self._observer = observer
        self._topics: dict[str, tuple[str, str]] = {}  # key -> (topic, type), parsed once
        self._subscriber: Any = None
        self._drained_ns = 0
        self._margin_s = min(DRAIN_INTERVAL_S, writer.flush_interval_s / 4.0)
        self._lock = threading.Lock()  # one drain at a time (the thread, or close)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ros2-recorder", daemon=True)
        self._closed = False

    def start(self) -> Self:
        """Subscribe and start the drain thread; return self."""
        if self._subscriber is not None or self._closed:
            raise ConfigurationError("the recorder is already started or closed")
        self._drained_ns = time.time_ns()
        self._subscriber = declare_queue_subscriber(self.session, self.key, FIFO_CAPACITY)
        self._thread.start()
        return self

    def drain(self) -> int:
        """Write every sample waiting in the FIFO; return how many were taken."""
        with self._lock:
            subscriber = self._subscriber
            if subscriber is None:
                return 0
            earliest_ns = self._drained_ns
            by_key: dict[str, tuple[list[bytes], list[bytes | None]]] = {}
            count = 0
            while (sample := subscriber.try_recv()) is not None:
                count += 1
                key = str(sample.key_expr)
                got = by_key.get(key)
                if got is None:
                    got = by_key[key] = ([], [])
                got[0].append(sample.payload.to_bytes())
                raw = sample.attachment
                got[1].append(None if raw is None else raw.to_bytes())
            taken_ns = time.time_ns()  # the FIFO was found empty: what comes next is later
            self._drained_ns = taken_ns
            for key, (payloads, attachments) in by_key.items():
                self._write_topic(key, payloads, attachments, earliest_ns, taken_ns)
            self.received += count
            return count

    def _topic(self, key: str) -> tuple[str, str]:
        known = self._topics.get(key)
        if known is None:
            known = graph.parse_topic_key(key)  # raises MessageError
            if len(self._topics) < _MAX_KEYS:
                self._topics[key] = known
        return known

    def _drop(self, name: str, exc: Exception, n: int = 1) -> None:
        self.malformed += n
        if self._on_malformed is not None:
            for _ in range(n):
                self._on_malformed(name, exc)

    def _write_topic(
        self,
        key: str,
        payloads: list[bytes],
        attachments: list[bytes | None],
        earliest_ns: int,
        taken_ns: int,
    ) -> None:
        """Write one key's samples of a drain (module docstring)."""
        try:
            topic, ros_type = self._topic(key)
        except MessageError as exc:
            self._drop(key, exc, len(payloads))
            return
        kept: list[bytes] = []
        kept_raw: list[bytes] = []
        heads: list[tuple[int, int]] = []
        for payload, raw in zip(payloads, attachments, strict=True):
            if raw is None or len(raw) != ATTACHMENT_SIZE or raw[16] != GID_SIZE:
                self._drop(topic, MessageError("sample without a valid rmw_zenoh attachment"))
                continue
            kept.append(payload)
            kept_raw.append(raw)
            heads.append(_ATTACHMENT_HEAD.unpack_from(raw))
        if not kept:
            return
        if self._observer is not None:
            self._observer(topic, kept, kept_raw)
        seq = np.fromiter((h[0] for h in heads), dtype=np.int64, count=len(heads))
        source_ns = np.fromiter((h[1] for h in heads), dtype=np.int64, count=len(heads))
        log_ns = np.clip(source_ns, earliest_ns, taken_ns)
        size = len(kept[0])
        try:
            if size and all(len(x) == size for x in kept):
                block = np.frombuffer(b"".join(kept), dtype=np.uint8).reshape(len(kept), size)
                self.writer.write_ros2_block(topic, ros_type, block, seq, source_ns, log_ns)
                self.written += len(kept)
                return
            for payload, s_, t_, l_ in zip(kept, seq, source_ns, log_ns, strict=True):
                self.writer.write_ros2(topic, ros_type, payload, int(s_), int(t_), int(l_))
                self.written += 1
        except DataError as exc:
            self._drop(topic, exc, len(kept))

    def _run(self) -> None:
        while not self._stop.wait(DRAIN_INTERVAL_S):
            self.drain()
            with contextlib.suppress(DataError):  # a write error is counted with the next sample
                self.writer.flush_if_due(margin_s=self._margin_s)

    def close(self) -> None:
        """Stop draining, take what arrived, unsubscribe, close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self.drain()
        with self._lock:
            subscriber, self._subscriber = self._subscriber, None
        undeclare_all(subscriber)
        self.writer.close()

    def stats(self) -> dict[str, Any]:
        """Counters of the recording (the keys of the service's ``recording`` statistics)."""
        return {
            "path": str(self.writer.path),
            "messages": self.written,
            "durable": self.writer.messages_durable,
            "received": self.received,
            "backlog": 0,
            "dropped": 0,
            "malformed": self.malformed,
        }
