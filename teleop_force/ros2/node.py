"""A ROS 2 node on a Zenoh session, declared the way rmw_zenoh declares one.

:class:`Node` declares the node's liveliness token; :meth:`Node.publisher` and
:meth:`Node.subscription` declare a Zenoh publisher or subscriber on rmw_zenoh's data key and
the entity's token. Entity ids count from 0 per node context, as rmw_zenoh's context does
(the node takes the first). A publisher attaches rmw_zenoh's 33-byte attachment to every
sample (sequence number from 1, source time from the system clock, its GID); a subscription
hears every hash of its type (``*`` in the hash chunk: Humble's ``TypeHashNotSupported`` too)
and hands its callback the payload and the parsed attachment. A sample without a valid
attachment is counted in :attr:`Subscription.malformed` and dropped.

Publishers declare reliable, keep-all QoS (Zenoh congestion control BLOCK, priority
REAL_TIME: the project's data streams), as rmw_zenoh maps that QoS; ``express`` unless the
caller says the message is followed by another in the same tick
(:mod:`teleop_force.transport.pubsub`).
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from teleop_force.errors import MessageError, TransportError
from teleop_force.ros2 import graph, interfaces
from teleop_force.ros2.attachment import Attachment
from teleop_force.transport import pubsub

#: What a subscription's callback receives: the CDR payload and the sample's attachment.
SampleCallback = Callable[[bytes, Attachment], Any]


class Publisher:
    """A publisher of one topic: ``publish(payload)`` puts it with the next attachment."""

    def __init__(self, node: Node, entity: graph.Entity, key: str, *, express: bool = True) -> None:
        """Declare the Zenoh publisher on ``key`` and the entity's liveliness token."""
        self.entity = entity
        self.key = key
        self.gid = entity.gid
        self._next_seq = 1
        self._lock = threading.Lock()
        self._publisher = pubsub.declare_data_publisher(node.session, key, express=express)
        self._token = pubsub.declare_token(node.session, entity.token_key)

    def publish(
        self,
        payload: bytes,
        source_timestamp_ns: int | None = None,
        *,
        sequence_number: int | None = None,
    ) -> Attachment:
        """Put ``payload`` with the next sequence number; return the attachment sent.

        ``sequence_number``: send this one instead (a replay keeps the recorded numbers);
        the count goes on after it.
        """
        with self._lock:
            seq = self._next_seq if sequence_number is None else sequence_number
            self._next_seq = seq + 1
        stamp = time.time_ns() if source_timestamp_ns is None else source_timestamp_ns
        attachment = Attachment(seq, stamp, self.gid)
        try:
            self._publisher.put(payload, attachment=attachment.encode())
        except zenoh.ZError as exc:
            raise TransportError(
                f"{self.key}: put failed: {pubsub.zenoh_error_text(exc)}"
            ) from None
        return attachment

    @property
    def zenoh_publisher(self) -> zenoh.Publisher:
        """The underlying Zenoh publisher (for ``matching_status``)."""
        return self._publisher

    def close(self) -> None:
        """Undeclare the token, then the publisher."""
        pubsub.undeclare_all(self._token, self._publisher)


class Subscription:
    """A subscription to one topic; see the module docstring."""

    def __init__(
        self,
        node: Node,
        entity: graph.Entity,
        key: str,
        callback: SampleCallback,
        *,
        direct: bool = False,
    ) -> None:
        """Declare the Zenoh subscriber on ``key`` and the entity's liveliness token."""
        self.entity = entity
        self.key = key
        self.malformed = 0
        self._callback = callback
        self._subscriber = pubsub.declare_subscriber(
            node.session, key, self._on_sample, direct=direct
        )
        self._token = pubsub.declare_token(node.session, entity.token_key)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        raw = sample.attachment
        try:
            if raw is None:
                raise MessageError("sample without rmw_zenoh's attachment")
            attachment = Attachment.decode(raw.to_bytes())
        except MessageError:
            self.malformed += 1
            return
        self._callback(sample.payload.to_bytes(), attachment)

    def close(self) -> None:
        """Undeclare the token, then the subscriber."""
        pubsub.undeclare_all(self._token, self._subscriber)


