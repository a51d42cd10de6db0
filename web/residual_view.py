"""The service's residual watch on the dashboard: its state, a finding and the command to run.

:class:`DiagnosticsInbox` subscribes to the ROS 2 topic ``/<device>/service/diagnostics``
(``teleop_force_msgs/msg/ServiceDiagnostics``, decoded to the project's
:class:`~teleop_force.transport.messages.ServiceDiagnostics`, ~1 Hz) and keeps the latest
report; :func:`diagnostics_markdown` renders it for the "Residual watch" folder: what the
watch is doing, and on a persistent dependence the joint, the variable, its size and the
command to run next (``teleop-force residual RECORDING --model MODEL``).
"""

from __future__ import annotations

import math
import time

from teleop_force.errors import MessageError
from teleop_force.ros2 import streams, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Subscription
from teleop_force.transport.messages import ServiceDiagnostics

#: Older than this, the report is shown as stale [s] (the watch reports every second).
STALE_AFTER_S = 5.0


class DiagnosticsInbox:
    """The latest diagnostics of one device's service, written by a Zenoh callback."""

    def __init__(self) -> None:
        """Start empty; :meth:`subscribe` declares the subscription."""
        self.latest: ServiceDiagnostics | None = None
        self.received_s = math.nan
        self._malformed = 0
        self._subscriptions: list[Subscription] = []

    def subscribe(self, node: Node, device: str) -> DiagnosticsInbox:
        """Subscribe on ``node`` to the device's diagnostics topic; return self."""
        self._subscriptions = streams.subscribe(
            node, device, topics.SERVICE_DIAGNOSTICS, self.on_message, self.on_malformed
        )
        return self

    def on_message(self, message: ServiceDiagnostics, _attachment: Attachment) -> None:
        """Keep one decoded report."""
        self.latest, self.received_s = message, time.perf_counter()

    def on_malformed(self, _topic: str, _error: MessageError) -> None:
        """Count one report that did not decode (it is dropped)."""
        self._malformed += 1

    @property
    def malformed(self) -> int:
        """Reports dropped: not decodable, or without a valid attachment."""
        return self._malformed + sum(sub.malformed for sub in self._subscriptions)

    def age_s(self) -> float:
        """Seconds since the latest report (infinity before the first)."""
        if math.isnan(self.received_s):
            return math.inf
        return time.perf_counter() - self.received_s

    def close(self) -> None:
        """Undeclare the subscription (idempotent)."""
        subscriptions, self._subscriptions = self._subscriptions, []
        for sub in subscriptions:
            sub.close()


def diagnostics_markdown(message: ServiceDiagnostics | None, age_s: float = 0.0) -> str:
    """Return the folder's markdown for ``message`` (``None``: nothing received yet)."""
    if message is None:
        return "no report from the service's residual watch yet"
    lines = []
    if age_s > STALE_AFTER_S:
        lines.append(f"**stale: the last report is {age_s:.0f} s old**")
    finding = message.finding
    if finding is not None:
        still = "and still holds" if finding.holds else "(no longer firing)"
        lines.append(
            f"**Dependence found** {still}: joint {finding.joint}'s external torque in free "
            f"motion depends on `{finding.variable}` since {finding.since_s:.0f} s "
            f"(effect {100 * finding.effect_fraction:.1f} % of the joint's RMS torque in "
            f"free motion, "
            f"{1000 * finding.effect_nm:.1f} mN m, p = {finding.p_value:.1e})."
        )
        lines.append("")
        lines.append("Run next, on a recording of this session:")
        lines.append("")
        lines.append(f"    {message.command}")
    elif message.state == "baseline":
        lines.append(
            f"Collecting the baseline of free motion ({message.stream_s:.0f} s of stream)."
        )
    else:
        lines.append(
            f"Watching: no dependence in free motion ({message.stream_s:.0f} s of stream)."
        )
    if message.checks:
        lines.append("")
        lines.append("| joint | rows | variable | effect % RMS | p | firing |")
        lines.append("|---:|---:|---|---:|---:|---:|")
        for c in message.checks:
            effect = "-" if math.isnan(c.effect_fraction) else f"{100 * c.effect_fraction:.1f}"
            p = "-" if math.isnan(c.p_value) else f"{c.p_value:.0e}"
            lines.append(
                f"| {c.joint} | {c.rows} | {c.variable or '-'} | {effect} | {p} | {c.consecutive} |"
            )
    return "\n".join(lines)
