"""The rmw_zenoh wire format against the values printed in rmw_zenoh's docs/design.md (Kilted).

Expected strings are copied from the design document's examples; they are not computed by the
code under test.
"""

from __future__ import annotations

import pytest
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype
from zenoh.ext import Int64, z_serialize

from locnerf.messages.codec import DecodeError
from locnerf.ros2.attachment import SIZE, Attachment
from locnerf.ros2.naming import (
    EntityKind,
    NodeIdentity,
    check_key,
    data_key,
    data_pattern,
    fully_qualified_name,
    mangle,
    normalise_namespace,
)
from locnerf.ros2.types import (
    build_typestore,
    dds_type_name,
    deserialize,
    message_class,
    serialize,
    service_definitions,
    type_hash,
)

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"  # design.md, chatter
TYPES_USED = (
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/CameraInfo",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/PoseArray",
    "tf2_msgs/msg/TFMessage",
)


def test_type_hash_and_dds_name_match_the_design_document():
    assert type_hash("std_msgs/msg/String") == STRING_HASH
    # As `ros2 topic info -v` prints it for /odom (public logs), not from design.md.
    assert type_hash("nav_msgs/msg/Odometry") == "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0"
    assert dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert dds_type_name("std_srvs/srv/Empty") == "std_srvs::srv::dds_::Empty_"
    with pytest.raises(ValueError, match="expected <package>/msg/<Name>"):
        dds_type_name("String")


@pytest.mark.parametrize("ros_type", TYPES_USED)
def test_hashes_of_the_types_used_agree_between_jazzy_and_kilted(ros_type):
    jazzy = get_typestore(Stores.ROS2_JAZZY).hash_rihs01(ros_type)
    assert type_hash(ros_type) == jazzy and len(jazzy) == len("RIHS01_") + 64


def test_data_keys_match_the_design_document():
    assert data_key(0, fully_qualified_name("chatter"), "std_msgs/msg/String") == f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    robot = fully_qualified_name("chatter", "/robot1")
    assert robot == "/robot1/chatter"
    assert data_key(0, robot, "std_msgs/msg/String") == f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert fully_qualified_name("/tf", "/robot1") == "/tf"
    assert data_pattern(3, "/amcl_pose") == "3/amcl_pose/*/*"
    with pytest.raises(ValueError, match="without"):
        fully_qualified_name("a*b")


def test_check_key_names_the_mismatch():
    key = data_key(0, "/odom", "nav_msgs/msg/Odometry")
    check_key(key, 0, "/odom", "nav_msgs/msg/Odometry")
    with pytest.raises(DecodeError) as error:
        check_key(key.rsplit("/", 1)[0] + "/RIHS01_" + "0" * 64, 0, "/odom", "nav_msgs/msg/Odometry")
    assert error.value.kind == "ros2_type_hash"
    with pytest.raises(DecodeError) as error:
        check_key(data_key(0, "/odom", "std_msgs/msg/String"), 0, "/odom", "nav_msgs/msg/Odometry")
    assert error.value.kind == "ros2_type_name"
    with pytest.raises(DecodeError) as error:
        check_key(key, 1, "/odom", "nav_msgs/msg/Odometry")
    assert error.value.kind == "ros2_key"


def test_liveliness_tokens_match_the_design_document_examples():
    listener = NodeIdentity(domain_id=2, session_id="aac3178e146ba6f1fc6e6a4085e77f21", node_name="listener")
    assert listener.node_token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    assert listener.entity_token(10, EntityKind.SUBSCRIPTION, "/chatter", "std_msgs/msg/String") == (
        f"@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
    )
    talker = NodeIdentity(domain_id=2, session_id="8b20917502ee955ac4476e0266340d5c", node_name="talker")
    assert talker.entity_token(10, EntityKind.PUBLISHER, "/chatter", "std_msgs/msg/String", qos="::,7:,:,:,,") == (
        f"@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
    )
    assert mangle("/robot1/cmd_vel") == "%robot1%cmd_vel" and mangle("") == "%"
    namespaced = NodeIdentity(domain_id=0, session_id="ab", node_name="locnerf", namespace="/robot1")
    assert namespaced.node_token() == "@ros2_lv/0/ab/0/0/NN/%/%robot1/locnerf"


def test_a_namespace_without_its_leading_slash_or_with_a_trailing_one_is_normalised():
    """``robot1`` and ``/robot1/`` name the namespace ``/robot1``: the token's mangled namespace is
    ``%robot1``, as for ``/robot1`` (``robot1`` gave ``robot1`` and ``/robot1/`` ``%robot1%``)."""
    for written in ("robot1", "/robot1/", "robot1/"):
        identity = NodeIdentity(domain_id=0, session_id="ab", node_name="locnerf", namespace=written)
        assert identity.namespace == "/robot1" and identity.node_token() == "@ros2_lv/0/ab/0/0/NN/%/%robot1/locnerf", written
    assert normalise_namespace("/") == normalise_namespace("") == ""
    assert NodeIdentity(domain_id=0, session_id="ab", node_name="n", namespace="a/b/").node_token().endswith("/%a%b/n")


