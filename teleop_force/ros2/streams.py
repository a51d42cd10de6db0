"""The project's ROS 2 topics received as the project's message values.

:func:`subscribe` declares, on a :class:`~teleop_force.ros2.node.Node`, the subscription(s)
of one topic kind of one device and hands ``on_message(message, attachment)`` every sample
decoded to the value of :mod:`teleop_force.transport.messages` it carries
(:class:`~teleop_force.transport.messages.JointState`, ``JointSetpoint``, ``ContactForce``,
``ForceEstimateMessage``, ``Status``, ``ServiceDiagnostics``), its ``seq`` the attachment's
sequence number modulo 2**32. An estimate is two messages with one header stamp (the
WrenchStamped on ``estimated_cf``, the EstimateDiagnostics on ``estimate_diagnostics``):
:class:`EstimateJoiner` pairs them and hands on the pair once both have arrived, with the
WrenchStamped's attachment.

A sample that does not decode, a JointState whose names are not the model's (empty names
are accepted), or the wrong joint count is handed to ``on_malformed(topic, error)`` and
dropped.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Final

from teleop_force.errors import MessageError
from teleop_force.ros2 import codec, fast_cdr, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.ros2.node import Node, Subscription
from teleop_force.transport import messages as m

#: ``on_message(message, attachment)``: a decoded sample and its rmw_zenoh attachment.
MessageCallback = Callable[[Any, Attachment], None]
#: ``on_malformed(topic, error)``: a dropped sample, by topic name.
MalformedCallback = Callable[[str, MessageError], None]

#: Estimate halves kept waiting for their other half, per half (oldest dropped first).
MAX_UNPAIRED: Final = 256
_SEQ_MASK: Final = 0xFFFF_FFFF


def check_joint_names(names: tuple[str, ...], expected: tuple[str, ...]) -> None:
    """Raise MessageError unless ``names`` is empty or ``expected`` (the model's names)."""
    if names and names != expected:
        hint = " (the driver's relative elbow)" if names == topics.DRIVER_JOINT_NAMES else ""
        raise MessageError(f"joint names {list(names)} are not the model's {list(expected)}{hint}")


def _joint_count(n: int, expected: int | None) -> None:
    if expected is not None and n != expected:
        raise MessageError(f"{n} joints, expected {expected}")


def decoder(topic: topics.Topic, n_joints: int | None = None) -> Callable[[bytes, int], Any]:
    """Return ``decode(payload, seq)`` for one topic kind (not the estimate: two messages).

    The project's own layouts (the model's names, the base frame) are read in one struct call
    (:mod:`~teleop_force.ros2.fast_cdr`); any other payload through rosbags, with the same
    checks: the two accept and refuse the same payloads.
    """
    names = None if n_joints is None else topics.model_joint_names(n_joints)
    fast_names = topics.model_joint_names(3 if n_joints is None else n_joints)
    fast_js = fast_cdr.JointStateLayout(fast_names)
    fast_setpoint = fast_cdr.JointStateLayout(fast_names, velocities=False, efforts=False)
    fast_wrench = fast_cdr.WrenchLayout(topics.BASE_FRAME)

    def joint_state(payload: bytes, seq: int) -> m.JointState:
        fast = fast_js.unpack(payload)
        if fast is not None:
            return m.JointState(seq, *fast)
        msg, named = codec.decode_joint_state(payload, seq)
        if names is not None:  # the names first: they say whose coordinates these are
            check_joint_names(named.names, names)
        _joint_count(len(msg.q_rad), n_joints)
        return msg

    def setpoint(payload: bytes, seq: int) -> m.JointSetpoint:
        fast = fast_setpoint.unpack(payload)
        if fast is not None:
            return m.JointSetpoint(seq, fast[0], fast[1])
        msg, named = codec.decode_joint_setpoint(payload, seq)
        if names is not None:  # the names first: they say whose coordinates these are
            check_joint_names(named.names, names)
        _joint_count(len(msg.q_rad), n_joints)
        return msg

    def true_force(payload: bytes, seq: int) -> m.ContactForce:
        fast = fast_wrench.unpack(payload)
        if fast is not None:
            return m.ContactForce(seq, fast[0], fast[1])
        return codec.decode_contact_force(payload, seq)

    table: dict[str, Callable[[bytes, int], Any]] = {
        topics.MEASURED_JS.kind: joint_state,
        topics.SETPOINT_JS.kind: setpoint,
        topics.TRUE_CF.kind: true_force,
        topics.STATUS.kind: codec.decode_status,
        topics.SERVICE_DIAGNOSTICS.kind: codec.decode_service_diagnostics,
    }
    try:
        return table[topic.kind]
    except KeyError:
        raise MessageError(f"no single-message decoder for {topic.kind!r}") from None


class EstimateJoiner:
    """Pairs estimate halves by header stamp; see the module docstring.

    Thread-safe (the two halves arrive on different Zenoh threads). :attr:`unpaired` counts
    halves dropped because ``max_unpaired`` newer ones were waiting (a receiver that drains
    its queues in batches sets it above its batch).
    """

    def __init__(
        self,
        on_estimate: MessageCallback,
        n_joints: int | None = None,
        *,
        seq_mask: int = _SEQ_MASK,
        max_unpaired: int = MAX_UNPAIRED,
    ) -> None:
        """``on_estimate(ForceEstimateMessage, wrench attachment)`` gets each joined pair."""
        self._on_estimate = on_estimate
        self._n_joints = n_joints
        self._seq_mask = seq_mask
        self._max_unpaired = max(1, int(max_unpaired))
        # the project's own layout in one struct call; any other through rosbags
        names = topics.model_joint_names(3 if n_joints is None else n_joints)
        self._fast_wrench = fast_cdr.WrenchLayout(topics.BASE_FRAME)
        self._fast_diagnostics = fast_cdr.EstimateDiagnosticsLayout(names, topics.BASE_FRAME)
        self._names = names
        self._lock = threading.Lock()
        self._wrenches: OrderedDict[int, tuple[codec.Wrench, Attachment]] = OrderedDict()
        self._diagnostics: OrderedDict[int, codec.EstimateDiagnostics] = OrderedDict()
        self.unpaired = 0

    def on_wrench(self, payload: bytes, attachment: Attachment) -> None:
        """One WrenchStamped of ``estimated_cf`` (raises MessageError if it does not parse)."""
        fast = self._fast_wrench.unpack(payload)
        if fast is None:
            wrench = codec.decode_wrench(payload)
        else:
            wrench = codec.Wrench(fast[0], topics.BASE_FRAME, fast[1], fast[2])
        with self._lock:
            diagnostics = self._diagnostics.pop(wrench.t_ns, None)
            if diagnostics is None:
                self._keep(self._wrenches, wrench.t_ns, (wrench, attachment))
                return
        self._emit(wrench, attachment, diagnostics)

    def on_diagnostics(self, payload: bytes, attachment: Attachment) -> None:
        """One EstimateDiagnostics (raises MessageError if it does not parse)."""
        fast = self._fast_diagnostics.unpack(payload)
        if fast is None:
            diagnostics = codec.decode_estimate_diagnostics(payload)
        else:
            t_ns, source, (ext, coverage, motor, model), on_ground = fast
            diagnostics = codec.EstimateDiagnostics(
                t_ns, topics.BASE_FRAME, source, self._names, ext, coverage, on_ground, motor,
                model,
            )  # fmt: skip
        _joint_count(len(diagnostics.tau_ext_nm), self._n_joints)
        with self._lock:
            pair = self._wrenches.pop(diagnostics.t_ns, None)
            if pair is None:
                self._keep(self._diagnostics, diagnostics.t_ns, diagnostics)
                return
        self._emit(pair[0], pair[1], diagnostics)

    def _keep(self, waiting: OrderedDict[int, Any], t_ns: int, value: Any) -> None:
        waiting[t_ns] = value
        while len(waiting) > self._max_unpaired:
            waiting.popitem(last=False)
            self.unpaired += 1

    def _emit(
        self, wrench: codec.Wrench, attachment: Attachment, diagnostics: codec.EstimateDiagnostics
    ) -> None:
        seq = attachment.sequence_number & self._seq_mask
        self._on_estimate(codec.estimate_message(seq, wrench, diagnostics), attachment)


def _guarded(
    topic: str,
    handle: Callable[[bytes, Attachment], None],
    on_malformed: MalformedCallback,
) -> Callable[[bytes, Attachment], None]:
    def callback(payload: bytes, attachment: Attachment) -> None:
        try:
            handle(payload, attachment)
        except MessageError as exc:
            on_malformed(topic, exc)

    return callback


def subscribe(
    node: Node,
    device: str,
    topic: topics.Topic,
    on_message: MessageCallback,
    on_malformed: MalformedCallback,
    *,
    n_joints: int | None = None,
    direct: bool = False,
    max_unpaired: int = MAX_UNPAIRED,
) -> list[Subscription]:
    """Subscribe to ``topic`` of ``device``; see the module docstring.

    ``topic`` is one of :data:`teleop_force.ros2.topics.ALL_TOPICS`; for
    :data:`~teleop_force.ros2.topics.ESTIMATED_CF` the estimate's two topics are subscribed
    to (two subscriptions returned; the halves arrive on different threads and may drift
    apart by up to ``max_unpaired`` before one is dropped). ``n_joints``: the joint count
    required (and the model's names for JointStates); ``None`` accepts any.
    """
    if topic == topics.ESTIMATE_DIAGNOSTICS:
        raise MessageError("subscribe to ESTIMATED_CF: it brings the diagnostics with it")
    if topic == topics.ESTIMATED_CF:
        joiner = EstimateJoiner(on_message, n_joints, max_unpaired=max_unpaired)
        halves = (
            (topics.ESTIMATED_CF, joiner.on_wrench),
            (topics.ESTIMATE_DIAGNOSTICS, joiner.on_diagnostics),
        )
        out = []
        for half, take in halves:
            name = topics.topic_name(device, half)
            out.append(
                node.subscription(
                    name, half.ros_type, _guarded(name, take, on_malformed), direct=direct
                )
            )
        return out
    decode = decoder(topic, n_joints)
    name = topics.topic_name(device, topic)

    def handle(payload: bytes, attachment: Attachment) -> None:
        on_message(decode(payload, attachment.sequence_number & _SEQ_MASK), attachment)

    return [
        node.subscription(name, topic.ros_type, _guarded(name, handle, on_malformed), direct=direct)
    ]
