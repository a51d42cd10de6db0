"""rmw_zenoh's names: topic data keys, liveliness tokens, QoS strings and entity GIDs.

Follows rmw_zenoh's ``docs/design.md`` and ``rmw_zenoh_cpp/src/detail/liveliness_utils.cpp``
(the current format, rmw_zenoh >= Jazzy 0.2.4 / Rolling 0.6.0 / Humble 0.1.2):

- a topic's data key is ``<domain_id>/<topic without leading or trailing />/<dds type>/<hash>``,
  e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...1a18``; Humble publishes
  ``TypeHashNotSupported`` in place of the hash, so :func:`topic_key_any_hash` subscribes
  with ``*`` in that chunk;
- a node's liveliness token is
  ``@ros2_lv/<domain>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node name>`` and a
  publisher's or subscription's appends ``<topic>/<dds type>/<hash>/<qos>``, each name
  *mangled* (every ``/`` replaced by ``%``);
- an entity's GID is XXH3-128 of its token key, its low 64 bits then its high 64 bits, each
  little-endian (``Entity::Entity``: two ``memcpy`` of ``low64`` and ``high64``).

:func:`parse_token` accepts exactly what rmw_zenoh's ``Entity::make(keyexpr)`` accepts, except
that numbers must be plain decimal digits (``strtoul`` also takes signs and spaces), and raises
:class:`~teleop_force.errors.MessageError` where rmw_zenoh logs an error and drops the token.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

import xxhash

from teleop_force.errors import ConfigurationError, MessageError

#: Hermetic admin space that prefixes every liveliness token.
ADMIN_SPACE: Final = "@ros2_lv"
#: The environment variable naming the ROS domain, and its default.
DOMAIN_ENV: Final = "ROS_DOMAIN_ID"
DEFAULT_DOMAIN_ID: Final = 0
#: Humble's rmw_zenoh puts this in the data key's hash chunk.
HASH_NOT_SUPPORTED: Final = "TypeHashNotSupported"
#: Length of a GID (``RMW_GID_STORAGE_SIZE`` in rmw_zenoh's builds).
GID_SIZE: Final = 16

_SLASH_REPLACEMENT: Final = "%"
_ROS_TYPE: Final = re.compile(r"^([A-Za-z0-9_]+)/(msg|srv)/([A-Za-z0-9_]+)$")
_DDS_TYPE: Final = re.compile(r"^([A-Za-z0-9_]+)::(msg|srv)::dds_::([A-Za-z0-9_]+)_$")
_DIGITS: Final = re.compile(r"^[0-9]+$")


class EntityKind(StrEnum):
    """The ``<entity_kind>`` chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


def domain_id_from_env(environ: Mapping[str, str] | None = None) -> int:
    """Return ``ROS_DOMAIN_ID`` as an int (0 when unset or empty); raise ConfigurationError."""
    env = os.environ if environ is None else environ
    text = env.get(DOMAIN_ENV, "").strip()
    if not text:
        return DEFAULT_DOMAIN_ID
    if not _DIGITS.match(text):
        raise ConfigurationError(f"{DOMAIN_ENV}={text!r} is not a non-negative integer")
    return int(text)


def mangle_name(name: str) -> str:
    """Return ``name`` with every ``/`` replaced by ``%`` (rmw_zenoh's ``mangle_name``)."""
    return name.replace("/", _SLASH_REPLACEMENT)


def demangle_name(name: str) -> str:
    """Return ``name`` with every ``%`` replaced by ``/`` (rmw_zenoh's ``demangle_name``)."""
    return name.replace(_SLASH_REPLACEMENT, "/")


def dds_type_name(ros_type: str) -> str:
    """Return the CDR type name of ``pkg/msg/Type``: ``pkg::msg::dds_::Type_``."""
    match = _ROS_TYPE.match(ros_type)
    if match is None:
        raise ConfigurationError(f"type name {ros_type!r} is not of the form pkg/msg/Type")
    package, kind, name = match.groups()
    return f"{package}::{kind}::dds_::{name}_"


