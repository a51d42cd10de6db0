"""rmw_zenoh's keys and tokens, checked against the examples of rmw_zenoh's docs/design.md."""

import pytest
import xxhash

from teleop_force.errors import ConfigurationError, MessageError
from teleop_force.ros2 import graph, interfaces
from teleop_force.ros2.graph import Entity, EntityKind, Qos, TopicInfo

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
STRING_DDS = "std_msgs::msg::dds_::String_"
ADD_TWO_INTS_DDS = "example_interfaces::srv::dds_::AddTwoInts_"

# docs/design.md, "Topic and Service name mapping to Zenoh key expressions"
DOC_KEYS = [
    ((0, "chatter", "std_msgs/msg/String", STRING_HASH),
     f"0/chatter/{STRING_DDS}/{STRING_HASH}"),
    ((0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH),
     f"0/robot1/chatter/{STRING_DDS}/{STRING_HASH}"),
    ((2, "add_two_ints", "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH),
     f"2/add_two_ints/{ADD_TWO_INTS_DDS}/{ADD_TWO_INTS_HASH}"),
]  # fmt: skip

# docs/design.md, "Graph Cache": the demo_nodes_cpp examples, byte for byte
LISTENER_ZID = "aac3178e146ba6f1fc6e6a4085e77f21"
DOC_NODE = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
DOC_SUB = (
    "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    f"{STRING_DDS}/{STRING_HASH}/::,10:,:,:,,"
)
DOC_PUB = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    f"{STRING_DDS}/{STRING_HASH}/::,7:,:,:,,"
)
DOC_SRV = (
    "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/"
    f"%add_two_ints/{ADD_TWO_INTS_DDS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,"
)
DOC_CLI = (
    "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/"
    f"%add_two_ints/{ADD_TWO_INTS_DDS}/{ADD_TWO_INTS_HASH}/::,10:,:,:,,"
)


@pytest.mark.parametrize(("args", "expected"), DOC_KEYS)
def test_data_keys_equal_the_design_doc(args, expected):
    domain, topic, ros_type, type_hash = args
    assert graph.topic_key(domain, topic, ros_type, type_hash) == expected


def test_the_string_hash_of_the_doc_is_the_one_rosbags_computes():
    # The doc's hash is rosidl's; the typestore computes it the same way.
    assert interfaces.typestore().hash_rihs01("std_msgs/msg/String") == STRING_HASH


def test_subscription_key_has_a_wildcard_hash_chunk():
    key = graph.topic_key_any_hash(0, "/slave/measured_js", "sensor_msgs/msg/JointState")
    assert key == "0/slave/measured_js/sensor_msgs::msg::dds_::JointState_/*"


def _entity(zid, kind, node, topic=None, dds=None, type_hash=None, depth=None):
    info = None
    if topic is not None:
        info = TopicInfo(topic, dds, type_hash, Qos(depth=depth))
    entity_id = "0" if kind is EntityKind.NODE else "10"
    return Entity(2, zid, "0", entity_id, kind, "/", node, topic=info)


def test_tokens_equal_the_design_doc():
    string = (STRING_DDS, STRING_HASH)
    add = (ADD_TWO_INTS_DDS, ADD_TWO_INTS_HASH)
    assert _entity(LISTENER_ZID, EntityKind.NODE, "listener").token_key == DOC_NODE
    sub = _entity(LISTENER_ZID, EntityKind.SUBSCRIPTION, "listener", "/chatter", *string, 10)
    assert sub.token_key == DOC_SUB
    pub = _entity("8b20917502ee955ac4476e0266340d5c", EntityKind.PUBLISHER, "talker",
                  "/chatter", *string, 7)  # fmt: skip
    assert pub.token_key == DOC_PUB
    srv = _entity("f9980ee0495eaafb3e38f0d19e2eae12", EntityKind.SERVICE,
                  "add_two_ints_server", "/add_two_ints", *add, 10)  # fmt: skip
    assert srv.token_key == DOC_SRV
    cli = _entity("e1dc8d1b45ae8717fce78689cc655685", EntityKind.CLIENT,
                  "add_two_ints_client", "/add_two_ints", *add, 10)  # fmt: skip
    assert cli.token_key == DOC_CLI


