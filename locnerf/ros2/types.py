"""ROS 2 message types: the rosbags type store, DDS type names, RIHS01 hashes and CDR.

The type store holds rosbags' Kilted definitions (those used here are identical in Jazzy; a test
pins that their hashes agree) with two changes:

* ``service_msgs/msg/ServiceEventInfo.client_gid`` is ``uint8[16]``: its .msg says ``char[16]``,
  and a ROS 2 .msg ``char`` is an alias of ``uint8``, which is how rosidl hashes it; rosbags keeps
  it as ``char`` and then hashes every service wrongly.
* ``std_srvs/srv/Empty`` (not in rosbags' stores) is registered as rosidl describes a service: a
  struct of ``request_message``, ``response_message`` and ``event_message`` whose event message is
  ``info``, ``request[<=1]``, ``response[<=1]`` (REP-2016), so rosbags can hash it.
* ``nav2_msgs/msg/Particle`` and ``nav2_msgs/msg/ParticleCloud`` (not in rosbags' stores) are
  registered from their .msg text, so rosbags serialises and hashes them as any other type.
"""

from __future__ import annotations

from functools import cache

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from locnerf.messages.codec import DecodeError

EMPTY_SERVICE = "std_srvs/srv/Empty"

ODOMETRY = "nav_msgs/msg/Odometry"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


SERVICE_EVENT_INFO = "service_msgs/msg/ServiceEventInfo"

NAV2_PARTICLE = "nav2_msgs/msg/Particle"
NAV2_PARTICLE_CLOUD = "nav2_msgs/msg/ParticleCloud"
NAV2_DEFINITIONS = {
    NAV2_PARTICLE: "geometry_msgs/Pose pose\nfloat64 weight\n",
    NAV2_PARTICLE_CLOUD: "std_msgs/Header header\nParticle[] particles\n",
}
"""nav2_msgs' .msg text (navigation2's nav2_msgs/msg/Particle.msg, ParticleCloud.msg, comments left out):
what nav2_amcl publishes on ``particle_cloud`` and RViz's nav2 particle cloud display reads."""


def service_definitions(service: str, request_fields: list, response_fields: list) -> dict:
    """rosbags definitions of a service ``pkg/srv/Name``: its request, response and event messages
    and the service itself, as rosidl's type description has them (fields in rosbags' form)."""
    request, response, event = f"{service}_Request", f"{service}_Response", f"{service}_Event"
    nested = lambda name: (Nodetype.NAME, name)
    bounded_one = lambda name: (Nodetype.SEQUENCE, ((Nodetype.NAME, name), 1))
    return {
        request: ([], request_fields),
        response: ([], response_fields),
        event: ([], [("info", nested(SERVICE_EVENT_INFO)), ("request", bounded_one(request)), ("response", bounded_one(response))]),
        service: ([], [("request_message", nested(request)), ("response_message", nested(response)), ("event_message", nested(event))]),
    }


def build_typestore() -> Typestore:
    """A new type store: Kilted's definitions, ServiceEventInfo corrected, std_srvs/srv/Empty and nav2_msgs' particle cloud added."""
    definitions = dict(get_typestore(Stores.ROS2_KILTED).fielddefs)
    constants, fields = definitions[SERVICE_EVENT_INFO]
    uint8_gid = (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), 16))
    definitions[SERVICE_EVENT_INFO] = (constants, [(name, uint8_gid if name == "client_gid" else desc) for name, desc in fields])
    store = get_typestore(Stores.EMPTY)
    store.register({name: value for name, value in definitions.items() if name not in store.fielddefs})
    store.register(service_definitions(EMPTY_SERVICE, [], []))
    for name, text in NAV2_DEFINITIONS.items():
        store.register(get_types_from_msg(text, name))
    return store


@cache
def typestore() -> Typestore:
    """The shared type store (:func:`build_typestore`)."""
    return build_typestore()


def dds_type_name(ros_type: str) -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_``, the type name rmw_zenoh puts in keys and tokens.

    Raises:
        ValueError: a name not of the form package/(msg|srv)/Name.
    """
    parts = ros_type.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv") or not all(parts):
        raise ValueError(f"ROS type {ros_type!r}: expected <package>/msg/<Name> or <package>/srv/<Name>")
    return f"{parts[0]}::{parts[1]}::dds_::{parts[2]}_"


@cache
def type_hash(ros_type: str) -> str:
    """The REP-2016 type hash ``RIHS01_<64 hex>`` of a message or service type (rosbags computes it)."""
    if ros_type not in typestore().fielddefs:
        raise ValueError(f"ROS type {ros_type!r} is not in the type store")
    return typestore().hash_rihs01(ros_type)


def message_class(ros_type: str) -> type:
    """The rosbags dataclass of ``ros_type`` (e.g. ``typestore().types['nav_msgs/msg/Odometry']``)."""
    return typestore().types[ros_type]


def serialize(message: object, ros_type: str) -> bytes:
    """A rosbags message -> CDR little-endian bytes with the 4-byte encapsulation header."""
    return bytes(typestore().serialize_cdr(message, ros_type))


def deserialize(payload: bytes, ros_type: str) -> object:
    """CDR bytes -> a rosbags message of ``ros_type``.

    Raises:
        DecodeError: ``ros2_cdr`` for a payload that is not a CDR ``ros_type``.
    """
    try:
        return typestore().deserialize_cdr(payload, ros_type)
    except Exception as error:  # noqa: BLE001 - rosbags' generated code runs on foreign bytes: nothing may escape to the filter thread
        raise DecodeError("ros2_cdr", f"{len(payload)} bytes are not a CDR {ros_type} ({type(error).__name__}: {error})") from None