def ros_type_name(dds_type: str) -> str:
    """Return ``pkg/msg/Type`` for ``pkg::msg::dds_::Type_``; raise MessageError otherwise."""
    match = _DDS_TYPE.match(dds_type)
    if match is None:
        raise MessageError(f"type name {dds_type!r} is not of the form pkg::msg::dds_::Type_")
    package, kind, name = match.groups()
    return f"{package}/{kind}/{name}"


def fully_qualified_name(topic: str, namespace: str = "/") -> str:
    """Return ``topic`` resolved in ``namespace`` (``"estimated_cf"`` -> ``"/estimated_cf"``)."""
    if not topic or topic.strip("/") == "":
        raise ConfigurationError(f"topic name {topic!r} is empty")
    if topic.startswith("/"):
        return topic.rstrip("/")
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic.rstrip('/')}"


def _strip_slashes(name: str) -> str:
    # rmw_zenoh's strip_slashes: at most one leading and one trailing slash.
    start = 1 if name.startswith("/") else 0
    end = len(name) - 1 if name.endswith("/") else len(name)
    return name[start:end]


def topic_key(domain_id: int, topic: str, ros_type: str, type_hash: str) -> str:
    """Return the data key of ``topic`` (``TopicInfo::TopicInfo``)."""
    return f"{domain_id}/{_strip_slashes(topic)}/{dds_type_name(ros_type)}/{type_hash}"


def parse_topic_key(key: str) -> tuple[str, str]:
    """Return a data key's ``(topic, ros_type)``; raise MessageError if it is not one.

    ``0/slave/estimated_cf/geometry_msgs::msg::dds_::WrenchStamped_/RIHS01_...`` gives
    ``("/slave/estimated_cf", "geometry_msgs/msg/WrenchStamped")``.
    """
    chunks = key.split("/")
    if len(chunks) < 4 or not _DIGITS.match(chunks[0]) or "" in chunks:
        raise MessageError("not a <domain>/<topic>/<type>/<hash> key", key=key)
    return "/" + "/".join(chunks[1:-2]), ros_type_name(chunks[-2])


def topic_key_any_hash(domain_id: int, topic: str, ros_type: str) -> str:
    """Return the data key of ``topic`` with ``*`` as its hash: hears Humble and later."""
    return topic_key(domain_id, topic, ros_type, "*")


# --------------------------------------------------------------------------- QoS

#: rmw's enum values (``rmw/types.h``) that rmw_zenoh's token parser maps.
RELIABILITY_RELIABLE: Final = 1
RELIABILITY_BEST_EFFORT: Final = 2
DURABILITY_TRANSIENT_LOCAL: Final = 1
DURABILITY_VOLATILE: Final = 2
HISTORY_KEEP_LAST: Final = 1
HISTORY_KEEP_ALL: Final = 2
LIVELINESS_AUTOMATIC: Final = 1
_RELIABILITIES: Final = frozenset({0, 1, 2, 3})
_DURABILITIES: Final = frozenset({0, 1, 2, 3})
_HISTORIES: Final = frozenset({0, 1, 2, 3})
_LIVELINESSES: Final = frozenset({0, 1, 3, 4, 5})
#: ``RMW_DURATION_INFINITE`` as (sec, nsec).
DURATION_INFINITE: Final = (9_223_372_036, 854_775_807)