@pytest.mark.parametrize("token", [DOC_NODE, DOC_SUB, DOC_PUB, DOC_SRV, DOC_CLI])
def test_doc_tokens_parse_and_format_back(token):
    entity = graph.parse_token(token)
    assert entity.token_key == token
    assert entity.domain_id == 2
    assert entity.namespace == "/" and entity.enclave == "/"


def test_parsed_subscription_token_fields():
    entity = graph.parse_token(DOC_SUB)
    assert entity.kind is EntityKind.SUBSCRIPTION
    assert (entity.zid, entity.node_id, entity.entity_id) == (LISTENER_ZID, "0", "10")
    assert entity.node_name == "listener"
    assert entity.topic is not None
    assert entity.topic.name == "/chatter"
    assert entity.topic.ros_type == "std_msgs/msg/String"
    assert entity.topic.type_hash == STRING_HASH
    assert entity.topic.qos == Qos(depth=10)


@pytest.mark.parametrize(
    "token",
    [
        "@ros2_lv/2/aac3/0/0/NN/%/%",  # 8 parts: no node name
        "@ros2_lv/2/aac3/0/0/NN/%//listener",  # an empty part
        "@ros2_xx/2/aac3/0/0/NN/%/%/listener",  # admin space
        "@ros2_lv/2/aac3/0/0/XX/%/%/listener",  # entity kind
        "@ros2_lv/x/aac3/0/0/NN/%/%/listener",  # domain
        "@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter",  # no type, hash, QoS
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING_DDS}/{STRING_HASH}/::,7:,:,",
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING_DDS}/{STRING_HASH}/9::,:,:,:,,",
        f"@ros2_lv/2/aac3/0/10/MP/%/%/talker/%chatter/{STRING_DDS}/{STRING_HASH}/::,x:,:,:,,",
    ],
)
def test_tokens_rmw_zenoh_rejects_raise_message_error(token):
    with pytest.raises(MessageError):
        graph.parse_token(token)


def test_default_qos_is_all_empty_and_keep_all_is_history_2():
    assert Qos().to_keyexpr() == "::,:,:,:,,"
    assert graph.KEEP_ALL_RELIABLE.to_keyexpr() == "::2,:,:,:,,"
    best_effort = Qos(reliability=graph.RELIABILITY_BEST_EFFORT, depth=1, deadline=(1, 5))
    assert best_effort.to_keyexpr() == "2::,1:1,5:,:,,"
    assert Qos.from_keyexpr(best_effort.to_keyexpr()) == best_effort


def test_gid_is_xxh3_128_of_the_token_low_half_first():
    # XXH3-128 of "" is 99aa06d3014798d86001c324468d497f (xxHash's test vector):
    # low64 = 0x6001c324468d497f, written little-endian first, then high64.
    assert graph.entity_gid("") == bytes.fromhex("7f498d4624c30160d8984701d306aa99")
    token = DOC_PUB
    canonical = xxhash.xxh3_128_digest(token.encode())  # big-endian high64 | low64
    assert graph.entity_gid(token) == canonical[::-1]
    assert graph.parse_token(token).gid == graph.entity_gid(token)


def test_domain_from_environment():
    assert graph.domain_id_from_env({}) == 0
    assert graph.domain_id_from_env({"ROS_DOMAIN_ID": "42"}) == 42
    with pytest.raises(ConfigurationError):
        graph.domain_id_from_env({"ROS_DOMAIN_ID": "-1"})


def test_type_names_mangle_both_ways():
    assert (
        graph.dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"
    )
    assert (
        graph.ros_type_name("sensor_msgs::msg::dds_::JointState_") == "sensor_msgs/msg/JointState"
    )
    with pytest.raises(ConfigurationError):
        graph.dds_type_name("JointState")
    with pytest.raises(MessageError):
        graph.ros_type_name("JointState")
