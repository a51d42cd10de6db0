"""The demo's live figures of a device's estimates, from the messages of a session.

:class:`SessionMonitor` takes the samples of ``/<device>/estimated_cf``,
``/<device>/estimate_diagnostics``, ``/<device>/true_cf`` and ``/<device>/status`` (the CDR
payload and rmw_zenoh's attachment of each) and keeps what ``teleop-force demo`` reports: the
estimates and true forces lost (from the attachments' sequence numbers), the accuracy of the
estimate during contact (an estimate paired with the true force of the same tick: its
``source_sequence`` is the sequence number of the slave's true force of that tick), the first
estimate, the slave's state and how often it went to ``holding``. A sample that does not decode
is counted in :attr:`malformed` and dropped.

It runs wherever those samples already arrive: in the session recorder, which receives every
message of the domain anyway (``--monitor``; :meth:`figures` on its statistics queryable), or
on subscriptions of the demo's own when nothing records. Not thread-safe: one caller at a time.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Final

from teleop_force.errors import MessageError
from teleop_force.ros2 import codec, streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.service.accuracy import AccuracyConfig, ForceAccuracy
from teleop_force.transport import messages as m
from teleop_force.transport.stream_stats import SequenceTracker

#: The topic kinds the monitor takes.
MONITORED: Final = (
    topics.ESTIMATED_CF,
    topics.ESTIMATE_DIAGNOSTICS,
    topics.TRUE_CF,
    topics.STATUS,
)
_SEQ_MASK: Final = 0xFFFF_FFFF
_DECODE_TRUE_FORCE: Final = streams.decoder(topics.TRUE_CF)


class SessionMonitor:
    """Loss, accuracy, first estimate and state of one device's estimates (module docstring).

    Args:
        device: The device whose topics are taken (``/<device>/...``).
        accuracy: Contact threshold and filter of the accuracy figure.
        max_unpaired: Estimate halves kept waiting for their other half (set it above the
            number of samples a caller hands over at once).

    """

    def __init__(
        self, device: str, accuracy: AccuracyConfig | None = None, *, max_unpaired: int = 1 << 16
    ) -> None:
        """Start with nothing received."""
        self.device = topics.validate_device(device)
        self.accuracy = ForceAccuracy(accuracy)
        self.estimates = SequenceTracker()
        self.true_forces = SequenceTracker()
        self.malformed = 0
        #: Header stamp (ns since the epoch) and source seq of the first estimate received.
        self.first_estimate_ns: int | None = None
        self.first_source_seq: int | None = None
        self.state = "unknown"
        self.reason = ""
        self.holds_seen = 0
        self._joiner = streams.EstimateJoiner(self._on_estimate, max_unpaired=max_unpaired)
        self._handlers: dict[str, Callable[[bytes, Attachment], None]] = {
            topics.topic_name(self.device, topics.ESTIMATED_CF): self._joiner.on_wrench,
            topics.topic_name(self.device, topics.ESTIMATE_DIAGNOSTICS): (
                self._joiner.on_diagnostics
            ),
            topics.topic_name(self.device, topics.TRUE_CF): self._on_true_force,
            topics.topic_name(self.device, topics.STATUS): self._on_status,
        }

    def handler(self, topic: str) -> Callable[[bytes, Attachment], None] | None:
        """Return the handler of a ROS topic name (``/slave/true_cf``), ``None`` if not taken."""
        return self._handlers.get(topic)

    def take(
        self, handle: Callable[[bytes, Attachment], None], payload: bytes, attachment: Attachment
    ) -> None:
        """Hand one sample to ``handle``; a sample that does not decode is counted, dropped."""
        try:
            handle(payload, attachment)
        except MessageError:
            self.malformed += 1

    def take_topic(
        self, topic: str, payloads: Sequence[bytes], attachments: Sequence[bytes]
    ) -> None:
        """Take samples of ``topic`` with their attachments' bytes (other topics: ignored)."""
        handle = self._handlers.get(topic)
        if handle is None:
            return
        for payload, attachment in zip(payloads, attachments, strict=True):
            try:
                parsed = Attachment.decode(attachment)
            except MessageError:
                self.malformed += 1
                continue
            self.take(handle, payload, parsed)

    def take_raw(self, topic: str, payload: bytes, attachment: bytes) -> None:
        """Take one sample of ``topic`` with its attachment's bytes (other topics: ignored)."""
        self.take_topic(topic, (payload,), (attachment,))

    def figures(self) -> dict[str, Any]:
        """JSON figures: first estimate, loss, state, holds, latest forces, accuracy."""
        accuracy = self.accuracy
        return {
            "device": self.device,
            "first_estimate_ns": self.first_estimate_ns,
            "first_source_seq": self.first_source_seq,
            "estimates": {"received": self.estimates.received, "lost": self.estimates.lost},
            "true_forces": {"received": self.true_forces.received, "lost": self.true_forces.lost},
            "malformed": self.malformed,
            "state": self.state,
            "reason": self.reason,
            "holds_seen": self.holds_seen,
            "latest_estimate_n": accuracy.latest_estimate,
            "latest_true_n": accuracy.latest_true,
            "force_error": accuracy.summary(),
        }

    def _on_estimate(self, estimate: m.ForceEstimateMessage, attachment: Attachment) -> None:
        if self.first_estimate_ns is None:
            self.first_estimate_ns, self.first_source_seq = estimate.t_ns, estimate.source_seq
        self.estimates.observe(estimate.seq)
        self.accuracy.add_estimate(estimate.source_seq, estimate.f_n)

    def _on_true_force(self, payload: bytes, attachment: Attachment) -> None:
        seq = attachment.sequence_number & _SEQ_MASK
        force = _DECODE_TRUE_FORCE(payload, seq)  # raises MessageError
        self.true_forces.observe(seq)
        self.accuracy.add_true(seq, force.f_n)

    def _on_status(self, payload: bytes, attachment: Attachment) -> None:
        status = codec.decode_status(payload, attachment.sequence_number & _SEQ_MASK)
        state = status.state.name.lower()
        if state == "holding" and self.state != "holding":
            self.holds_seen += 1
        self.state, self.reason = state, status.reason