@dataclass(frozen=True, slots=True)
class Qos:
    """A QoS profile as rmw_zenoh encodes it in tokens; the defaults are rmw_zenoh's defaults.

    Durations are ``(sec, nsec)``. rmw_zenoh's default: reliable, volatile, keep last 42,
    infinite deadline, lifespan and lease, automatic liveliness.
    """

    reliability: int = RELIABILITY_RELIABLE
    durability: int = DURABILITY_VOLATILE
    history: int = HISTORY_KEEP_LAST
    depth: int = 42
    deadline: tuple[int, int] = DURATION_INFINITE
    lifespan: tuple[int, int] = DURATION_INFINITE
    liveliness: int = LIVELINESS_AUTOMATIC
    liveliness_lease_duration: tuple[int, int] = DURATION_INFINITE

    def __post_init__(self) -> None:
        """Validate the enum values and counts; raise ConfigurationError."""
        for name, value, allowed in (
            ("reliability", self.reliability, _RELIABILITIES),
            ("durability", self.durability, _DURABILITIES),
            ("history", self.history, _HISTORIES),
            ("liveliness", self.liveliness, _LIVELINESSES),
        ):
            if value not in allowed:
                raise ConfigurationError(f"QoS {name} {value!r} is not one of {sorted(allowed)}")
        numbers = (self.depth, *self.deadline, *self.lifespan, *self.liveliness_lease_duration)
        if any(not isinstance(x, int) or x < 0 for x in numbers):
            raise ConfigurationError(f"QoS depth and durations must be non-negative ints: {self}")

    def to_keyexpr(self) -> str:
        """Return rmw_zenoh's ``qos_to_keyexpr``: defaults left empty, ``:`` and ``,`` between."""
        d = Qos()

        def part(value: int, default: int) -> str:
            return "" if value == default else str(value)

        return (
            f"{part(self.reliability, d.reliability)}:"
            f"{part(self.durability, d.durability)}:"
            f"{part(self.history, d.history)},{part(self.depth, d.depth)}:"
            f"{part(self.deadline[0], d.deadline[0])},{part(self.deadline[1], d.deadline[1])}:"
            f"{part(self.lifespan[0], d.lifespan[0])},{part(self.lifespan[1], d.lifespan[1])}:"
            f"{part(self.liveliness, d.liveliness)},"
            f"{part(self.liveliness_lease_duration[0], d.liveliness_lease_duration[0])},"
            f"{part(self.liveliness_lease_duration[1], d.liveliness_lease_duration[1])}"
        )

    @classmethod
    def from_keyexpr(cls, text: str) -> Qos:
        """Parse :meth:`to_keyexpr`'s form as ``keyexpr_to_qos`` does; raise MessageError."""
        parts = text.split(":")
        sub = [p.split(",") for p in parts]
        if len(parts) < 6 or any(len(sub[i]) < 2 for i in (2, 3, 4)) or len(sub[5]) < 3:
            raise MessageError(f"QoS {text!r} does not have rmw_zenoh's 6 fields")
        d = cls()

        def number(value: str, default: int) -> int:
            if value == "":
                return default
            if not _DIGITS.match(value):
                raise MessageError(f"QoS {text!r}: {value!r} is not a number")
            return int(value)

        try:
            return cls(
                reliability=number(parts[0], d.reliability),
                durability=number(parts[1], d.durability),
                history=number(sub[2][0], d.history),
                depth=number(sub[2][1], d.depth),
                deadline=(number(sub[3][0], d.deadline[0]), number(sub[3][1], d.deadline[1])),
                lifespan=(number(sub[4][0], d.lifespan[0]), number(sub[4][1], d.lifespan[1])),
                liveliness=number(sub[5][0], d.liveliness),
                liveliness_lease_duration=(
                    number(sub[5][1], d.liveliness_lease_duration[0]),
                    number(sub[5][2], d.liveliness_lease_duration[1]),
                ),
            )
        except ConfigurationError as exc:
            raise MessageError(f"QoS {text!r}: {exc}") from None


#: What the project's publishers and subscribers declare: reliable, and every sample kept
#: (a full queue blocks the publisher, Zenoh's congestion control BLOCK), as rmw_zenoh maps it.
KEEP_ALL_RELIABLE: Final = Qos(history=HISTORY_KEEP_ALL)


# --------------------------------------------------------------------------- entities


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """The topic part of a publisher's or subscription's token.

    Attributes:
        name: Fully qualified topic name, e.g. ``/slave/estimated_cf``.
        dds_type: The CDR type name, e.g. ``geometry_msgs::msg::dds_::WrenchStamped_``.
        type_hash: ``RIHS01_<64 hex digits>`` (or Humble's ``TypeHashNotSupported``).
        qos: The entity's QoS.

    """

    name: str
    dds_type: str
    type_hash: str
    qos: Qos = field(default_factory=Qos)

    @property
    def ros_type(self) -> str:
        """The type as ``pkg/msg/Type``."""
        return ros_type_name(self.dds_type)


