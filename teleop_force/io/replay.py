"""Replay a recorded session over Zenoh as if it were live (``teleop-force replay``).

The joint states, setpoints, true contact forces and statuses of a session MCAP are published
on their recorded keys, in recorded (log-time) order, with the recorded timing divided by
``speed`` (``speed == 0``: as fast as possible, for benchmarks). Recorded estimates are not
published: a running force-estimation service (or one started in this process with
``with_service``) computes them again, exactly as it did live.

Every message keeps its ``seq``; its stamp ``t_ns`` is shifted by one constant so the stream
looks current (``t_ns + (now_at_start - first t_ns)``). The service counts time from a
stream's first stamp in integer nanoseconds, so the shift changes nothing in its arithmetic:
the same joint states in the same order give the same estimates, bit for bit.

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

from teleop_force.errors import ConfigurationError, DataError, TeleopForceError
from teleop_force.io.mcap_session import SessionReader
from teleop_force.process.lifetime import StopSignal
from teleop_force.transport import keys
from teleop_force.transport import messages as m
from teleop_force.transport.pubsub import (
    declare_data_publisher,
    declare_token,
    put,
    undeclare_all,
    wait_for_subscribers,
)

#: Kinds of recorded channels that are published again.
REPLAYED_KINDS: Final = (keys.MEASURED_JS, keys.SETPOINT_JS, keys.MEASURED_CF, keys.STATUS)
ROLE: Final = "replay"
#: Sleeping is accurate to ~0.1 ms; the last part before a message's time is spun.
_SPIN_S: Final = 2e-4
#: Every wire message begins with magic (2), version, type, seq (u32), then the stamp ``t_ns``
#: (i64, little-endian): restamping rewrites those 8 bytes instead of rebuilding the message.
_STAMP_OFFSET: Final = 8
_STAMP: Final = struct.Struct("<q")


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
        published: Messages published per key.
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
    counts = reader.message_counts
    with_js = [d for d in reader.devices() if counts.get(keys.measured_js(d), 0) > 0]
    if len(with_js) == 1:
        return with_js[0]
    raise DataError(
        f"cannot tell the primary device among {', '.join(with_js) or 'none'}; pass --device",
        path=reader.path,
    )


def replayed_topics(reader: SessionReader) -> list[str]:
    """Return the recorded keys a replay publishes (the kinds of :data:`REPLAYED_KINDS`)."""
    topics = []
    for topic in reader.topics:
        try:
            parsed = keys.parse(topic)
        except TeleopForceError:
            continue
        if parsed.kind in REPLAYED_KINDS:
            topics.append(topic)
    return sorted(topics)


def replay_session(
    session: zenoh.Session, config: ReplayConfig, stop: StopSignal | None = None
) -> ReplayResult:
    """Publish the recording on ``session`` (module docstring); return what was published."""
    stop = stop if stop is not None else StopSignal()
    reader = SessionReader(config.path)
    device = primary_device(reader, config.device)
    topics = replayed_topics(reader)
    primary_js = keys.measured_js(device)
    if primary_js not in topics:
        raise DataError(f"no joint states of {device!r} ({primary_js}) to replay", path=config.path)
    publishers = {topic: declare_data_publisher(session, topic) for topic in topics}
    token = declare_token(session, keys.alive(device, ROLE))
    published = dict.fromkeys(topics, 0)
    try:
        matched = True
        if config.wait_subscribers_s > 0.0:
            matched = wait_for_subscribers(
                publishers[primary_js], config.wait_subscribers_s, stop=stop.is_set
            )
        started_s = time.perf_counter()
        first_log_ns: int | None = None
        last_log_ns = 0
        shift_ns = 0
        scale = 0.0 if config.speed == 0.0 else 1e-9 / config.speed
        for topic, log_ns, message in reader.messages(topics):
            if stop.is_set():
                break
            if not isinstance(message, m.JointState | m.JointSetpoint | m.ContactForce | m.Status):
                continue
            if first_log_ns is None:
                first_log_ns = log_ns
                if config.restamp:
                    shift_ns = time.time_ns() - message.t_ns
                started_s = time.perf_counter()
            last_log_ns = log_ns
            if scale:
                _sleep_until(started_s + (log_ns - first_log_ns) * scale)
            payload = message.encode()
            if shift_ns:
                payload = _restamped(payload, message.t_ns + shift_ns)
            put(publishers[topic], payload)
            published[topic] += 1
        duration = time.perf_counter() - started_s
    finally:
        undeclare_all(token, *publishers.values())
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


def _restamped(payload: bytes, t_ns: int) -> bytes:
    """``payload`` with the stamp ``t_ns`` in its header (docs/wire_format.md), nothing else."""
    out = bytearray(payload)
    _STAMP.pack_into(out, _STAMP_OFFSET, t_ns)
    return bytes(out)


def _sleep_until(deadline_s: float) -> None:
    remaining = deadline_s - time.perf_counter() - _SPIN_S
    if remaining > 0.0:
        time.sleep(remaining)
    while time.perf_counter() < deadline_s:
        pass
