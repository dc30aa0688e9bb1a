"""Bags through real processes on loopback Zenoh: ``locnerf run ingest`` replays a bag (source
``rosbag``, a bad image in the middle counted in its status and skipped, the replay to its end), and
``locnerf record`` writes ROS 2 topics published on the session into an MCAP bag that mcap_ros2 decodes."""

from __future__ import annotations

import signal
import time

import numpy as np
import torch

from locnerf.bags.writer import BagWriter, EventWriter
from locnerf.messages import keys
from locnerf.messages.codec import decode, decode_rgbd
from locnerf.messages.schemas import Odometry, ServiceStatus
from locnerf.messages.stamps import nanoseconds_from_seconds
from locnerf.ros2 import convert
from locnerf.ros2 import messages as build
from locnerf.ros2.types import IMAGE, NAV2_PARTICLE, NAV2_PARTICLE_CLOUD, message_class
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.sensor_ingest.__main__ import IngestConfig
from locnerf_services.supervisor import write_config
from tests.bags.synthetic import sensor_stream
from tests.integration.conftest import ROBOT, wait_for
from tests.services.test_bag_record import decoded_messages
from tests.services.test_ros2_mcap import pose_of


def test_the_ingest_replays_a_bag_and_counts_a_bad_image(hub, tmp_path):
    stack, observer, bus = hub
    events = sensor_stream(seed=8, ticks=10, image_every=3)
    with BagWriter(tmp_path / "bag") as bag:
        writer = EventWriter(bag)
        for index, event in enumerate(events):
            writer.write(event)
            if index == 5:  # between the first and second image: an encoding the node does not read
                bag.write(
                    "/camera/image_raw",
                    IMAGE,
                    round(event.stamp * 1e9),
                    build.image_message(round(event.stamp * 1e9), np.zeros((2, 2), np.uint16), "bayer_rggb16", "camera"),
                )
    received: dict[str, list[bytes]] = {"odometry": [], "image": [], "status": []}
    bus.subscribe(keys.key(ROBOT, keys.ODOMETRY), lambda _k, payload: received["odometry"].append(payload))
    bus.subscribe(keys.key(ROBOT, keys.IMAGE), lambda _k, payload: received["image"].append(payload))
    bus.subscribe(keys.key(ROBOT, keys.INGEST_STATUS, ingest_id="bags"), lambda _k, payload: received["status"].append(payload))
    config = IngestConfig(robot_id=ROBOT, ingest_id="bags", source="rosbag", rosbag={"path": str(tmp_path / "bag")}, speed=4.0, prefetch_events=0)
    process = stack.start("ingest", "run", "ingest", "--config", str(write_config(tmp_path / "ingest.toml", config)))
    wait_for(lambda: process.poll() is not None, 60.0, "the ingest to replay the bag and exit", stack)
    assert process.returncode == 0, stack.log_tail()
    time.sleep(0.5)

    odometry = [decode(payload, Odometry) for payload in received["odometry"]]
    truth = [event for event in events if type(event).__name__ == "OdometryEvent"]
    assert [message.stamp_ns for message in odometry] == [nanoseconds_from_seconds(event.stamp) for event in truth], "stamps kept (as float seconds)"
    assert torch.allclose(torch.tensor(odometry[-1].T_odom_body, dtype=torch.float64), truth[-1].T_odom_body, atol=1e-12)
    images = [event for event in events if type(event).__name__ == "ImageEvent"]
    assert len(received["image"]) == len(images), "every good image, the one after the bad one too"
    _header, pixels, depth = decode_rgbd(received["image"][-1])
    assert np.array_equal(pixels, images[-1].pixels) and np.array_equal(depth, images[-1].depth.millimetres)
    final = decode(received["status"][-1], ServiceStatus)
    assert final.counters["bad_ros2_encoding"] == 1 and final.counters["events_sent"] == len(events), final.counters


def test_locnerf_record_writes_the_topics_it_hears_into_an_mcap_bag(hub, tmp_path):
    stack, _observer, bus = hub
    process = stack.start("record", "record", str(tmp_path / "out"))
    node = Ros2Node(bus, 0, "fake_filter")
    amcl = node.publisher("amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped")
    cloud = node.publisher("particle_cloud", NAV2_PARTICLE_CLOUD)
    odom = node.publisher("odom", "nav_msgs/msg/Odometry")
    generator = torch.Generator().manual_seed(9)
    published = {}
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and not (tmp_path / "out").exists():
        time.sleep(0.1)
    assert (tmp_path / "out").exists(), stack.log_tail()
    for sent in range(20):  # 2 s: routes to the new subscriber are declared asynchronously
        stamp = 1_700_000_000_000_000_000 + sent * 100_000_000
        T = torch.eye(4, dtype=torch.float64)
        T[:3, 3] = torch.randn(3, generator=generator, dtype=torch.float64)
        pose_type = message_class("geometry_msgs/msg/PoseWithCovariance")
        amcl.publish(
            message_class("geometry_msgs/msg/PoseWithCovarianceStamped")(
                header=convert.header(stamp, "map"), pose=pose_type(pose=convert.pose_message(T), covariance=np.eye(6).reshape(-1))
            )
        )
        particle = message_class(NAV2_PARTICLE)(pose=convert.pose_message(T), weight=0.25)
        cloud.publish(message_class(NAV2_PARTICLE_CLOUD)(header=convert.header(stamp, "map"), particles=[particle] * 4))
        odom.publish(build.odometry_message(stamp, T))
        published[stamp] = T
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    wait_for(lambda: process.poll() is not None, 20.0, "locnerf record to close its bag", stack)
    assert process.returncode == 0, stack.log_tail()
    node.close()

    decoded = decoded_messages(tmp_path / "out")
    assert {"/amcl_pose", "/particle_cloud", "/odom"} <= set(decoded), stack.log_tail()
    for topic in ("/amcl_pose", "/particle_cloud", "/odom"):
        assert len(decoded[topic]) >= 10, (topic, len(decoded[topic]))
    for _time, message in decoded["/amcl_pose"]:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        assert torch.allclose(pose_of(message.pose.pose.position, message.pose.pose.orientation), published[stamp], atol=0)
    for _time, message in decoded["/particle_cloud"]:
        assert [p.weight for p in message.particles] == [0.25] * 4
