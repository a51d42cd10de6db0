"""Replay a recorded session over Zenoh as ROS 2 messages, as if live (``teleop-force replay``).

The joint states, setpoints, true contact forces and statuses of a session MCAP are published
as ROS 2 messages on rmw_zenoh's keys by a node ``teleop_force_replay``
(:mod:`teleop_force.ros2.node`), each stream on its topic ``/<device>/<kind>``
(``measured_js``, ``setpoint_js``, ``true_cf``, ``status``), in recorded (log-time) order,
with the recorded timing divided by ``speed`` (``speed == 0``: as fast as possible, for
benchmarks). A session recorded from ROS 2 is published as recorded: the CDR bytes as they
are; one recorded before (the project's own CDR or JSON channels) is encoded with
:mod:`teleop_force.ros2.codec` (joint names :func:`~teleop_force.ros2.topics.model_joint_names`,
wrenches in the ``base`` frame). Recorded estimates are not published: a running
force-estimation service (or one started in this process with ``--with-service``) computes
them again, exactly as it did live.

Every message keeps its sequence number (rmw_zenoh's attachment: the recorded MCAP sequence,
or an old session's ``seq``); its header stamp is shifted by one constant so the stream looks
current (``stamp + (now_at_start - first stamp)``, the 8 stamp bytes of the header rewritten,
nothing else; ``restamp=False``: the bytes untouched), and its attachment's source time is
the time it is published. The service counts time from a stream's first stamp in integer
nanoseconds, so the shift changes nothing in its arithmetic: the same joint states in the
same order give the same estimates, bit for bit.

Before the first message the replay waits (``wait_subscribers_s``) until the primary device's
joint-state publisher has a matching subscriber, because Zenoh may drop what is published in
the first milliseconds after a match. The result reports the throughput in messages per
second (with ``speed == 0``, the replay's own).

Re-estimating a recording with a model (``replay --with-service --record``) needs no Zenoh:
:mod:`teleop_force.service.reestimation` computes it in batch.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import zenoh

from teleop_force.errors import ConfigurationError, DataError, MessageError
from teleop_force.io.mcap_session import (
    MEASURED_JS,
    SETPOINT_JS,
    STATUS,
    TRUE_CF,
    SessionReader,
    parse_stream,
)
from teleop_force.process.lifetime import StopSignal
from teleop_force.ros2 import topics as ros_topics
from teleop_force.ros2.node import Node
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import declare_token, undeclare_all, wait_for_subscribers

#: Stream kinds that are published again, with their ROS 2 topic.
REPLAYED_TOPICS: Final = {
    MEASURED_JS: ros_topics.MEASURED_JS, SETPOINT_JS: ros_topics.SETPOINT_JS,
    TRUE_CF: ros_topics.TRUE_CF, STATUS: ros_topics.STATUS,
}  # fmt: skip
REPLAYED_KINDS: Final = tuple(REPLAYED_TOPICS)
ROLE: Final = "replay"
#: The replay's ROS 2 node.
NODE_NAME: Final = "teleop_force_replay"
#: Sleeping is accurate to ~0.1 ms; the last part before a message's time is spun.
_SPIN_S: Final = 2e-4
#: Every replayed type begins with a std_msgs/Header, its stamp (int32 sec, uint32 nanosec)
#: right after the 4-byte CDR encapsulation header.
_STAMP_OFFSET: Final = 4
_STAMP: Final = struct.Struct("<iI")
_NS_PER_S: Final = 1_000_000_000


@dataclass(frozen=True)
class ReplayConfig:
    """What to replay and how fast.

    Attributes:
        path: The session MCAP.
        speed: Time scale (2: twice as fast; 0: as fast as possible).
        device: Primary device (default: the recording's ``primary_device``).
        wait_subscribers_s: Wait this long for a subscriber of the primary joint states.
        restamp: Shift the stamps to the present (``False``: publish the recorded stamps).

    """

    path: Path
    speed: float = 1.0
    device: str | None = None
    wait_subscribers_s: float = 10.0
    restamp: bool = True

    def __post_init__(self) -> None:
        """Check the ranges."""
        object.__setattr__(self, "path", Path(self.path))
        if not (math.isfinite(self.speed) and self.speed >= 0.0):
            raise ConfigurationError(
                f"--speed must be >= 0 (0: as fast as possible), got {self.speed}"
            )
        if self.device is not None:
            keys.validate_chunk(self.device)
        if not self.wait_subscribers_s >= 0.0:
            raise ConfigurationError("wait_subscribers_s must be >= 0")


@dataclass(frozen=True)
class ReplayResult:
    """What a replay published.

    Attributes:
        device: The primary device.
        published: Messages published per ROS 2 topic.
        duration_s: Wall time of the publishing.
        recorded_span_s: Log-time span of the replayed messages in the recording.
        matched: Whether a subscriber of the primary joint states was found before starting.
        stopped: Whether the replay was interrupted.
        messages_per_s: Messages published per second of wall time (``--fast``: the
            throughput of the replay itself).

    """

    device: str
    published: dict[str, int]
    duration_s: float
    recorded_span_s: float
    matched: bool
    stopped: bool
    messages_per_s: float = 0.0

    def __post_init__(self) -> None:
        """Check the counts and durations."""
        if self.duration_s < 0.0 or self.recorded_span_s < 0.0:
            raise ConfigurationError("durations must be >= 0")
        if any(count < 0 for count in self.published.values()):
            raise ConfigurationError("published counts must be >= 0")
        if not self.messages_per_s >= 0.0:
            raise ConfigurationError("messages_per_s must be >= 0")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return dataclasses.asdict(self)


def primary_device(reader: SessionReader, device: str | None = None) -> str:
    """Return the replayed device: ``device``, else the metadata's, else the only one."""
    if device is not None:
        return device
    primary = reader.metadata.get("primary_device")
    if primary:
        return keys.validate_chunk(primary)
    with_js = [d for d in reader.devices() if reader.stream_count(d, MEASURED_JS) > 0]
    if len(with_js) == 1:
        return with_js[0]
    raise DataError(
        f"cannot tell the primary device among {', '.join(with_js) or 'none'}; pass --device",
        path=reader.path,
    )


def replayed_topics(reader: SessionReader) -> list[str]:
    """Return the recorded channels a replay publishes (streams of :data:`REPLAYED_KINDS`)."""
    return sorted(
        topic for stream, topic in reader.streams.items() if stream.kind in REPLAYED_KINDS
    )


def replay_session(
    session: zenoh.Session, config: ReplayConfig, stop: StopSignal | None = None
) -> ReplayResult:
    """Publish the recording on ``session`` (module docstring); return what was published.

    ``published`` counts the messages per ROS 2 topic (``/slave/measured_js`` ...).
    """
    stop = stop if stop is not None else StopSignal()
    reader = SessionReader(config.path)
    device = primary_device(reader, config.device)
    channels = {topic: ros2_topic(topic) for topic in replayed_topics(reader)}
    types = {}  # recorded topic -> ROS 2 type
    for topic in channels:
        stream = parse_stream(topic)
        assert stream is not None  # replayed_topics' contract
        types[topic] = REPLAYED_TOPICS[stream.kind].ros_type
    primary_js = reader.stream_topic(device, MEASURED_JS)
    if primary_js is None or primary_js not in channels:
        raise DataError(f"no joint states of {device!r} to replay", path=config.path)
    published = dict.fromkeys(channels.values(), 0)
    encoder = _Encoder(reader)
    node = Node(session, NODE_NAME)
    token = None
    try:
        publishers = {t: node.publisher(name, types[t]) for t, name in channels.items()}
        token = declare_token(session, keys.alive(device, ROLE))
        matched = True
        if config.wait_subscribers_s > 0.0:
            matched = wait_for_subscribers(
                publishers[primary_js].zenoh_publisher, config.wait_subscribers_s, stop=stop.is_set
            )
        started_s = time.perf_counter()
        first_log_ns: int | None = None
        last_log_ns = 0
        shift_ns: int | None = None if config.restamp else 0
        scale = 0.0 if config.speed == 0.0 else 1e-9 / config.speed
        for topic, log_ns, sequence, payload in encoder.messages(list(channels)):
            if stop.is_set():
                break
            if shift_ns is None and (stamp_ns := _stamp_ns(payload)) is not None:
                shift_ns = time.time_ns() - stamp_ns
            if first_log_ns is None:
                first_log_ns = log_ns
                started_s = time.perf_counter()
            last_log_ns = log_ns
            if scale:
                _sleep_until(started_s + (log_ns - first_log_ns) * scale)
            if shift_ns:
                payload = _restamped(payload, shift_ns)
            publishers[topic].publish(payload, sequence_number=sequence)
            published[channels[topic]] += 1
        duration = time.perf_counter() - started_s
    finally:
        undeclare_all(token)
        node.close()
    span = 0.0 if first_log_ns is None else (last_log_ns - first_log_ns) * 1e-9
    total = sum(published.values())
    return ReplayResult(
        device=device,
        published=published,
        duration_s=round(duration, 6),
        recorded_span_s=round(span, 6),
        matched=matched,
        stopped=stop.is_set(),
        messages_per_s=round(total / duration, 1) if duration > 0.0 else 0.0,
    )


def ros2_topic(recorded_topic: str) -> str:
    """Return the ROS 2 topic a recorded replayed channel is published on (``/<device>/<kind>``)."""
    stream = parse_stream(recorded_topic)
    if stream is None or stream.kind not in REPLAYED_TOPICS:
        raise ConfigurationError(f"{recorded_topic!r} is not a replayed stream")
    return ros_topics.topic_name(stream.device, REPLAYED_TOPICS[stream.kind])


def ros2_payload(message: object) -> tuple[str, bytes] | None:
    """Return the ROS 2 type and CDR payload of an old session's replayed message, else None.

    Joint states in the model's joint names, wrenches in the ``base`` frame; raise
    MessageError for a message ROS 2 cannot carry (a stamp beyond int32 seconds).
    """
    from teleop_force.ros2 import codec  # rosbags: when replaying

    if isinstance(message, m.JointState):
        names = ros_topics.model_joint_names(message.n_joints)
        return ros_topics.MEASURED_JS.ros_type, codec.encode_joint_state(message, names)
    if isinstance(message, m.JointSetpoint):
        names = ros_topics.model_joint_names(len(message.q_rad))
        return ros_topics.SETPOINT_JS.ros_type, codec.encode_joint_setpoint(message, names)
    if isinstance(message, m.ContactForce):
        payload = codec.encode_contact_force(message, ros_topics.BASE_FRAME)
        return ros_topics.TRUE_CF.ros_type, payload
    if isinstance(message, m.Status):
        return ros_topics.STATUS.ros_type, codec.encode_status(message)
    return None


def check_one_kind(reader: SessionReader, topics: list[str]) -> bool:
    """Return whether ``topics`` are ROS 2 channels (else older ones); DataError if both."""
    old = [t for t in topics if not reader.is_ros2_topic(t)]
    if old and len(old) != len(topics):
        raise DataError(
            "a session with both ROS 2 and older channels cannot be replayed", path=reader.path
        )
    return not old


class _Encoder:
    """The replayed messages as ROS 2 payloads: ROS 2 channels as recorded, old ones encoded."""

    def __init__(self, reader: SessionReader) -> None:
        self.reader = reader

    def messages(self, topics: list[str]) -> Any:
        """Yield ``(topic, log_time_ns, sequence number, CDR payload)`` in log-time order."""
        if check_one_kind(self.reader, topics):
            for raw in self.reader.raw_messages(topics):
                yield raw.topic, raw.log_time_ns, raw.sequence, raw.data
            return
        for topic, log_ns, message in self.reader.messages(topics):
            try:
                encoded = ros2_payload(message)
            except (MessageError, ConfigurationError) as exc:
                raise DataError(
                    f"cannot replay the message at log time {log_ns} ns: {exc}",
                    path=self.reader.path,
                    column=topic,
                ) from None
            if encoded is not None:
                yield topic, log_ns, message.seq, encoded[1]


def _stamp_ns(payload: bytes) -> int | None:
    """Return the header stamp of a little-endian CDR payload [ns]; None if it has none."""
    if len(payload) < _STAMP_OFFSET + _STAMP.size or payload[:2] != b"\x00\x01":
        return None  # recorded as received: a malformed or big-endian message
    sec, nanosec = _STAMP.unpack_from(payload, _STAMP_OFFSET)
    return int(sec) * _NS_PER_S + int(nanosec)


def _restamped(payload: bytes, shift_ns: int) -> bytes:
    """``payload`` with its header stamp shifted by ``shift_ns``, nothing else.

    A payload without a readable stamp (:func:`_stamp_ns`) goes out as it was recorded.
    """
    t_ns = _stamp_ns(payload)
    if t_ns is None:
        return payload
    sec, nanosec = divmod(t_ns + shift_ns, _NS_PER_S)
    out = bytearray(payload)
    _STAMP.pack_into(out, _STAMP_OFFSET, sec, nanosec)
    return bytes(out)


def _sleep_until(deadline_s: float) -> None:
    remaining = deadline_s - time.perf_counter() - _SPIN_S
    if remaining > 0.0:
        time.sleep(remaining)
    while time.perf_counter() < deadline_s:
        pass
