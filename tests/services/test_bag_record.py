"""The recorder writes what the filter publishes on ROS 2 (amcl_pose, particle_cloud, /tf) and the
odometry it reads into an MCAP rosbag2, read back by a second, independent decoder: the mcap reader
with Foxglove's mcap_ros2 CDR decoder, using the schemas in the file (not rosbags). Every decoded
message equals the one the filter's bridge published, and its values are the filter's; evo reads
the pose trajectory from the bag."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from evo.tools.file_interface import read_bag_trajectory
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader
from ruamel.yaml import YAML

from locnerf.bags.writer import BagWriter
from locnerf.ros2.naming import data_key
from locnerf.ros2.types import deserialize
from locnerf_services.ros2.config import Ros2Config
from locnerf_services.ros2.recorder import Ros2Recorder, default_topics
from tests.services.test_ros2_bridge import T_BODY_CAM, setup
from tests.services.test_ros2_mcap import assert_same, pose_of, publish_initial_pose_and_odometry


def decoded_messages(bag) -> dict[str, list[tuple[int, object]]]:
    """Topic -> (log time ns, message decoded by mcap_ros2) of the bag's MCAP file."""
    (path,) = bag.glob("*.mcap")
    decoded: dict[str, list[tuple[int, object]]] = {}
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, value in reader.iter_decoded_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            decoded.setdefault(channel.topic, []).append((message.log_time, value))
    return decoded


def test_the_filters_outputs_and_its_odometry_decode_from_the_bag_with_mcap_ros2(tmp_path):
    _world, loop, bus, driver, publishers, _received = setup()
    config = Ros2Config(enabled=True)
    topics = default_topics(config)
    assert [name for name, _ in topics] == ["amcl_pose", "particle_cloud", "/tf", "odom", "camera/image_raw", "camera/camera_info"]
    published: dict[str, list[bytes]] = {}
    for name, ros_type in topics:
        topic = "/" + name.lstrip("/")
        bus.subscribe(data_key(0, topic, ros_type), lambda _key, payload, topic=topic: published.setdefault(topic, []).append(payload))
    with BagWriter(tmp_path / "bag") as bag:
        recorder = Ros2Recorder(bus, bag, topics)
        T_map_base, T_odom_base = publish_initial_pose_and_odometry(loop, driver, publishers)
        recorder.step(0.0)
        recorder.close()
    assert recorder.bad.total == 0 and recorder.inbox.dropped == 0
    assert set(published) == {"/amcl_pose", "/particle_cloud", "/tf", "/odom"}

    decoded = decoded_messages(tmp_path / "bag")
    types = {"/" + name.lstrip("/"): ros_type for name, ros_type in topics}
    assert {topic: len(found) for topic, found in decoded.items()} == {topic: len(found) for topic, found in published.items()}
    for topic, payloads in published.items():
        for payload, (_time, message) in zip(payloads, decoded[topic], strict=True):
            assert_same(deserialize(payload, types[topic]), message, topic)

    (_time, amcl) = decoded["/amcl_pose"][-1]
    assert (amcl.header.stamp.sec, amcl.header.stamp.nanosec, amcl.header.frame_id) == (10, 250_000_000, "map")
    assert torch.allclose(pose_of(amcl.pose.pose.position, amcl.pose.pose.orientation), T_map_base, atol=1e-3), "the base pose given in initialpose"
    (_time, cloud) = decoded["/particle_cloud"][-1]
    assert [p.weight for p in cloud.particles] == pytest.approx(loop.localizer.particles.weights.tolist(), abs=0)
    base_poses = loop.metric_particle_poses() @ torch.linalg.inv(T_BODY_CAM)
    assert [p.pose.position.z for p in cloud.particles] == pytest.approx(base_poses[:, 2, 3].tolist(), abs=1e-12)
    (_time, tf) = decoded["/tf"][-1]
    (transform,) = tf.transforms
    T_map_odom = pose_of(transform.transform.translation, transform.transform.rotation)
    assert torch.allclose(T_map_odom @ T_odom_base, pose_of(amcl.pose.pose.position, amcl.pose.pose.orientation), atol=1e-9)
    (_time, odometry) = decoded["/odom"][-1]
    assert torch.allclose(pose_of(odometry.pose.pose.position, odometry.pose.pose.orientation), T_odom_base, atol=1e-12)

    with Reader(tmp_path / "bag") as reader:  # a third reader: evo's, as a robot team would plot the run
        trajectory = read_bag_trajectory(reader, "/amcl_pose")
    assert np.allclose(trajectory.positions_xyz[-1], T_map_base[:3, 3].numpy(), atol=1e-3) and trajectory.timestamps[-1] == 10.25

    metadata = YAML(typ="safe").load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["storage_identifier"] == "mcap" and metadata["message_count"] == sum(len(found) for found in published.values())