def test_nav2_particle_cloud_is_registered_from_its_msg_text():
    """nav2_msgs/ParticleCloud = Header header, Particle[] particles; Particle = Pose pose, float64 weight
    (navigation2's .msg files); its key carries its DDS name and its own RIHS01 hash, not PoseArray's."""
    fields = build_typestore().fielddefs
    assert fields["nav2_msgs/msg/Particle"] == ([], [("pose", (Nodetype.NAME, "geometry_msgs/msg/Pose")), ("weight", (Nodetype.BASE, ("float64", 0)))])
    particles = (Nodetype.SEQUENCE, ((Nodetype.NAME, "nav2_msgs/msg/Particle"), 0))
    assert fields["nav2_msgs/msg/ParticleCloud"] == ([], [("header", (Nodetype.NAME, "std_msgs/msg/Header")), ("particles", particles)])
    key = data_key(0, "/particle_cloud", "nav2_msgs/msg/ParticleCloud")
    assert key.startswith("0/particle_cloud/nav2_msgs::msg::dds_::ParticleCloud_/RIHS01_") and len(key.rsplit("/", 1)[1]) == len(STRING_HASH)
    assert type_hash("nav2_msgs/msg/ParticleCloud") not in (type_hash("geometry_msgs/msg/PoseArray"), type_hash("nav2_msgs/msg/Particle"))


def test_attachment_layout_is_the_zenoh_ext_serialisation_of_two_int64_and_the_gid():
    gid = bytes(range(16))
    attachment = Attachment(sequence_number=7, source_timestamp_ns=1_700_000_000_123_456_789, gid=gid)
    data = attachment.encode()
    assert len(data) == SIZE == 33
    assert data == z_serialize((Int64(7), Int64(1_700_000_000_123_456_789), gid)).to_bytes()
    assert data[:8] == (7).to_bytes(8, "little") and data[16] == 0x10 and data[17:] == gid
    assert Attachment.decode(data) == attachment
    for bad in (None, data[:-1], data[:16] + b"\x0f" + gid):
        with pytest.raises(DecodeError) as error:
            Attachment.decode(bad)
        assert error.value.kind == "ros2_attachment"


def test_cdr_has_the_encapsulation_header_and_malformed_bytes_raise():
    payload = serialize(message_class("std_msgs/msg/String")(data="hi"), "std_msgs/msg/String")
    # CDR_LE header 00 01 00 00, uint32 length 3 (with the NUL), "hi\0": worked by hand.
    assert payload == b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00"
    assert deserialize(payload, "std_msgs/msg/String").data == "hi"
    for bad in (b"", b"\x00\x01\x00\x00\x01", b"\x07\x07\x00\x00" + payload[4:]):
        with pytest.raises(DecodeError) as error:
            deserialize(bad, "nav_msgs/msg/Odometry")
        assert error.value.kind == "ros2_cdr"


def test_service_hashes_follow_rosidl():
    """Oracles from outside this code: ServiceEventInfo's hash from rosidl-generated C code
    (``service_msgs__msg__ServiceEventInfo__EXPECTED_HASH``, first 27 bytes as printed there) and
    rcl_interfaces/srv/GetParameterTypes's hash from ros-z's tests, which state it was verified
    against rmw_zenoh_cpp. The same construction hashes std_srvs/srv/Empty."""
    assert type_hash("service_msgs/msg/ServiceEventInfo").startswith("RIHS01_41bcbbe07a75c9b52bc96bfd5c24d7f0fc0a08c0cb7921b3373c57")
    store = build_typestore()
    sequence = lambda base: (Nodetype.SEQUENCE, ((Nodetype.BASE, (base, 0)), 0))
    store.register(service_definitions("rcl_interfaces/srv/GetParameterTypes", [("names", sequence("string"))], [("types", sequence("uint8"))]))
    assert store.hash_rihs01("rcl_interfaces/srv/GetParameterTypes") == "RIHS01_da199c878688b3e530bdfe3ca8f74cb9fa0c303101e980a9e8f260e25e1c80ca"
    response = serialize(message_class("std_srvs/srv/Empty_Response")(), "std_srvs/srv/Empty_Response")
    assert response == b"\x00\x01\x00\x00\x00"  # one uint8 structure_needs_at_least_one_member
    assert type_hash("std_srvs/srv/Empty").startswith("RIHS01_")