class QueueSubscription:
    """A subscription whose samples wait in a ring, taken with :meth:`try_recv` later.

    For receivers that want the messages but not at once (the demo's supervisor): no Python
    runs on Zenoh's receive thread. A full ring drops its oldest samples.
    """

    def __init__(self, node: Node, entity: graph.Entity, key: str, capacity: int) -> None:
        """Declare the ring-channel subscriber on ``key`` and the entity's liveliness token."""
        self.entity = entity
        self.key = key
        self.malformed = 0
        self._subscriber = pubsub.declare_queue_subscriber(
            node.session, key, capacity, drop_oldest=True
        )
        self._token = pubsub.declare_token(node.session, entity.token_key)

    def try_recv(self) -> tuple[bytes, Attachment] | None:
        """Return the oldest sample waiting, or None; samples without attachment are skipped."""
        while True:
            try:
                sample = self._subscriber.try_recv()
            except zenoh.ZError:  # undeclared meanwhile: nothing more to read
                return None
            if sample is None:
                return None
            raw = sample.attachment
            try:
                if raw is None:
                    raise MessageError("sample without rmw_zenoh's attachment")
                return sample.payload.to_bytes(), Attachment.decode(raw.to_bytes())
            except MessageError:
                self.malformed += 1

    def close(self) -> None:
        """Undeclare the token, then the subscriber."""
        pubsub.undeclare_all(self._token, self._subscriber)


class Node:
    """One ROS 2 node on ``session`` (one context per session, as in rmw_zenoh)."""

    def __init__(
        self,
        session: zenoh.Session,
        name: str,
        *,
        namespace: str = "/",
        domain_id: int | None = None,
        enclave: str = "/",
    ) -> None:
        """Declare the node's liveliness token (domain from ``ROS_DOMAIN_ID`` by default)."""
        self.session = session
        self.domain_id = graph.domain_id_from_env() if domain_id is None else domain_id
        try:
            self.zid = str(session.zid())
        except zenoh.ZError as exc:
            raise TransportError(f"no Zenoh session id: {pubsub.zenoh_error_text(exc)}") from None
        self._ids = itertools.count()
        node_id = str(next(self._ids))
        self.entity = graph.Entity(
            domain_id=self.domain_id,
            zid=self.zid,
            node_id=node_id,
            entity_id=node_id,
            kind=graph.EntityKind.NODE,
            namespace=namespace,
            node_name=name,
            enclave=enclave,
        )
        self._entities: list[Publisher | Subscription | QueueSubscription] = []
        self._token = pubsub.declare_token(session, self.entity.token_key)

    def _entity(
        self, kind: graph.EntityKind, topic: str, ros_type: str, qos: graph.Qos
    ) -> tuple[graph.Entity, graph.TopicInfo]:
        info = graph.TopicInfo(
            name=graph.fully_qualified_name(topic, self.entity.namespace),
            dds_type=graph.dds_type_name(ros_type),
            type_hash=interfaces.type_hash(ros_type),
            qos=qos,
        )
        entity = graph.Entity(
            domain_id=self.domain_id,
            zid=self.zid,
            node_id=self.entity.node_id,
            entity_id=str(next(self._ids)),
            kind=kind,
            namespace=self.entity.namespace,
            node_name=self.entity.node_name,
            enclave=self.entity.enclave,
            topic=info,
        )
        return entity, info

    def publisher(
        self,
        topic: str,
        ros_type: str,
        qos: graph.Qos = graph.KEEP_ALL_RELIABLE,
        *,
        express: bool = True,
    ) -> Publisher:
        """Declare a publisher of ``ros_type`` on ``topic`` (resolved in the node namespace).

        ``express=False``: its messages wait for the next express one of the session.
        """
        entity, info = self._entity(graph.EntityKind.PUBLISHER, topic, ros_type, qos)
        key = graph.topic_key(self.domain_id, info.name, ros_type, info.type_hash)
        publisher = Publisher(self, entity, key, express=express)
        self._entities.append(publisher)
        return publisher

    def subscription(
        self,
        topic: str,
        ros_type: str,
        callback: SampleCallback,
        *,
        qos: graph.Qos = graph.KEEP_ALL_RELIABLE,
        direct: bool = False,
    ) -> Subscription:
        """Declare a subscription to ``topic``, any type hash; see :class:`Subscription`."""
        entity, info = self._entity(graph.EntityKind.SUBSCRIPTION, topic, ros_type, qos)
        key = graph.topic_key_any_hash(self.domain_id, info.name, ros_type)
        subscription = Subscription(self, entity, key, callback, direct=direct)
        self._entities.append(subscription)
        return subscription

    def queue_subscription(
        self,
        topic: str,
        ros_type: str,
        capacity: int,
        *,
        qos: graph.Qos = graph.KEEP_ALL_RELIABLE,
    ) -> QueueSubscription:
        """Declare a ring-channel subscription to ``topic``; see :class:`QueueSubscription`."""
        entity, info = self._entity(graph.EntityKind.SUBSCRIPTION, topic, ros_type, qos)
        key = graph.topic_key_any_hash(self.domain_id, info.name, ros_type)
        subscription = QueueSubscription(self, entity, key, capacity)
        self._entities.append(subscription)
        return subscription

    def close(self) -> None:
        """Undeclare every entity, then the node's token."""
        for entity in reversed(self._entities):
            entity.close()
        self._entities.clear()
        pubsub.undeclare_all(self._token)
