"""What the filter publishes on ROS 2, decoded by a second CDR implementation: mcap-ros2-support
(Foxglove's), not rosbags. The bridge's payloads for amcl_pose, particle_cloud and /tf are written,
as they are, into an MCAP file (ros2 profile, schemas in ros2msg from the .msg text of
common_interfaces and navigation2, written here by hand), read back with mcap_ros2's decoder, and
their values compared with what the filter holds."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory

from locnerf.geometry.quaternion import quaternion_to_matrix
from locnerf.geometry.se3 import make_pose
from locnerf.ros2.naming import data_key
from locnerf.ros2.types import deserialize
from tests.ros2 import messages
from tests.services.test_ros2_bridge import T_BODY_CAM, drain, pose, setup

SEPARATOR = "=" * 80
MSG = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance",
    "geometry_msgs/PoseWithCovarianceStamped": "std_msgs/Header header\nPoseWithCovariance pose",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\nTransform transform",
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms",
    "nav2_msgs/Particle": "geometry_msgs/Pose pose\nfloat64 weight",
    "nav2_msgs/ParticleCloud": "std_msgs/Header header\nParticle[] particles",
}
"""The .msg text of each type (comments left out), as ROS 2 ships it."""
DEPENDENCIES = {
    "geometry_msgs/PoseWithCovarianceStamped": (
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose",
        "geometry_msgs/Point",
        "geometry_msgs/Quaternion",
    ),
    "nav2_msgs/ParticleCloud": (
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "nav2_msgs/Particle",
        "geometry_msgs/Pose",
        "geometry_msgs/Point",
        "geometry_msgs/Quaternion",
    ),
    "tf2_msgs/TFMessage": (
        "geometry_msgs/TransformStamped",
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/Transform",
        "geometry_msgs/Vector3",
        "geometry_msgs/Quaternion",
    ),
}
TOPICS = {  # topic -> (our ROS type, schema name)
    "/amcl_pose": ("geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/PoseWithCovarianceStamped"),
    "/particle_cloud": ("nav2_msgs/msg/ParticleCloud", "nav2_msgs/ParticleCloud"),
    "/tf": ("tf2_msgs/msg/TFMessage", "tf2_msgs/TFMessage"),
}


def ros2msg(name: str) -> str:
    """A schema's ros2msg text: the type's .msg, then each dependency after a separator and ``MSG: <name>``."""
    return "\n".join([MSG[name], *(f"{SEPARATOR}\nMSG: {dependency}\n{MSG[dependency]}" for dependency in DEPENDENCIES[name])])


def round_trip(payloads: dict[str, list[bytes]]) -> dict[str, list[object]]:
    """Our CDR payloads by topic -> an MCAP file in memory -> mcap_ros2's decoded messages by topic."""
    buffer = io.BytesIO()
    writer = Writer(buffer)
    writer.start(profile="ros2", library="locnerf test")
    for topic, (_ros_type, schema) in TOPICS.items():
        schema_id = writer.register_schema(name=schema, encoding="ros2msg", data=ros2msg(schema).encode())
        channel = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema_id)
        for sequence, payload in enumerate(payloads[topic]):
            writer.add_message(channel_id=channel, log_time=sequence, publish_time=sequence, data=payload, sequence=sequence)
    writer.finish()
    buffer.seek(0)
    decoded: dict[str, list[object]] = {topic: [] for topic in TOPICS}
    for _schema, channel, _message, message in make_reader(buffer, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
        decoded[channel.topic].append(message)
    return decoded


def pose_of(position: object, orientation: object) -> torch.Tensor:
    """(4, 4) pose from decoded position (x, y, z) and quaternion (x, y, z, w) fields."""
    quaternion = torch.tensor([orientation.w, orientation.x, orientation.y, orientation.z], dtype=torch.float64)
    return make_pose(quaternion_to_matrix(quaternion), torch.tensor([position.x, position.y, position.z], dtype=torch.float64))


def assert_same(ours: object, theirs: object, path: str = "") -> None:
    """Every field of a rosbags message equals the one mcap_ros2 decoded, exactly."""
    if hasattr(ours, "__dataclass_fields__"):
        for name in ours.__dataclass_fields__:
            if name != "__msgtype__":
                assert_same(getattr(ours, name), getattr(theirs, name), f"{path}.{name}")
    elif isinstance(ours, (list, np.ndarray)):
        assert len(ours) == len(theirs), path
        for index, (item, other) in enumerate(zip(ours, theirs, strict=True)):
            assert_same(item, other, f"{path}[{index}]")
    else:
        assert ours == theirs, (path, ours, theirs)


def publish_initial_pose_and_odometry(loop, driver, publishers) -> tuple[torch.Tensor, torch.Tensor]:
    """Drive the bridge through one cycle of every output: an initial pose, an odometry message, and a particle cloud due.
    Returns the (4, 4) ``T_map_base`` given as the initial pose and the ``T_odom_base`` of the odometry."""
    T_map_base = pose([0.0, 0.0, 0.5], [0.3, -0.2, 0.1])
    covariance = np.diag([1e-8, 2e-8, 3e-8, 1e-10, 2e-10, 3e-10]).reshape(-1).tolist()
    publishers["initialpose"].publish(messages.initial_pose(10.0, T_map_base, covariance))
    drain(driver)
    T_odom_base = pose([0.0, 0.0, -0.2], [1.0, 2.0, 0.0])
    publishers["odom"].publish(messages.odometry(10.25, T_odom_base))
    drain(driver)
    loop._last_particles = -math.inf
    drain(driver, 2)
    return T_map_base, T_odom_base


def test_amcl_pose_particle_cloud_and_tf_decode_with_mcap_ros2_support():
    _world, loop, bus, driver, publishers, _received = setup()
    payloads: dict[str, list[bytes]] = {topic: [] for topic in TOPICS}
    for topic, (ros_type, _schema) in TOPICS.items():
        bus.subscribe(data_key(0, topic, ros_type), lambda _key, payload, topic=topic: payloads[topic].append(payload))
    T_map_base, T_odom_base = publish_initial_pose_and_odometry(loop, driver, publishers)
    assert all(payloads.values()), {topic: len(found) for topic, found in payloads.items()}

    decoded = round_trip(payloads)
    for topic, (ros_type, _schema) in TOPICS.items():
        assert len(decoded[topic]) == len(payloads[topic])
        for payload, message in zip(payloads[topic], decoded[topic], strict=True):
            assert_same(deserialize(payload, ros_type), message, topic)

    amcl = decoded["/amcl_pose"][-1]
    assert (amcl.header.stamp.sec, amcl.header.stamp.nanosec, amcl.header.frame_id) == (10, 250_000_000, "map")
    T_published = pose_of(amcl.pose.pose.position, amcl.pose.pose.orientation)
    assert torch.allclose(T_published, T_map_base, atol=1e-3), "the base pose given in initialpose"
    ros_covariance = np.reshape(amcl.pose.covariance, (6, 6))
    assert np.allclose(ros_covariance, ros_covariance.T) and np.all(np.diag(ros_covariance) > 0)

    cloud = decoded["/particle_cloud"][-1]
    assert cloud.header.frame_id == "map" and [p.weight for p in cloud.particles] == pytest.approx(loop.localizer.particles.weights.tolist())
    base_poses = loop.metric_particle_poses() @ torch.linalg.inv(T_BODY_CAM)
    assert [p.pose.position.x for p in cloud.particles] == pytest.approx(base_poses[:, 0, 3].tolist(), abs=1e-12)

    (transform,) = decoded["/tf"][-1].transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ("map", "odom")
    assert (transform.header.stamp.sec, transform.header.stamp.nanosec) == (11, 250_000_000), "stamp + transform_tolerance (1 s)"
    T_map_odom = pose_of(transform.transform.translation, transform.transform.rotation)
    assert torch.allclose(T_map_odom @ T_odom_base, T_published, atol=1e-9), "T_map_odom = T_map_base · T_odom_base⁻¹"