@dataclass(frozen=True, slots=True)
class Entity:
    """A node, publisher, subscription, service or client in rmw_zenoh's graph.

    Attributes:
        domain_id: The ROS domain.
        zid: The Zenoh session id as Zenoh prints it (32 hex digits at most).
        node_id: The node's id within its context (decimal string).
        entity_id: The entity's id within the context; equal to ``node_id`` for a node.
        kind: Node, publisher, subscription...
        namespace: The node's namespace, ``/`` for none.
        node_name: The node's name.
        enclave: The SROS enclave, ``/`` for none.
        topic: The topic of a non-node entity, ``None`` for a node.

    """

    domain_id: int
    zid: str
    node_id: str
    entity_id: str
    kind: EntityKind
    namespace: str
    node_name: str
    enclave: str = "/"
    topic: TopicInfo | None = None

    def __post_init__(self) -> None:
        """Check what rmw_zenoh's ``Entity::make`` checks; raise ConfigurationError."""
        if not self.entity_id or not self.node_id or not self.zid:
            raise ConfigurationError("an entity needs a zid, a node id and an entity id")
        if not self.namespace or not self.node_name:
            raise ConfigurationError("an entity needs a namespace (/ for none) and a node name")
        if (self.kind is EntityKind.NODE) != (self.topic is None):
            raise ConfigurationError("a node has no topic, every other entity has one")

    @property
    def token_key(self) -> str:
        """The liveliness token's key expression, exactly as rmw_zenoh builds it."""
        parts = [
            ADMIN_SPACE,
            str(self.domain_id),
            self.zid,
            self.node_id,
            self.entity_id,
            self.kind.value,
            mangle_name(self.enclave),
            mangle_name(self.namespace),
            mangle_name(self.node_name),
        ]
        if self.topic is not None:
            parts += [
                mangle_name(self.topic.name),
                mangle_name(self.topic.dds_type),
                mangle_name(self.topic.type_hash),
                self.topic.qos.to_keyexpr(),
            ]
        return "/".join(parts)

    @property
    def gid(self) -> bytes:
        """The 16-byte GID: XXH3-128 of :attr:`token_key`, low then high 64 bits, little-endian."""
        return entity_gid(self.token_key)


def entity_gid(token_key: str) -> bytes:
    """Return rmw_zenoh's GID of the entity whose liveliness token is ``token_key``."""
    digest = xxhash.xxh3_128_intdigest(token_key.encode("utf-8"))
    return digest.to_bytes(GID_SIZE, "little")


_INDEX_NODE_NAME: Final = 8
_INDEX_QOS: Final = 12


def parse_token(key: str) -> Entity:
    """Parse a liveliness token key as rmw_zenoh's ``Entity::make(keyexpr)``; raise MessageError."""
    parts = key.split("/")
    if len(parts) < _INDEX_NODE_NAME + 1:
        raise MessageError(f"{len(parts)}/{_INDEX_NODE_NAME + 1} parts", key=key)
    if any(p == "" for p in parts):
        raise MessageError("empty parts", key=key)
    if parts[0] != ADMIN_SPACE:
        raise MessageError(f"admin space {parts[0]!r} is not {ADMIN_SPACE!r}", key=key)
    try:
        kind = EntityKind(parts[5])
    except ValueError:
        raise MessageError(f"invalid entity {parts[5]!r}", key=key) from None
    if not _DIGITS.match(parts[1]):
        raise MessageError(f"domain id {parts[1]!r} is not a number", key=key)
    topic = None
    if kind is not EntityKind.NODE:
        if len(parts) < _INDEX_QOS + 1:
            raise MessageError("a non-node token without its topic, type, hash and QoS", key=key)
        topic = TopicInfo(
            name=demangle_name(parts[9]),
            dds_type=demangle_name(parts[10]),
            type_hash=demangle_name(parts[11]),
            qos=Qos.from_keyexpr(parts[12]),
        )
    try:
        return Entity(
            domain_id=int(parts[1]),
            zid=parts[2],
            node_id=parts[3],
            entity_id=parts[4],
            kind=kind,
            enclave=demangle_name(parts[6]),
            namespace=demangle_name(parts[7]),
            node_name=demangle_name(parts[8]),
            topic=topic,
        )
    except ConfigurationError as exc:
        raise MessageError(str(exc), key=key) from None
