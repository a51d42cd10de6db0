"""Print the generated tables of docs/wire_format.md: keys, type hashes, tokens, byte examples.

Run from the repository root and paste the output into the page::

    uv run python docs/wire_format_tables.py

``tests/ros2/test_wire_format_doc.py`` checks that every line printed here is in the page.
"""

from __future__ import annotations

from teleop_force.ros2 import codec, graph, interfaces, topics
from teleop_force.ros2.attachment import Attachment
from teleop_force.transport import keys
from teleop_force.transport import messages as m

#: The demo's devices: which topics each one's processes publish.
DEMO_TOPICS = (
    ("slave", topics.MEASURED_JS),
    ("slave", topics.TRUE_CF),
    ("slave", topics.STATUS),
    ("slave", topics.ESTIMATED_CF),
    ("slave", topics.ESTIMATE_DIAGNOSTICS),
    ("slave", topics.SERVICE_DIAGNOSTICS),
    ("master", topics.MEASURED_JS),
    ("master", topics.SETPOINT_JS),
)
#: An example GID and attachment (the values are arbitrary).
EXAMPLE_GID = bytes(range(0xA0, 0xB0))
EXAMPLE_ATTACHMENT = Attachment(1, 1_764_158_400_123_456_789, EXAMPLE_GID)


def hash_table() -> list[str]:
    """Return the RIHS01 hash of every published type."""
    lines = ["| type | CDR type name (key chunk) | RIHS01 hash |", "|---|---|---|"]
    for ros_type in interfaces.PUBLISHED_TYPES:
        lines.append(
            f"| `{ros_type}` | `{graph.dds_type_name(ros_type)}` | "
            f"`{interfaces.type_hash(ros_type)}` |"
        )
    return lines


def data_key_table() -> list[str]:
    """Return the demo's data keys in domain 0."""
    lines = ["| topic | data key (domain 0) |", "|---|---|"]
    for device, topic in DEMO_TOPICS:
        lines.append(
            f"| `{topics.topic_name(device, topic)}` | `{topics.data_key(device, topic, 0)}` |"
        )
    return lines


def subscription_keys() -> list[str]:
    """Return the keys a subscriber declares: one device, every device."""
    return [
        topics.subscription_key("slave", topics.ESTIMATED_CF, 0),
        topics.subscription_key(None, topics.ESTIMATED_CF, 0),
    ]


def service_tokens() -> list[str]:
    """Return the service's node, publisher and subscription tokens (zid shown as ``<zid>``)."""
    zid, name = "<zid>", "teleop_force_service"
    node = graph.Entity(0, zid, "0", "0", graph.EntityKind.NODE, "/", name)
    lines = [node.token_key]
    entities = (
        (graph.EntityKind.PUBLISHER, topics.ESTIMATED_CF),
        (graph.EntityKind.PUBLISHER, topics.ESTIMATE_DIAGNOSTICS),
        (graph.EntityKind.SUBSCRIPTION, topics.MEASURED_JS),
    )
    for entity_id, (kind, topic) in enumerate(entities, start=1):
        info = graph.TopicInfo(
            topics.topic_name("slave", topic),
            graph.dds_type_name(topic.ros_type),
            interfaces.type_hash(topic.ros_type),
            graph.KEEP_ALL_RELIABLE,
        )
        entity = graph.Entity(0, zid, "0", str(entity_id), kind, "/", name, topic=info)
        lines.append(entity.token_key)
    return lines


def attachment_example() -> list[str]:
    """Return an attachment's 33 bytes in hex, 8 bytes a group."""
    raw = EXAMPLE_ATTACHMENT.encode()
    groups = [raw[0:8], raw[8:16], raw[16:17], raw[17:33]]
    return [" ".join(g.hex() for g in groups)]


def wrench_example() -> list[str]:
    """Return the CDR bytes of an estimate's WrenchStamped, frame ``base``."""
    t_ns = 1_764_158_400_123_456_789
    estimate = m.ForceEstimateMessage(
        1, t_ns, 1, (0.5, -1.25, 2.0), (0.0,) * 3, (True,) * 3, (1.0,) * 3, (0.0,) * 3, (0.0,) * 3
    )
    wrench, diagnostics = codec.encode_estimate(
        estimate, topics.OMNI_MODEL_JOINT_NAMES, topics.BASE_FRAME
    )
    frame_end = 16 + len(topics.BASE_FRAME) + 1
    force_at = 4 + -(-(frame_end - 4) // 8) * 8  # aligned to 8, counted from byte 4
    fields = [
        (0, 4, "encapsulation header"),
        (4, 8, "stamp.sec"),
        (8, 12, "stamp.nanosec"),
        (12, 16, "frame_id length"),
        (16, frame_end, "frame_id"),
        (frame_end, force_at, "padding"),
    ] + [
        (force_at + 8 * k, force_at + 8 * k + 8, name)
        for k, name in enumerate(
            ("force.x", "force.y", "force.z", "torque.x", "torque.y", "torque.z")
        )
    ]
    return [
        f"WrenchStamped {len(wrench)} bytes, EstimateDiagnostics {len(diagnostics)} bytes (n = 3)",
        *(f"{a:3d}  {wrench[a:b].hex(' '):23s}  {name}" for a, b, name in fields),
    ]


def joint_state_size() -> list[str]:
    """Return the size of the Omni's JointState and setpoint payloads."""
    js = m.JointState(1, 1_764_158_400_123_456_789, (0.0,) * 3, (0.0,) * 3, (0.0,) * 3)
    sp = m.JointSetpoint(1, 1_764_158_400_123_456_789, (0.0,) * 3)
    names = topics.OMNI_MODEL_JOINT_NAMES
    return [
        f"JointState {len(codec.encode_joint_state(js, names))} bytes, "
        f"setpoint {len(codec.encode_joint_setpoint(sp, names))} bytes (Omni names, frame_id '')"
    ]


def project_key_table() -> list[str]:
    """Return the project's own keys (JSON, control, liveliness), for device ``<device>``."""
    d = "DEVICE"
    rows = [
        (keys.service_model(d), "queryable, JSON"),
        (keys.service_stats(d), "queryable, JSON"),
        (keys.service_control(d), "queryable, JSON"),
        (keys.service_adapt(d), "subscriber, text `on` / `off`"),
        (keys.process_stats(d, "ROLE"), "queryable, JSON"),
        (keys.alive(d, "ROLE"), "liveliness token"),
    ]
    lines = ["| key | kind |", "|---|---|"]
    for key, kind in rows:
        shown = key.replace("DEVICE", "<device>").replace("ROLE", "<role>")
        lines.append(f"| `{shown}` | {kind} |")
    return lines


SECTIONS = {
    "hashes": hash_table,
    "data keys": data_key_table,
    "subscription keys": subscription_keys,
    "service tokens": service_tokens,
    "attachment": attachment_example,
    "wrench": wrench_example,
    "joint state": joint_state_size,
    "project keys": project_key_table,
}


def main() -> None:
    """Print every section."""
    for title, make in SECTIONS.items():
        print(f"## {title}\n")
        print("\n".join(make()))
        print()


if __name__ == "__main__":
    main()
